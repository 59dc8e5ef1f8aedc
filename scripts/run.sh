#!/usr/bin/env bash
# The "main job": set up, build (release) and run the simulated cell in the foreground
# (scripts/sim_cell.sh: an LDS-ME on the cell bus, two workstations, four devices in network
# namespaces, `pnp discover` showing them come and go) until Ctrl-C.
#   scripts/run.sh            the simulated cell (root: network namespaces)
#   scripts/run.sh --server [extra args for `pnp ua serve`]
#                             only the demo server on port $PNP_PORT (default 4840)
#   PNP_SIM_SECONDS=N         stop the cell after N s (default: run until Ctrl-C)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
# Only what the main job runs (the pnp executable and the libraries it links); the test
# command builds the rest of the same tree.
bash "$ROOT/scripts/build.sh" release pnp
PNP="$ROOT/build/apps/pnp/pnp"
if [[ "${1:-}" != "--server" ]] && [[ $(id -u) -eq 0 ]] && ip netns list >/dev/null 2>&1; then
    exec bash "$ROOT/scripts/sim_cell.sh" "$PNP"
fi
[[ "${1:-}" == "--server" ]] && shift
PORT="${PNP_PORT:-4840}"
echo "[run] $PNP ua serve --port $PORT $*"
exec "$PNP" ua serve --port "$PORT" "$@"
