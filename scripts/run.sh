#!/usr/bin/env bash
# The "main job": set up, build (release) and run the simulated Plug & Produce cell end to end
# (`pnp cell run`, src/cell/README.md): the cell bus (LDS-ME, semantic MES), `pnp sim` with the
# thesis cell, every device and component plugged in one at a time (plug-in -> skills detected
# printed for each), the thesis process through the MES, the operator's swap of the Robotiq
# in dock 2 for a WSG 50, the same process again, a report (text here, JSON in
# ./cell-report.json). Exits non-zero if a step failed or the cube is off by more than 1 mm.
#   scripts/run.sh [pnp cell run options]   e.g. --netns (root), --report FILE, --log-dir DIR
#   scripts/run.sh --up [options]           the same cell left running until Ctrl-C
#   scripts/run.sh --server [args]          only the demo server on port $PNP_PORT (4840)
# PNP_SIM_SECONDS is gone: the main job ends by itself (about 3 minutes of simulated motion
# on two cores, two rounds of the thesis process); `--up` runs
# until Ctrl-C.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
# Only what the main job runs (the pnp executable and the libraries it links); the test
# command builds the rest of the same tree.
bash "$ROOT/scripts/build.sh" release pnp
PNP="$ROOT/build/apps/pnp/pnp"
case "${1:-}" in
--server)
    shift
    PORT="${PNP_PORT:-4840}"
    echo "[run] $PNP ua serve --port $PORT $*"
    exec "$PNP" ua serve --port "$PORT" "$@"
    ;;
--up)
    shift
    echo "[run] $PNP cell up $*"
    exec "$PNP" cell up "$@"
    ;;
*)
    echo "[run] $PNP cell run $*"
    exec "$PNP" cell run "$@"
    ;;
esac
