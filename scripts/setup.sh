#!/usr/bin/env bash
# Installs everything the project needs on Debian bookworm (run as root), then
# the npm test tooling (node-opcua) from package-lock.json.
#
# Idempotent and fast when everything is already there: one dpkg-query for the
# Debian packages, a checksum stamp for node_modules.
#
#   PNP_SKIP_APT=1   do not touch Debian packages (only check / npm)
#   PNP_SKIP_NPM=1   do not run npm ci
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
log() { printf '[setup] %s\n' "$*"; }

# ---------------------------------------------------------------------------------
# Debian packages
# ---------------------------------------------------------------------------------
PACKAGES=(
    # toolchain
    build-essential g++ cmake ninja-build pkg-config git python3
    # repeated builds on one machine (scripts/build.sh uses it when present; never required)
    ccache
    # the LLVM linker (CMakeLists.txt uses it when usable: links 4x faster than GNU ld)
    lld
    # clang 14 (Debian default) + its sanitizer/libFuzzer runtime, LLVM tools
    # (llvm-symbolizer for sanitizer stack traces)
    clang libclang-rt-14-dev llvm
    # clang 19: clang 14 cannot compile libstdc++-12's <ranges> views, so the
    # asan/fuzz build uses clang-19 (libFuzzer + ASan runtime in libclang-rt-19-dev)
    clang-19 libclang-rt-19-dev
    # libraries
    libasio-dev libpugixml-dev libssl-dev libfmt-dev libspdlog-dev libcli11-dev
    # the openssl command line: the independent peer of the crypto and PKI tests
    openssl
    nlohmann-json3-dev libgtest-dev libgmock-dev libbenchmark-dev
    # robot kinematics and motion (src/kinematics, src/motion): KDL chains from DH tables or
    # URDF, Eigen for poses
    liborocos-kdl-dev libkdl-parser-dev liburdfdom-dev libeigen3-dev
    # the cell description file (src/world): YAML with the line of every node, for errors
    libyaml-cpp-dev
    # the tools' adapters (src/device/robotiq, src/device/ecbpi): Modbus RTU / TCP clients;
    # the simulators implement the device side themselves (src/modbus), so both sides are
    # independent implementations of the protocol
    libmodbus-dev
    # interop / capture / process tools
    tshark iproute2 procps util-linux
    # discovery interop (tests/discovery/discovery_interop_netns_test.cpp): avahi in a
    # network namespace on a private system bus
    avahi-daemon avahi-utils dbus
    # middleware evaluation (pnp bench middleware, docs/middleware_bench.md): the peers
    # each adapter links, the ROS master, load generators and the plotter
    mosquitto libpaho-mqtt-dev libfastrtps-dev libfastcdr-dev
    libroscpp-dev libstd-msgs-dev python3-rosmaster
    stress-ng iperf3 gnuplot-nox
    # the knowledge base (src/kb, docs/knowledge-base.md): Turtle parsing (serd), the SPARQL
    # endpoint client (libcurl), and Virtuoso, the real SPARQL server tests/kb runs against
    libserd-dev libcurl4-openssl-dev virtuoso-opensource
    # the live dashboard (src/dashboard, web/dashboard): HTTP + WebSocket server (websocketpp
    # on standalone asio) and the headless browser its page is tested in (puppeteer-core)
    libwebsocketpp-dev chromium
)

# Node.js: the machine image ships nodesource's nodejs (which bundles npm and
# conflicts with Debian's npm package). Only ask Debian for nodejs+npm when there
# is no node/npm at all.
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
    PACKAGES+=(nodejs npm)
fi

missing_packages() {
    # prints the packages of PACKAGES that are not fully installed
    local installed
    installed="$(dpkg-query -W -f='${Package} ${db:Status-Status}\n' "${PACKAGES[@]}" 2>/dev/null |
        awk '$2 == "installed" { print $1 }' || true)"
    local p
    for p in "${PACKAGES[@]}"; do
        # dpkg-query prints names without ":arch"; g++ etc. contain regex chars, use -F
        if ! grep -qxF -- "$p" <<<"$installed"; then
            printf '%s\n' "$p"
        fi
    done
}

if [[ "${PNP_SKIP_APT:-0}" != "1" ]]; then
    mapfile -t MISSING < <(missing_packages)
    if ((${#MISSING[@]} == 0)); then
        log "Debian packages: all ${#PACKAGES[@]} present"
    else
        log "Debian packages missing: ${MISSING[*]}"
        if [[ "$(id -u)" != "0" ]]; then
            echo "[setup] ERROR: need root to apt-get install: ${MISSING[*]}" >&2
            exit 1
        fi
        export DEBIAN_FRONTEND=noninteractive
        # tshark: do not ask whether non-root users may capture
        echo "wireshark-common wireshark-common/install-setuid boolean false" | debconf-set-selections
        APT_OPTS=(-y -q -o DPkg::Lock::Timeout=600 -o Dpkg::Options::=--force-confdef -o Dpkg::Options::=--force-confold)
        log "apt-get update"
        apt-get -q -o DPkg::Lock::Timeout=600 update
        log "apt-get install ${MISSING[*]}"
        apt-get install "${APT_OPTS[@]}" --no-install-recommends "${MISSING[@]}"
        mapfile -t STILL < <(missing_packages)
        if ((${#STILL[@]} != 0)); then
            echo "[setup] ERROR: still missing after install: ${STILL[*]}" >&2
            exit 1
        fi
    fi
fi

# ---------------------------------------------------------------------------------
# npm tooling (node-opcua for the interop tests)
# ---------------------------------------------------------------------------------
if [[ "${PNP_SKIP_NPM:-0}" != "1" ]]; then
    cd "$ROOT"
    STAMP="node_modules/.pnp-setup.stamp"
    want="$( (cat package.json package-lock.json; node --version) | sha256sum | cut -d' ' -f1)"
    have="$(cat "$STAMP" 2>/dev/null || true)"
    if [[ -d node_modules && "$want" == "$have" ]]; then
        log "node_modules up to date with package-lock.json"
    else
        log "npm ci"
        npm ci --no-audit --no-fund --loglevel=error
        printf '%s\n' "$want" >"$STAMP"
    fi
fi

log "done"
