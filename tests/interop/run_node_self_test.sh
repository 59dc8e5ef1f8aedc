#!/usr/bin/env bash
# Validates the interop test itself: node_client.js against node_server.js (both
# node-opcua), through the same runner that is used against our server.
#
# usage: tests/interop/run_node_self_test.sh [PORT]
set -uo pipefail
export INTEROP_NAME=node-self-test
# shellcheck source=lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
PORT="${1:-$(free_port 28450)}"
exec bash "$INTEROP_DIR/run_node_client_vs_pnp.sh" "$INTEROP_DIR/node_server_as_pnp.sh" "$PORT"
