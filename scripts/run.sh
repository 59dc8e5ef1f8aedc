#!/usr/bin/env bash
# The "main job": set up, build (release) and run the server in the foreground.
#   scripts/run.sh [extra args for `pnp ua serve`]
#   PNP_PORT=4840 (default)
# (Later this starts the simulated cell.)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
bash "$ROOT/scripts/build.sh" release
PORT="${PNP_PORT:-4840}"
echo "[run] $ROOT/build/apps/pnp/pnp ua serve --port $PORT $*"
exec "$ROOT/build/apps/pnp/pnp" ua serve --port "$PORT" "$@"
