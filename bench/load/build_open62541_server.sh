#!/usr/bin/env bash
# Builds open62541's side of bench/load (o6_load_server.c) against an open62541 source tree
# built beside the project — never part of this repository. For example:
#
#   git clone -b v1.5.7 https://github.com/open62541/open62541 ../open62541
#   cmake -S ../open62541 -B ../open62541/build -G Ninja -DCMAKE_BUILD_TYPE=Release \
#         -DUA_NAMESPACE_ZERO=REDUCED -DUA_ENABLE_ENCRYPTION=OFF -DUA_LOGLEVEL=400
#   ninja -C ../open62541/build
#   bash bench/load/build_open62541_server.sh ../open62541 ../open62541/build /tmp/o6_load_server
#
# usage: build_open62541_server.sh SOURCE_DIR BUILD_DIR OUTPUT
set -euo pipefail
[[ $# -eq 3 ]] || { sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 2; }
src="$1" build="$2" out="$3"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
lib="$build/bin/libopen62541.a"
[[ -f "$lib" ]] || { echo "no $lib: build open62541 first" >&2; exit 2; }
cc -O2 -std=c11 -D_POSIX_C_SOURCE=200809L -Wall \
    -I"$src/include" -I"$src/plugins/include" -I"$src/arch" -I"$build/src_generated" \
    "$here/o6_load_server.c" "$lib" -lpthread -lm -o "$out"
echo "built $out"
