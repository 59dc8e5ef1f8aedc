#!/usr/bin/env bash
# Configure (CMake + Ninja) and build.
#
#   scripts/build.sh [MODE] [TARGET...]   builds TARGETs only (default: everything of MODE);
#                                         e.g. `scripts/build.sh release pnp` (scripts/run.sh)
#
#   scripts/build.sh [release]  -> build/       RelWithDebInfo, g++
#   scripts/build.sh asan       -> build-asan/  Debug, -DPNP_SANITIZE=ON (ASan + UBSan), clang
#                                  >= 16: the tests and, in the same tree, the libFuzzer targets
#                                  (-DPNP_FUZZ=ON; their seed corpora in build-asan/corpus/), so
#                                  that CI compiles the sources twice (release, asan), not three
#                                  times; g++ without fuzz targets when there is no clang
#   scripts/build.sh fuzz       -> build-fuzz/  clang >= 16, optimised (-O2), -DPNP_FUZZ=ON
#                                  -DPNP_SANITIZE=ON, tests/benchmarks off; builds only the
#                                  targets under fuzz/ (CMake's "fuzz/all"): for fuzzing
#                                  campaigns, 3-5x the executions per second of the asan tree's
#                                  -O0 fuzzers; exits 3 if no usable clang
#   scripts/build.sh pgo        -> build-pgo/   RelWithDebInfo, profile-guided (g++): pnp is
#                                  built instrumented, trained with scripts/pgo-train.sh, then
#                                  pnp and the benchmarks are built with the profile; tests off
#                                  (the optimised build of a cell; compiles twice)
#
# Environment:
#   PNP_ASAN_COMPILER=clang|gcc  compiler family of the asan build (default clang: it
#                                compiles the -O0 sanitized tree in 8 minutes where g++ takes
#                                14, and builds the fuzz targets; gcc: tests only)
#   PNP_BUILD_JOBS=N             parallel jobs (default: nproc)
#   PNP_CMAKE_ARGS="..."         extra arguments for the configure step
#   PNP_CCACHE=auto|off          auto (default): compile through ccache when it is installed
#                                (repeated builds on one machine; never required)
#
# clang 14 (Debian's default clang) is never picked: it cannot compile libstdc++-12's
# <ranges> views. scripts/setup.sh installs clang-19 + libclang-rt-19-dev.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MODE="${1:-release}"
shift || true
JOBS="${PNP_BUILD_JOBS:-$(nproc)}"
log() { printf '[build] %s\n' "$*"; }

find_clang() {
    local v
    for v in 19 18 17 16; do
        if command -v "clang++-$v" >/dev/null 2>&1; then
            CXX_PATH="$(command -v "clang++-$v")"
            return 0
        fi
    done
    return 1
}

ARGS=(-G Ninja -DCMAKE_EXPORT_COMPILE_COMMANDS=ON)
CXX_PATH=""
TARGET=()
case "$MODE" in
    release)
        DIR="$ROOT/build"
        ARGS+=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPNP_SANITIZE=OFF -DPNP_FUZZ=OFF)
        ;;
    asan)
        DIR="$ROOT/build-asan"
        FUZZ=OFF
        case "${PNP_ASAN_COMPILER:-clang}" in
            clang)
                if find_clang; then
                    FUZZ=ON
                elif [[ -n "${PNP_ASAN_COMPILER:-}" ]]; then
                    echo "[build] ERROR: PNP_ASAN_COMPILER=clang but no clang++-19..16 (run scripts/setup.sh)" >&2
                    exit 1
                else
                    log "no clang++-19..16: the asan tree is built with g++, without fuzz targets"
                    CXX_PATH="$(command -v g++)"
                fi
                ;;
            gcc) CXX_PATH="$(command -v g++)" ;;
            *)
                echo "[build] ERROR: PNP_ASAN_COMPILER must be clang or gcc" >&2
                exit 2
                ;;
        esac
        ARGS+=(-DCMAKE_BUILD_TYPE=Debug -DPNP_SANITIZE=ON "-DPNP_FUZZ=$FUZZ" -DPNP_BUILD_BENCH=OFF)
        ARGS+=("-DCMAKE_CXX_COMPILER=$CXX_PATH")
        ;;
    fuzz)
        DIR="$ROOT/build-fuzz"
        if ! find_clang; then
            echo "[build] no clang++-19..16 found: cannot build libFuzzer targets (run scripts/setup.sh)" >&2
            exit 3
        fi
        ARGS+=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPNP_SANITIZE=ON -DPNP_FUZZ=ON
            -DPNP_BUILD_TESTS=OFF -DPNP_BUILD_BENCH=OFF)
        ARGS+=("-DCMAKE_CXX_COMPILER=$CXX_PATH")
        TARGET=(--target fuzz/all)
        ;;
    pgo)
        DIR="$ROOT/build-pgo"
        CXX_PATH="$(command -v g++)"
        ARGS+=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPNP_SANITIZE=OFF -DPNP_FUZZ=OFF
            -DPNP_BUILD_TESTS=OFF "-DCMAKE_CXX_COMPILER=$CXX_PATH")
        ;;
    *)
        echo "usage: $0 [release|asan|fuzz|pgo]" >&2
        exit 2
        ;;
