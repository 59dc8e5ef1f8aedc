#!/usr/bin/env bash
# The pnp benchmark: builds a Release tree if needed, then runs bench/pnp_bench once.
# See bench/README.md for what is measured and how to read the table.
#
#   bash bench/run.sh                       # defaults: server + clients on CPU 0
#   bash bench/run.sh --placement split     # server on CPU 0, clients on CPU 1
#   bash bench/run.sh --iterations 5000 --realtime
#   bash bench/run.sh --help                # every option of pnp_bench
#
# Environment:
#   PNP_BENCH_BUILD_DIR   build tree (default: build-bench); must be a Release build
#   PNP_BUILD_JOBS        parallel build jobs (default: nproc)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${PNP_BENCH_BUILD_DIR:-$ROOT/build-bench}"
JOBS="${PNP_BUILD_JOBS:-$(nproc)}"
log() { printf '[bench] %s\n' "$*" >&2; }

# Toolchain and generator inputs (node-opcua-nodesets) come from scripts/setup.sh.
if ! command -v cmake >/dev/null 2>&1 || ! command -v ninja >/dev/null 2>&1 ||
    [[ ! -f "$ROOT/node_modules/node-opcua-nodesets/nodesets/Opc.Ua.NodeSet2.xml" ]]; then
    log "build prerequisites missing: running scripts/setup.sh"
    bash "$ROOT/scripts/setup.sh"
fi

# GCC 12 at -O3 (Release) reports false -Wrestrict / -Warray-bounds / -Wstringop-overflow
# inside libstdc++'s std::string operator+ and std::vector insert/push_back (GCC bugs 105329,
# 105651, 106199); they stay warnings instead of failing the build. The project's own builds
# use -O2.
O3_FLAGS="-Wno-error=restrict -Wno-error=array-bounds -Wno-error=stringop-overflow"
if [[ ! -f "$BUILD/CMakeCache.txt" ]]; then
    log "configure Release -> $BUILD"
    cmake -S "$ROOT" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DPNP_BUILD_BENCH=ON \
        -DPNP_SANITIZE=OFF -DCMAKE_CXX_FLAGS="$O3_FLAGS" >&2
elif ! grep -q -- "^CMAKE_CXX_FLAGS:STRING=$O3_FLAGS\$" "$BUILD/CMakeCache.txt"; then
    cmake -S "$ROOT" -B "$BUILD" -DCMAKE_CXX_FLAGS="$O3_FLAGS" >&2
fi
BUILD_TYPE="$(sed -n 's/^CMAKE_BUILD_TYPE:[A-Z]*=//p' "$BUILD/CMakeCache.txt")"
if [[ "$BUILD_TYPE" != "Release" ]] || grep -q '^PNP_SANITIZE:BOOL=ON' "$BUILD/CMakeCache.txt"; then
    log "ERROR: $BUILD is a '$BUILD_TYPE' build (sanitizers: $(sed -n 's/^PNP_SANITIZE:BOOL=//p' "$BUILD/CMakeCache.txt")); the benchmark needs Release without sanitizers"
    exit 2
fi
if ! grep -q '^PNP_BUILD_BENCH:BOOL=ON' "$BUILD/CMakeCache.txt"; then
    cmake -S "$ROOT" -B "$BUILD" -DPNP_BUILD_BENCH=ON >&2
fi

log "build pnp_bench (+ pnp, helpers) in $BUILD (-j$JOBS)"
cmake --build "$BUILD" -j "$JOBS" --target pnp_bench >&2

exec "$BUILD/bench/pnp_bench" --json "$BUILD/bench/results.json" "$@"
