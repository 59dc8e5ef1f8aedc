#!/usr/bin/env bash
# The training workload of the profile-guided build (scripts/build.sh pgo): what a cell does
# most, through the pnp command line on 127.0.0.1 — a skill server whose skills clients run
# (lock, write, start, transition events, result, unlock), find and list; an OPC UA server
# that clients read, write, browse, call and watch. The instrumented programs write their
# profiles when they exit.
#
#   scripts/pgo-train.sh PNP_EXE
set -euo pipefail

PNP="${1:?usage: $0 PNP_EXE}"
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
run_skill --skill Delay --repeat 3000 DurationMs=0
run_skill --skill Delay --repeat 100 DurationMs=2
run_skill --skill MoveGripper --repeat 300 Width=0.02
run_skill --skill Grasp --repeat 20
run_skill --skill Release --repeat 20
for _ in 1 2 3; do
    "$PNP" skills --once --json --no-mdns --url "$skills" --duration 300 >/dev/null
done

log "OPC UA services: pnp ua serve, read / write / browse / call / monitor / events"
start_server ua serve --host 127.0.0.1 --port 0 --no-register
ua="$URL"
for _ in $(seq 1 20); do
    "$PNP" ua read "$ua" /Objects/Server/ServerStatus/State i=2258 >/dev/null
    "$PNP" ua write "$ua" "nsu=urn:pnp:demo;s=Array.Int32" "[1,2,3]" >/dev/null
    "$PNP" ua browse "$ua" i=85 --depth 2 >/dev/null
    "$PNP" ua call "$ua" "nsu=urn:pnp:demo;s=Demo" "nsu=urn:pnp:demo;s=Demo.Add" 2 3 >/dev/null
done
"$PNP" ua monitor "$ua" i=2258 --interval 10 --duration 2000 >/dev/null
"$PNP" ua events "$ua" i=2253 --duration 1000 >/dev/null

stop_servers
log "ok"
