#!/usr/bin/env bash
# Run the node-opcua interop client against our server.
#
# usage: tests/interop/run_node_client_vs_pnp.sh PNP_BINARY PORT [CLIENT_SCRIPT]
#   CLIENT_SCRIPT: the node script to run (default node_client.js; node_subscriber.js
#   for subscriptions and events), from tests/interop.
#   starts `PNP_BINARY ua serve --port PORT --user operator:secret` with the Robotics test
#   model (pnp.RobotCell.NodeSet2.xml; node_client.js also opens a UserName session as
#   operator/secret), waits (<= 10 s) for the port, runs
#   the client script against opc.tcp://127.0.0.1:PORT, stops the server by PID and
#   exits with the client's status.
# Server output goes to $PNP_INTEROP_LOG_DIR (default: a temp dir), printed on failure.
set -uo pipefail
export INTEROP_NAME=node-client-vs-pnp
# shellcheck source=lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"

if [[ $# -lt 2 ]]; then
    echo "usage: $0 PNP_BINARY PORT [CLIENT_SCRIPT]" >&2
    exit 2
fi
PNP_BINARY="$1"
PORT="$2"
CLIENT_SCRIPT="${3:-node_client.js}"
if [[ ! -x "$PNP_BINARY" ]]; then
    ilog "not an executable: $PNP_BINARY"
    exit 2
fi
require_node_modules || exit 2
if port_listening "$PORT"; then
    ilog "port $PORT is already in use"
    exit 2
fi

LOG_DIR="${PNP_INTEROP_LOG_DIR:-$(mktemp -d /tmp/pnp-interop.XXXXXX)}"
mkdir -p "$LOG_DIR"
SERVER_LOG="$LOG_DIR/pnp-server-$PORT.log"
CLIENT_ERR="$LOG_DIR/node-client-$PORT.stderr"

SERVER_PID=""
# shellcheck disable=SC2317 # invoked via trap
cleanup() {
    local rc=$?
    if [[ -n "$SERVER_PID" ]]; then
        stop_pid "$SERVER_PID" TERM 5
        SERVER_PID=""
    fi
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# A Robotics (OPC 40010-1) model loaded from NodeSet2 XML, with two instances (node_client.js
# browses and reads them).
# --no-register: tests talk to loopback only (no mDNS on the machine's network).
# --allow-none: the harness exercises every service over SecurityPolicy None (the secured
# endpoints: tests/cli/secure_interop_test.cpp).
SERVE_ARGS=(ua serve --port "$PORT" --no-register --allow-none --user operator:secret "${ROBOTICS_SERVE_ARGS[@]}")
ilog "starting: $PNP_BINARY ${SERVE_ARGS[*]} (log: $SERVER_LOG)"
"$PNP_BINARY" "${SERVE_ARGS[@]}" >"$SERVER_LOG" 2>&1 </dev/null &
SERVER_PID=$!

if ! wait_for_port "$PORT" 10 "$SERVER_PID"; then
    ilog "server did not come up; its output:"
    tail -n 50 "$SERVER_LOG" >&2
    echo "not ok - pnp server listening on port $PORT"
    exit 1
fi

timeout -k 5 70 node "$INTEROP_DIR/$CLIENT_SCRIPT" "opc.tcp://127.0.0.1:$PORT" 2>"$CLIENT_ERR"
rc=$?
if [[ $rc -eq 124 ]]; then
    echo "not ok - $CLIENT_SCRIPT killed after 70 s"
fi
if ! kill -0 "$SERVER_PID" 2>/dev/null; then
    echo "not ok - pnp server still running after the client run (it exited)"
    rc=1
fi
if [[ $rc -ne 0 ]]; then
    ilog "node_client exit code $rc; last server output:"
    tail -n 50 "$SERVER_LOG" >&2
    ilog "node_client stderr (tail):"
    tail -n 20 "$CLIENT_ERR" >&2
fi
exit "$rc"
