# shellcheck shell=bash
# Helpers for the interop shell scripts (source this file).
# Every wait loop is bounded; processes are only ever stopped by their PID.

INTEROP_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
REPO_ROOT="$(cd "$INTEROP_DIR/../.." && pwd)"

# `pnp ua serve` arguments that load the Robotics test model and create the instances
# node_client.js browses and reads (see pnp.RobotCell.NodeSet2.xml).
# shellcheck disable=SC2034 # used by the scripts that source this file
ROBOTICS_SERVE_ARGS=(--nodeset "$INTEROP_DIR/pnp.RobotCell.NodeSet2.xml"
    --instance "nsu=http://opcfoundation.org/UA/Robotics/;i=1002=RobotSystem"
    --instance "nsu=urn:pnp:robotcell;i=1001=Arm1")

ilog() { printf '[%s] %s\n' "${INTEROP_NAME:-interop}" "$*" >&2; }

# port_listening PORT -> 0 if something listens on TCP PORT (does not connect)
port_listening() {
    local port="$1"
    if command -v ss >/dev/null 2>&1; then
        [[ -n "$(ss -Hltn "sport = :$port" 2>/dev/null)" ]]
    else
        (exec 3<>"/dev/tcp/127.0.0.1/$port") 2>/dev/null
    fi
}

# wait_for_port PORT TIMEOUT_S [PID] -> 0 once PORT listens; 1 on timeout or if PID died
wait_for_port() {
    local port="$1" timeout_s="$2" pid="${3:-}"
    local tries=$((timeout_s * 10)) i
    for ((i = 0; i < tries; i++)); do
        if port_listening "$port"; then
            return 0
        fi
        if [[ -n "$pid" ]] && ! kill -0 "$pid" 2>/dev/null; then
            ilog "process $pid exited before port $port was listening"
            return 1
        fi
        sleep 0.1
    done
    ilog "port $port not listening after ${timeout_s}s"
    return 1
}

# wait_for_line FILE REGEX TIMEOUT_S [PID] -> 0 once a line of FILE matches REGEX
wait_for_line() {
    local file="$1" re="$2" timeout_s="$3" pid="${4:-}"
    local tries=$((timeout_s * 10)) i
    for ((i = 0; i < tries; i++)); do
        if [[ -f "$file" ]] && grep -qE -- "$re" "$file"; then
            return 0
        fi
        if [[ -n "$pid" ]] && ! kill -0 "$pid" 2>/dev/null; then
            ilog "process $pid exited before '$re' appeared in $file"
            return 1
        fi
        sleep 0.1
    done
    ilog "'$re' not seen in $file after ${timeout_s}s"
    return 1
}

# stop_pid PID [SIGNAL] [GRACE_S]: signal PID, wait up to GRACE_S, then SIGKILL.
stop_pid() {
    local pid="$1" sig="${2:-TERM}" grace="${3:-5}" i
    [[ -n "$pid" ]] || return 0
    kill -0 "$pid" 2>/dev/null || { wait "$pid" 2>/dev/null || true; return 0; }
    kill "-$sig" "$pid" 2>/dev/null || true
    for ((i = 0; i < grace * 10; i++)); do
        kill -0 "$pid" 2>/dev/null || break
        sleep 0.1
    done
    if kill -0 "$pid" 2>/dev/null; then
        ilog "pid $pid still alive after SIG$sig + ${grace}s, sending SIGKILL"
        kill -KILL "$pid" 2>/dev/null || true
    fi
    wait "$pid" 2>/dev/null || true
}

# free_port [START]: prints a TCP port (START..START+199) nothing listens on. Below the
# kernel's ephemeral range (32768-60999 by default): a port there can be taken as the local
# port of an outgoing connection between this check and the server's bind (EADDRINUSE).
free_port() {
    local p="${1:-28400}" i
    for ((i = 0; i < 200; i++)); do
        if ! port_listening "$((p + i))"; then
            echo "$((p + i))"
            return 0
        fi
    done
    return 1
}

# require_node_modules: node-opcua must be installed (scripts/setup.sh does npm ci)
require_node_modules() {
    if [[ ! -d "$REPO_ROOT/node_modules/node-opcua" ]]; then
        ilog "node_modules/node-opcua missing: run scripts/setup.sh (npm ci) first"
        return 1
    fi
}
