#!/usr/bin/env bash
# Build-time benchmark (not run in CI): how long a clean build takes, how long a rebuild takes
# after touching one widely used header, and where the time goes (per target, per file).
#
#   bash scripts/build-times.sh [MODE] [--target T] [--touch FILE] [--dir DIR] [--keep]
#
#   MODE      release (default), asan: the flags of scripts/build.sh MODE
#   --target  build only T (e.g. pnp, the main job's executable); default: everything
#   --touch   header touched before the rebuild (default src/ua/types/builtin.hpp)
#   --dir     build tree (default: a fresh directory under /tmp, removed at the end)
#   --keep    keep the build tree
#
# ccache is disabled for the measurement (CCACHE_DISABLE=1): the figures are those of a
# machine that never built the project. Prints the clean and the rebuild wall time, then the
# 25 slowest translation units and the compile time summed per target, from .ninja_log.
# The machine should be otherwise idle: the figures are wall-clock times on all its cores.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
MODE=release
TARGET=()
TOUCH="src/ua/types/builtin.hpp"
DIR=""
KEEP=0
while (($#)); do
    case "$1" in
        release | asan) MODE="$1" ;;
        --target) TARGET=(--target "$2"); shift ;;
        --touch) TOUCH="$2"; shift ;;
        --dir) DIR="$2"; shift ;;
        --keep) KEEP=1 ;;
        -h | --help) sed -n '2,17p' "$0"; exit 0 ;;
        *) echo "unknown argument: $1 (see --help)" >&2; exit 2 ;;
    esac
    shift
done
[[ -f "$ROOT/$TOUCH" ]] || { echo "no such file: $ROOT/$TOUCH" >&2; exit 2; }
if [[ -z "$DIR" ]]; then
    DIR="$(mktemp -d /tmp/pnp-build-times.XXXXXX)"
else
    rm -rf "$DIR"
fi
cleanup() { ((KEEP)) || rm -rf "$DIR"; }
trap cleanup EXIT

export CCACHE_DISABLE=1
case "$MODE" in
    release) FLAGS=(-DCMAKE_BUILD_TYPE=RelWithDebInfo -DPNP_SANITIZE=OFF) ;;
    asan) FLAGS=(-DCMAKE_BUILD_TYPE=Debug -DPNP_SANITIZE=ON -DPNP_BUILD_BENCH=OFF) ;;
esac
now() { date +%s.%N; }
secs() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.1f", b - a }'; }

echo "[build-times] $MODE${TARGET[1]:+ --target ${TARGET[1]}} in $DIR ($(nproc) cores, $(g++ -dumpfullversion))"
t0="$(now)"
cmake -S "$ROOT" -B "$DIR" -G Ninja -DPNP_FUZZ=OFF "${FLAGS[@]}" >"$DIR.configure.log" 2>&1 ||
    { cat "$DIR.configure.log"; exit 1; }
t1="$(now)"
cmake --build "$DIR" -j "$(nproc)" "${TARGET[@]}" >"$DIR.build.log" 2>&1 ||
    { tail -n 40 "$DIR.build.log"; exit 1; }
t2="$(now)"
cp "$DIR/.ninja_log" "$DIR.clean.ninja_log"
steps_clean="$(grep -c '^\[' "$DIR.build.log" || true)"

touch "$ROOT/$TOUCH"
t3="$(now)"
cmake --build "$DIR" -j "$(nproc)" "${TARGET[@]}" >"$DIR.rebuild.log" 2>&1 ||
    { tail -n 40 "$DIR.rebuild.log"; exit 1; }
t4="$(now)"
steps_rebuild="$(grep -c '^\[' "$DIR.rebuild.log" || true)"

# Per file and per target, from the clean build's log (ms start, ms end, mtime, output).
echo
echo "slowest translation units of the clean build (s, wall, $(nproc) jobs in parallel):"
awk -F'\t' 'NR > 1 && $4 ~ /\.o$/ { printf "%7.1f  %s\n", ($2 - $1) / 1000, $4 }' \
    "$DIR.clean.ninja_log" | sort -rn | head -n 25
echo
echo "compile time per target (s, summed over its files; files):"
awk -F'\t' 'NR > 1 && $4 ~ /\.o$/ {
        t = $4; sub(/\.dir\/.*/, "", t); n = split(t, p, "/"); t = p[n]
        s[t] += ($2 - $1) / 1000; c[t]++; total += ($2 - $1) / 1000; files++ }
    END { for (k in s) printf "%7.1f  %3d  %s\n", s[k], c[k], k
          printf "%7.1f  %3d  (all)\n", total, files }' "$DIR.clean.ninja_log" | sort -rn
rm -f "$DIR.configure.log" "$DIR.build.log" "$DIR.rebuild.log" "$DIR.clean.ninja_log"
echo
echo "configure:                   $(secs "$t0" "$t1") s"
echo "clean build:                 $(secs "$t1" "$t2") s ($steps_clean steps)"
echo "rebuild after touching $TOUCH: $(secs "$t3" "$t4") s ($steps_rebuild steps)"
