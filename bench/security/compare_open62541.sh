#!/usr/bin/env bash
# Issue 24: pnp vs open62541, side by side, with the same policies, sizes and method — Call
# Echo (ByteString in -> out) SignAndEncrypt vs None at 2 B .. 32 KiB, one client, one
# server, 127.0.0.1 — and the secured handshake. open62541 is never part of this repository:
# build it and its two benchmark programs elsewhere and point OPEN62541_BENCH_DIR at them.
#
#   OPEN62541_BENCH_DIR=/path/to/o6bench bash bench/security/compare_open62541.sh
#       [--runs 3] [--iterations 2000] [--rounds 5] [--connects 30]
#       [--policies "Basic256Sha256 Aes128_Sha256_RsaOaep Aes256_Sha256_RsaPss"]
#       [--cpu N|none] [--inprocess] [--timeout S] [--keep DIR]
#
# Per run and policy, interleaved: our client (pnp_bench_security --url --policy P) against
# our server (pnp_bench_security --serve), then the open62541 client against the open62541
# server; each client alternates None and SignAndEncrypt rounds itself (fresh connection per
# round, medians of the round medians). With --runs N the table gives the median of the N
# runs and the spread (min-max). By default every process runs on one CPU (the last one):
# server and client share it, as in the issue's measurement; --cpu none leaves placement
# to the kernel. --inprocess runs our server inside our client process instead (the
# benchmark's default mode; open62541 always runs as two processes).
#
# OPEN62541_BENCH_DIR must hold two programs built with open62541 (OpenSSL):
#   o6_server PORT CERT.der KEY.pem
#       endpoints None + the three policies (SignAndEncrypt), every client trusted, an object
#       ns=1;s=Demo with method ns=1;s=Demo.Echo; prints "ready ..." once listening; stops on
#       SIGTERM.
#   o6_client URL POLICY CERT.der KEY.pem --iterations N --rounds R --connects C --csv FILE
#       appends "echo,open62541,POLICY,BYTES,NONE_US,SECURED_US" per size and
#       "connect,open62541,POLICY,NONE_MS,CONNECT_MS,GETENDPOINTS_MS,KNOWN_ENDPOINT_MS".
# Certificates (RSA 2048, self-signed) are created per invocation with `pnp pki create`.
#
# Environment:
#   OPEN62541_BENCH_DIR   the directory above (required)
#   PNP_BUILD_DIR         our build tree (default: build) with bench/security/pnp_bench_security
#                         (configured with -DPNP_BUILD_BENCH=ON) and apps/pnp/pnp
#   PNP_CLI               the pnp executable for `pnp pki create` (default: $PNP_BUILD_DIR/apps/pnp/pnp)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BUILD="${PNP_BUILD_DIR:-$ROOT/build}"
PNP_BENCH="$BUILD/bench/security/pnp_bench_security"
PNP="${PNP_CLI:-$BUILD/apps/pnp/pnp}"
O6="${OPEN62541_BENCH_DIR:-}"

runs=3 iterations=2000 rounds=5 connects=30 timeout_s=900 inprocess=0 keep=""
policies="Basic256Sha256 Aes128_Sha256_RsaOaep Aes256_Sha256_RsaPss"
cpu=$(($(nproc) - 1))
usage() { sed -n '2,/^set -euo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; }
while [[ $# -gt 0 ]]; do
    case "$1" in
    --runs) runs="$2"; shift 2 ;;
    --iterations) iterations="$2"; shift 2 ;;
    --rounds) rounds="$2"; shift 2 ;;
    --connects) connects="$2"; shift 2 ;;
    --policies) policies="$2"; shift 2 ;;
    --cpu) cpu="$2"; shift 2 ;;
    --timeout) timeout_s="$2"; shift 2 ;;
    --inprocess) inprocess=1; shift ;;
    --keep) keep="$2"; shift 2 ;;
    -h | --help) usage; exit 0 ;;
    *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
for n in "$runs" "$iterations" "$rounds" "$connects" "$timeout_s"; do
    [[ "$n" =~ ^[0-9]+$ && "$n" -ge 1 ]] || { echo "not a positive count: $n" >&2; exit 2; }
done
[[ "$runs" -le 100 ]] || { echo "--runs at most 100" >&2; exit 2; }
log() { printf '[compare] %s\n' "$*" >&2; }