esac

# A tree configured with another compiler or generator cannot be reconfigured in place.
if [[ -f "$DIR/CMakeCache.txt" ]]; then
    stale=0
    grep -q '^CMAKE_GENERATOR:INTERNAL=Ninja$' "$DIR/CMakeCache.txt" || stale=1
    if [[ -n "$CXX_PATH" ]] && ! grep -q "^CMAKE_CXX_COMPILER:[A-Z]*=${CXX_PATH}\$" "$DIR/CMakeCache.txt"; then
        stale=1
    fi
    if ((stale)); then
        log "removing $DIR (configured with another compiler/generator)"
        rm -rf "$DIR"
    fi
fi

# shellcheck disable=SC2206
EXTRA=(${PNP_CMAKE_ARGS:-})
# Not for pgo: its objects depend on profiles outside the compiler's command line.
if [[ "${PNP_CCACHE:-auto}" != off && "$MODE" != pgo ]] && command -v ccache >/dev/null 2>&1; then
    ARGS+=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
    # Paths below the checkout hashed relative to it: another clone on the same machine (CI's)
    # hits the same cache entries.
    export CCACHE_BASEDIR="${CCACHE_BASEDIR:-$ROOT}" CCACHE_NOHASHDIR="${CCACHE_NOHASHDIR:-1}"
else
    ARGS+=(-UCMAKE_CXX_COMPILER_LAUNCHER)
fi
if (($# > 0)); then
    TARGET=(--target "$@")
fi

# Profile-guided: pnp is built instrumented, trained, and everything is built again with the
# profile, in the same tree (GCC checks a profile against the source file's path, and the
# generated sources live in the tree): each run compiles twice.
if [[ "$MODE" == pgo ]]; then
    log "configure pgo (instrumented) -> ${DIR#"$ROOT"/}"
    cmake -S "$ROOT" -B "$DIR" "${ARGS[@]}" -DPNP_BUILD_BENCH=OFF -DPNP_PGO=generate \
        "-DPNP_PGO_DIR=$DIR/pgo-profile" "${EXTRA[@]}"
    log "build the instrumented pnp (-j$JOBS)"
    cmake --build "$DIR" -j "$JOBS" --target pnp
    rm -rf "$DIR/pgo-profile"  # profiles add up: start from none
    log "train: scripts/pgo-train.sh"
    bash "$ROOT/scripts/pgo-train.sh" "$DIR/apps/pnp/pnp"
    n="$(find "$DIR/pgo-profile" -name '*.gcda' 2>/dev/null | wc -l)"
    if ((n == 0)); then
        log "ERROR: the training wrote no profile"
        exit 1
    fi
    log "$n profiles in ${DIR#"$ROOT"/}/pgo-profile"
    ARGS+=(-DPNP_BUILD_BENCH=ON -DPNP_PGO=use "-DPNP_PGO_DIR=$DIR/pgo-profile")
fi
log "configure $MODE -> ${DIR#"$ROOT"/} ${CXX_PATH:+(CXX=$CXX_PATH)}"
cmake -S "$ROOT" -B "$DIR" "${ARGS[@]}" "${EXTRA[@]}"
log "build $MODE (-j$JOBS)"
if [[ "$MODE" == fuzz ]] && [[ ! -f "$ROOT/fuzz/CMakeLists.txt" ]]; then
    log "no fuzz/CMakeLists.txt: nothing to build"
    exit 0
fi
cmake --build "$DIR" -j "$JOBS" "${TARGET[@]}"
log "ok: $MODE build in ${DIR#"$ROOT"/}"
