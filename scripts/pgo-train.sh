#!/usr/bin/env bash
# The training workload of the profile-guided build (scripts/build.sh pgo): what a cell does
# most, through the pnp command line on 127.0.0.1 — a skill server whose skills clients run
# (lock, write, start, transition events, result, unlock), find and list; an OPC UA server
# that clients read, write, browse, call and watch. The instrumented programs write their
# profiles when they exit.
#
#   scripts/pgo-train.sh PNP_EXE
#
#   PNP_PGO_TRAIN_PERCENT=100  the share of the repetitions to run (1..100): the sanitized test
#                              tree runs every command of the workload at 10 % (a -O0 ASan pnp
#                              is about 15x slower; the test checks commands, not volume)
set -euo pipefail

PNP="${1:?usage: $0 PNP_EXE}"
PERCENT="${PNP_PGO_TRAIN_PERCENT:-100}"
if ! [[ "$PERCENT" =~ ^[0-9]+$ ]] || ((PERCENT < 1 || PERCENT > 100)); then
    echo "PNP_PGO_TRAIN_PERCENT must be 1..100, not '$PERCENT'" >&2
    exit 2
fi
# n COUNT: COUNT scaled by PERCENT, at least 1
n() { local v=$(($1 * PERCENT / 100)); echo $((v < 1 ? 1 : v)); }
log() { printf '[pgo-train] %s\n' "$*" >&2; }
tmp="$(mktemp -d)"
pids=()
# Stops the servers by PID with SIGTERM: they exit normally and write their profiles.
stop_servers() {
    for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
    for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
    pids=()
}
trap 'stop_servers; rm -rf "$tmp"' EXIT

# Starts a server (its arguments) and sets URL from its "listening on URL" line (10 s at most).
start_server() {
    local out="$tmp/server.${#pids[@]}"
    "$PNP" "$@" >"$out" 2>/dev/null &
    pids+=("$!")
    URL=""
    for _ in $(seq 1 200); do
        URL="$(sed -n 's/^listening on //p' "$out" | head -n 1)"
        [[ -n "$URL" ]] && return 0
        sleep 0.05
    done
    log "ERROR: '$*' did not start"
    exit 1
}


log "skills: pnp demo-skills, pnp skill run, pnp skills"
start_server demo-skills --host 127.0.0.1 --port 0 --no-register
skills="$URL"
run_skill() { "$PNP" skill run "$skills" --timeout 10000 "$@" >/dev/null; }
run_skill --skill Delay --repeat "$(n 3000)" DurationMs=0
run_skill --skill Delay --repeat "$(n 100)" DurationMs=2
run_skill --skill MoveGripper --repeat "$(n 300)" Width=0.02
run_skill --skill Grasp --repeat "$(n 20)"
run_skill --skill Release --repeat "$(n 20)"
for _ in 1 2 3; do
    "$PNP" skills --once --json --no-mdns --url "$skills" --duration 300 >/dev/null
done

log "OPC UA services: pnp ua serve, read / write / browse / call / monitor / events"
start_server ua serve --host 127.0.0.1 --port 0 --no-register
ua="$URL"
for _ in $(seq 1 "$(n 20)"); do
    "$PNP" ua read "$ua" /Objects/Server/ServerStatus/State i=2258 >/dev/null
    "$PNP" ua write "$ua" "nsu=urn:pnp:demo;s=Array.Int32" "[1,2,3]" >/dev/null
    "$PNP" ua browse "$ua" i=85 --depth 2 >/dev/null
    "$PNP" ua call "$ua" "nsu=urn:pnp:demo;s=Demo" "nsu=urn:pnp:demo;s=Demo.Add" 2 3 >/dev/null
done
"$PNP" ua monitor "$ua" i=2258 --interval 10 --duration 2000 >/dev/null
"$PNP" ua events "$ua" i=2253 --duration 1000 >/dev/null

stop_servers
log "ok"