[[ -n "$O6" ]] || { echo "set OPEN62541_BENCH_DIR (see --help)" >&2; exit 2; }
for f in "$O6/o6_server" "$O6/o6_client" "$PNP_BENCH" "$PNP"; do
    [[ -x "$f" ]] || { echo "missing executable: $f (see --help)" >&2; exit 2; }
done
pin=()
if [[ "$cpu" != none ]]; then
    command -v taskset >/dev/null || { echo "taskset missing: use --cpu none" >&2; exit 2; }
    pin=(taskset -c "$cpu")
fi

work="$(mktemp -d /tmp/pnp-o6-compare.XXXXXX)"
pids=()
# Every process this script starts is stopped by its PID: SIGTERM, then SIGKILL after 5 s.
cleanup() {
    local pid i
    for pid in "${pids[@]}"; do
        kill -TERM "$pid" 2>/dev/null || continue
        for ((i = 0; i < 50; i++)); do
            kill -0 "$pid" 2>/dev/null || break
            sleep 0.1
        done
        kill -KILL "$pid" 2>/dev/null || true
        wait "$pid" 2>/dev/null || true
    done
    pids=()
    if [[ -n "$keep" ]]; then
        mkdir -p "$keep" && cp -r "$work"/. "$keep"/
    fi
    rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# Waits (at most 20 s) until FILE has a line matching PATTERN while PID lives; prints it.
wait_line() {
    local file="$1" pattern="$2" pid="$3" i
    for ((i = 0; i < 200; i++)); do
        if grep -m1 -E "$pattern" "$file" 2>/dev/null; then return 0; fi
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.1
    done
    echo "no '$pattern' from PID $pid; its output:" >&2
    cat "$file" >&2
    return 1
}

# Certificates for the open62541 programs (ApplicationUri in the SubjectAltName).
for who in server client; do
    "$PNP" pki create --uri "urn:open62541:bench:$who" --name "o6$who" --dns localhost \
        --ip 127.0.0.1 --out-cert "$work/o6_${who}_cert.der" \
        --out-key "$work/o6_${who}_key.pem" >/dev/null
done

csv="$work/results.csv"
: >"$csv"
o6_url="" pnp_url=""

start_servers() {
    # Ours: port 0, the URL comes from its first line.
    if [[ "$inprocess" == 0 ]]; then
        "${pin[@]}" "$PNP_BENCH" --serve 0 >"$work/pnp_server.log" 2>&1 &
        pids+=($!)
        local line
        line="$(wait_line "$work/pnp_server.log" '^listening on ' "$!")"
        pnp_url="${line#listening on }"
    fi
    # open62541: a free port from a range; a few tries if one is taken meanwhile.
    local try port pid
    for ((try = 0; try < 5; try++)); do
        port=$((20000 + (RANDOM % 20000)))
        if ss -Hltn "sport = :$port" 2>/dev/null | grep -q .; then continue; fi
        "${pin[@]}" "$O6/o6_server" "$port" "$work/o6_server_cert.der" \
            "$work/o6_server_key.pem" >"$work/o6_server.log" 2>&1 &
        pid=$!
        pids+=("$pid")
        if wait_line "$work/o6_server.log" '^ready ' "$pid" >/dev/null; then
            o6_url="opc.tcp://127.0.0.1:$port"
            return 0
        fi
    done
    echo "open62541 server did not start" >&2
    return 1
}

start_servers
log "pnp server: ${pnp_url:-in the client process}; open62541 server: $o6_url; CPU: $cpu"
log "runs $runs, policies: $policies; $iterations calls per size and mode in $rounds rounds"

for ((run = 1; run <= runs; run++)); do
    for policy in $policies; do
        log "run $run/$runs $policy: pnp"
        url_args=()
        [[ "$inprocess" == 0 ]] && url_args=(--url "$pnp_url")
        timeout "$timeout_s" "${pin[@]}" "$PNP_BENCH" "${url_args[@]}" --policy "$policy" \
            --iterations "$iterations" --rounds "$rounds" --connects "$connects" \
            --csv "$work/run.csv" >>"$work/pnp_client.log" 2>&1 ||
            { echo "pnp_bench_security failed:" >&2; tail -20 "$work/pnp_client.log" >&2; exit 1; }
        log "run $run/$runs $policy: open62541"
        timeout "$timeout_s" "${pin[@]}" "$O6/o6_client" "$o6_url" "$policy" \
            "$work/o6_client_cert.der" "$work/o6_client_key.pem" --iterations "$iterations" \
            --rounds "$rounds" --connects "$connects" --csv "$work/run.csv" \
            >>"$work/o6_client.log" 2>&1 ||
            { echo "o6_client failed:" >&2; tail -20 "$work/o6_client.log" >&2; exit 1; }
        sed "s/^/$run,/" "$work/run.csv" >>"$csv"
        rm -f "$work/run.csv"
    done
done

# One table: the median of the runs, and min-max when there is more than one.
python3 - "$csv" "$runs" <<'EOF'
import collections, sys
path, runs = sys.argv[1], int(sys.argv[2])
echo = collections.defaultdict(list)   # (policy, bytes, column) -> values over runs
conn = collections.defaultdict(list)   # (policy, column) -> values
order = []
for line in open(path):
    f = line.strip().split(",")
    run, kind, stack, policy = f[0], f[1], f[2], f[3]
    if policy not in order:
        order.append(policy)
    if kind == "echo":
        b = int(f[4])
        echo[(policy, b, stack + " None")].append(float(f[5]))
        echo[(policy, b, stack + " secured")].append(float(f[6]))
        if stack == "pnp":
            echo[(policy, b, "crypto")].append(float(f[7]))
    else:
        if stack == "pnp":
            conn[(policy, "pnp None")].append(float(f[4]))
            conn[(policy, "pnp connect")].append(float(f[5]))
            conn[(policy, "pnp handshake")].append(float(f[7]))
        else:
            conn[(policy, "o6 None")].append(float(f[4]))
            conn[(policy, "o6 connect")].append(float(f[5]))
            conn[(policy, "o6 handshake")].append(float(f[7]))

def med(v):
    s = sorted(v)
    n = len(s)
    return s[n // 2] if n % 2 else (s[n // 2 - 1] + s[n // 2]) / 2

def cell(v, fmt="%.1f"):
    if not v:
        return "-"
    if len(v) == 1:
        return fmt % v[0]
    return (fmt % med(v)) + " (" + (fmt % min(v)) + "-" + (fmt % max(v)) + ")"

print()
print("Call Echo round trip, µs: median of %d run(s) (min-max); SignAndEncrypt vs None" % runs)
hdr = ("policy", "bytes", "pnp None", "pnp secured", "open62541 None", "open62541 secured",
       "pnp/open62541 secured")
rows = []
for p in order:
    for b in sorted({k[1] for k in echo if k[0] == p}):
        ps, os_ = echo[(p, b, "pnp secured")], echo[(p, b, "open62541 secured")]
        ratios = [x / y for x, y in zip(ps, os_)]  # per run: same run, side by side
        rows.append((p, str(b), cell(echo[(p, b, "pnp None")]), cell(ps),
                     cell(echo[(p, b, "open62541 None")]), cell(os_), cell(ratios, "%.2f")))
w = [max(len(r[i]) for r in rows + [hdr]) for i in range(len(hdr))]
for r in [hdr] + rows:
    print("  ".join(r[i].ljust(w[i]) if i == 0 else r[i].rjust(w[i]) for i in range(len(hdr))))

print()
print("Connect, ms (median of the per-run medians; min-max). handshake: pnp = connect - "
      "GetEndpoints; open62541 = UA_Client_connect with the endpoint known (OPN + FindServers"
      " + CreateSession + ActivateSession + Read NamespaceArray)")
hdr = ("policy", "pnp handshake", "open62541 handshake", "pnp/open62541", "pnp connect",
       "open62541 connect", "pnp None", "open62541 None")
rows = []
for p in order:
    ph, oh = conn[(p, "pnp handshake")], conn[(p, "o6 handshake")]
    rows.append((p, cell(ph, "%.2f"), cell(oh, "%.2f"),
                 cell([x / y for x, y in zip(ph, oh)], "%.2f"),
                 cell(conn[(p, "pnp connect")], "%.2f"), cell(conn[(p, "o6 connect")], "%.2f"),
                 cell(conn[(p, "pnp None")], "%.2f"), cell(conn[(p, "o6 None")], "%.2f")))
w = [max(len(r[i]) for r in rows + [hdr]) for i in range(len(hdr))]
for r in [hdr] + rows:
    print("  ".join(r[i].ljust(w[i]) if i == 0 else r[i].rjust(w[i]) for i in range(len(hdr))))
EOF
