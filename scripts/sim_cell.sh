#!/usr/bin/env bash
# A simulated Plug & Produce cell on this machine (root: network namespaces, veth, bridges):
#
#   cell bus 10.10.0.0/24   pnp lds (LDS-ME, level 0) .1      you: `pnp discover` .100
#                           ws1 .11, ws2 .12 (pnp ua serve --lds-me: workstations)
#   ws1 segment 10.11.0.0/24  devices d11 .11 (gripper skills: pnp demo-skills), d12 .12
#   ws2 segment 10.12.0.0/24  devices d21 .11, d22 .12 (gripper skills)
#
# Devices register with their workstation, workstations with the cell bus; `pnp discover`
# on the cell bus shows every server as it appears and `pnp skills` every skill (by type);
# a skill is run by its type with `pnp skill run`. Then the script unplugs and plugs
# devices so that you can watch them come and go, and keeps running until Ctrl-C (or for
# PNP_SIM_SECONDS). Everything it creates is removed on exit.
#
#   scripts/sim_cell.sh [PNP_BINARY]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PNP="${1:-$ROOT/build/apps/pnp/pnp}"
P="pnpsim$$-"
SECONDS_TO_RUN="${PNP_SIM_SECONDS:-0}"
LOGDIR="$(mktemp -d /tmp/pnp-sim-cell.XXXXXX)"
PIDS=()
NAMESPACES=()

log() { printf '[cell] %s\n' "$*"; }

cleanup() {
    set +e
    for pid in "${PIDS[@]}"; do kill "$pid" 2>/dev/null; done
    for pid in "${PIDS[@]}"; do wait "$pid" 2>/dev/null; done
    for ns in "${NAMESPACES[@]}"; do ip netns del "$ns" 2>/dev/null; done
    log "stopped; logs in $LOGDIR"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

if [[ $(id -u) -ne 0 ]] || ! command -v ip >/dev/null; then
    echo "sim_cell.sh needs root and iproute2 (network namespaces)" >&2
    exit 2
fi

ns() { ip netns add "$P$1"; NAMESPACES+=("$P$1"); ip -n "$P$1" link set lo up; }
port=0
attach() {  # host segment ifname cidr
    port=$((port + 1))
    ip -n "$P$1" link add "$3" type veth peer name "p$port" netns "${P}sw"
    ip -n "${P}sw" link set "p$port" master "$2" up
    ip -n "$P$1" addr add "$4" dev "$3"
    ip -n "$P$1" link set "$3" up
}
start() {  # host name args...
    local host="$1" name="$2"
    shift 2
    ip netns exec "$P$host" "$PNP" "$@" >"$LOGDIR/$name.out" 2>"$LOGDIR/$name.log" &
    PIDS+=($!)
    eval "PID_$name=$!"
}

ns sw
for br in bus ws1net ws2net; do
    ip -n "${P}sw" link add "$br" type bridge
    ip -n "${P}sw" link set "$br" up
done
ns cell
attach cell bus eth0 10.10.0.1/24
ns client
attach client bus eth0 10.10.0.100/24
for k in 1 2; do
    ns "ws$k"
    attach "ws$k" bus eth0 "10.10.0.1$k/24"
    attach "ws$k" "ws${k}net" eth1 "10.1$k.0.1/24"
    ip netns exec "${P}ws$k" sysctl -q -w net.ipv4.ip_forward=1
    ip -n "${P}client" route add "10.1$k.0.0/24" via "10.10.0.1$k"
    for j in 1 2; do
        ns "d$k$j"
        attach "d$k$j" "ws${k}net" eth0 "10.1$k.0.1$j/24"
        ip -n "${P}d$k$j" route add default via "10.1$k.0.1"
    done
done
log "topology up (namespaces ${P}*)"

log "pnp discover on the cell bus (10.10.0.100):"
ip netns exec "${P}client" "$PNP" discover &
PIDS+=($!)
sleep 0.3
log "starting the cell bus LDS-ME, two workstations, four devices"
start cell cell lds --port 4840 --public-host 10.10.0.1 --name cell-bus
for k in 1 2; do
    start "ws$k" "ws$k" ua serve --port 4840 --public-host "10.10.0.1$k" --lds-me --name "ws$k"
done
log "pnp skills on the cell bus: the skills of every component, by type, as they come and go"
ip netns exec "${P}client" "$PNP" skills &
PIDS+=($!)
# d11 and d22 are grippers offering skills (pnp demo-skills), d12 and d21 plain servers.
start d11 d11 demo-skills --port 4840 --public-host 10.11.0.11 --name d11 --controller Gripper11
start d12 d12 ua serve --port 4840 --public-host 10.11.0.12 --name d12
start d21 d21 ua serve --port 4840 --public-host 10.12.0.11 --name d21
start d22 d22 demo-skills --port 4840 --public-host 10.12.0.12 --name d22 --controller Gripper22
sleep 3
log "running a MoveGripperSkillType skill, found by type (pnp skill run):"
ip netns exec "${P}client" "$PNP" skill run MoveGripperSkillType Width=0.03 || true
log "d22 (a gripper) crashes (kill -9): its skills go with the registration expiry"
kill -9 "$PID_d22"
wait "$PID_d22" 2>/dev/null || true
sleep 3
log "unplugging d12 (graceful stop)"
kill "$PID_d12"
sleep 2
log "d21 crashes (kill -9): gone within the registration expiry (1.8 s)"
kill -9 "$PID_d21"
wait "$PID_d21" 2>/dev/null || true
sleep 3
log "plugging d12 in again"
start d12 d12 ua serve --port 4840 --public-host 10.11.0.12 --name d12
if [[ "$SECONDS_TO_RUN" -gt 0 ]]; then
    sleep "$SECONDS_TO_RUN"
else
    log "running; Ctrl-C to stop"
    while true; do sleep 3600; done
fi
