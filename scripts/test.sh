#!/usr/bin/env bash
# Full test run (this is what CI runs through .ci/run):
#   1. scripts/setup.sh                      (packages + npm ci)
#   2. release build  + ctest (build/); the ctest entries test_ua_client_interop and
#      test_ua_client_subscription_interop run our client against node-opcua servers
#   3. asan build     + ctest (build-asan/, clang-19: the tests and the libFuzzer targets;
#      labels bench|fuzz excluded)
#   4. every libFuzzer target of build-asan/fuzz/ for PNP_FUZZ_SECONDS each (default 60),
#      PNP_FUZZ_JOBS at a time (default: the number of cores); when the asan tree has none
#      (g++), a fuzz tree is built for them first (build-fuzz/, clang-19)
#   5. interop: node-opcua client vs node-opcua server (validates the harness);
#      node-opcua client vs `build/apps/pnp/pnp ua serve`; tshark capture of that run
# Ends with one line "N passed, N failed, N skipped" (tests, not steps) and exits
# non-zero if anything failed.
#
# Environment:
#   PNP_FUZZ_SECONDS=60        libFuzzer -max_total_time per target (0 disables fuzzing)
#   PNP_FUZZ_JOBS=N            fuzz targets run at a time (default: nproc, at least 2)
#   PNP_INTEROP=auto|on|off    auto (default): pnp interop runs when build/apps/pnp/pnp
#                              exists; on: a missing binary is a failure; off: skip
#   PNP_SKIP_ASAN=1            skip step 3
#   PNP_SKIP_SETUP=1           skip step 1
set -uo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT" || exit 1
NPROC="$(nproc)"
JOBS=$((NPROC < 2 ? 2 : NPROC))
FUZZ_SECONDS="${PNP_FUZZ_SECONDS:-60}"
FUZZ_JOBS="${PNP_FUZZ_JOBS:-$JOBS}"
[[ "$FUZZ_JOBS" =~ ^[1-9][0-9]*$ ]] || FUZZ_JOBS=$JOBS
INTEROP="${PNP_INTEROP:-auto}"
PNP_BIN="$ROOT/build/apps/pnp/pnp"
LOGS="$ROOT/build-logs"
mkdir -p "$LOGS"

PASSED=0
FAILED=0
SKIPPED=0
STEPS=()

banner() { printf '\n========== %s ==========\n' "$*"; }
step_result() { # NAME STATUS DETAIL
    STEPS+=("$(printf '%-34s %-5s %s' "$1" "$2" "${3:-}")")
}

# Every pnp process the tests start takes its certificate from one PKI folder of this run
# (secure by default, docs/security.md): fresh for each run, never the user's own folder.
export PNP_PKI="$ROOT/build-logs/pki"
rm -rf "$PNP_PKI"
# Test artifacts kept with the logs: the dashboard's screenshots (tests/dashboard).
export PNP_ARTIFACT_DIR="$ROOT/build-logs/artifacts"
rm -rf "$PNP_ARTIFACT_DIR"

# Sanitizer run-time settings for everything started from here (ctest, fuzzers).
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:strict_string_checks=1:detect_stack_use_after_return=1:check_initialization_order=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
if [[ -z "${ASAN_SYMBOLIZER_PATH:-}" ]] && command -v llvm-symbolizer >/dev/null 2>&1; then
    ASAN_SYMBOLIZER_PATH="$(command -v llvm-symbolizer)"
    export ASAN_SYMBOLIZER_PATH
fi

# run_ctest NAME BUILD_DIR [extra ctest args...]: adds the ctest counts to the totals
run_ctest() {
    local name="$1" dir="$2"
    shift 2
    local log="$LOGS/ctest-$name.log"
    banner "ctest $name"
    ctest --test-dir "$dir" --output-on-failure -j "$JOBS" --timeout 900 "$@" 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]}
    local line total=0 failed=0 skipped=0
    line="$(grep -E '[0-9]+% tests passed, [0-9]+ tests? failed out of [0-9]+' "$log" | tail -n 1)"
    if [[ -n "$line" ]]; then
        failed="$(sed -E 's/.* ([0-9]+) tests? failed out of ([0-9]+).*/\1/' <<<"$line")"
        total="$(sed -E 's/.* ([0-9]+) tests? failed out of ([0-9]+).*/\2/' <<<"$line")"
        skipped="$(sed -n '/The following tests did not run:/,/^$/p' "$log" | grep -cE '\((Skipped|Disabled)\)' || true)"
    fi
    local passed=$((total - failed - skipped))
    ((passed < 0)) && passed=0
    if [[ -z "$line" ]] && grep -q 'No tests were found' "$log"; then
        step_result "ctest $name" "WARN" "no tests found"
        return 0
    fi
    if [[ $rc -ne 0 && $failed -eq 0 ]]; then
        failed=1 # ctest itself failed (e.g. no build tree)
    fi
    PASSED=$((PASSED + passed))
    FAILED=$((FAILED + failed))
    SKIPPED=$((SKIPPED + skipped))
    if [[ $rc -eq 0 ]]; then
        step_result "ctest $name" "ok" "$passed passed, $skipped skipped"
    else
        step_result "ctest $name" "FAIL" "$passed passed, $failed failed, $skipped skipped"
    fi
}

# run_build MODE -> 0 on success; a failed build counts as one failed test
run_build() {
    local mode="$1"
    banner "build $mode"
    if bash "$ROOT/scripts/build.sh" "$mode" 2>&1 | tee "$LOGS/build-$mode.log"; then
        step_result "build $mode" "ok"
        return 0
    fi
    FAILED=$((FAILED + 1))
    step_result "build $mode" "FAIL" "see $LOGS/build-$mode.log"
    return 1
}

# client_counts FILE: prints "P F S" from the last
# "node_client: P passed, F failed, S skipped" line of FILE (fails if none)
client_counts() {
    local line
    line="$(grep -E '^node_client: [0-9]+ passed, [0-9]+ failed, [0-9]+ skipped' "$1" | tail -n 1)"
    [[ -n "$line" ]] || return 1
    sed -E 's/^node_client: ([0-9]+) passed, ([0-9]+) failed, ([0-9]+) skipped.*/\1 \2 \3/' <<<"$line"
}

# run_interop NAME LOG CMD...: runs a node_client-based script; counts its checks
run_interop() {
    local name="$1" log="$2"
    shift 2
    banner "$name"
    timeout -k 10 180 "$@" 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]} counts p f s
    if counts="$(client_counts "$log")"; then
        read -r p f s <<<"$counts"
        PASSED=$((PASSED + p))
        FAILED=$((FAILED + f))
        SKIPPED=$((SKIPPED + s))
        if [[ $rc -ne 0 && $f -eq 0 ]]; then
            FAILED=$((FAILED + 1)) # the runner failed outside the client's checks
        fi
        counts="$p passed, $f failed, $s skipped"
    else
        if [[ $rc -eq 0 ]]; then PASSED=$((PASSED + 1)); else FAILED=$((FAILED + 1)); fi
        counts="exit $rc"
    fi
    step_result "$name" "$([[ $rc -eq 0 ]] && echo ok || echo FAIL)" "$counts"
}

# ---------------------------------------------------------------------------------
# 1. setup
# ---------------------------------------------------------------------------------
if [[ "${PNP_SKIP_SETUP:-0}" != "1" ]]; then
    banner "setup"
    if ! bash "$ROOT/scripts/setup.sh"; then
        echo "setup failed"
        echo "0 passed, 1 failed"
        exit 1
    fi
fi

# ---------------------------------------------------------------------------------
# 2. release
# ---------------------------------------------------------------------------------
RELEASE_OK=0
if run_build release; then
    RELEASE_OK=1
    run_ctest release "$ROOT/build"
fi

# ---------------------------------------------------------------------------------
# 3. asan
# ---------------------------------------------------------------------------------
if [[ "${PNP_SKIP_ASAN:-0}" == "1" ]]; then
    step_result "asan" "skip" "PNP_SKIP_ASAN=1"
elif run_build asan; then
    # Not the `scenario` tests (the whole cell in real time, tests/cell/CMakeLists.txt): -O0
    # with ASan cannot keep the simulated world's 500 Hz pace; the release tree runs them.
    run_ctest asan "$ROOT/build-asan" -LE 'bench|fuzz|scenario'
fi

# ---------------------------------------------------------------------------------
# 4. fuzzing: the libFuzzer targets of the asan tree (clang builds them there), else of a
#    fuzz tree built for them; FUZZ_JOBS targets at a time, each for FUZZ_SECONDS
# ---------------------------------------------------------------------------------
banner "fuzz"
# fuzz_targets DIR: the fuzz executables built in DIR
fuzz_targets() {
    find "$1/fuzz" -maxdepth 1 -type f -perm -u+x -name 'fuzz_*' 2>/dev/null | sort
}
# run_fuzzer EXE CORPUS_ROOT: one libFuzzer run; its exit code in $LOGS/fuzz-NAME.rc
run_fuzzer() {
    local fz="$1" name corpus artifacts seeds=() d
    name="$(basename "$fz")"
    corpus="$2/corpus/$name"
    artifacts="$2/artifacts"
    mkdir -p "$corpus" "$artifacts"
    for d in "$ROOT/fuzz/corpus/$name" "$ROOT/fuzz/$name" "$ROOT/tests/fuzz/corpus/$name"; do
        [[ -d "$d" ]] && seeds+=("$d")
    done
    echo "running $name for ${FUZZ_SECONDS}s (corpus $corpus${seeds[*]:+, seeds: ${seeds[*]}})"
    timeout -k 10 $((FUZZ_SECONDS + 120)) "$fz" -max_total_time="$FUZZ_SECONDS" -timeout=10 \
        -rss_limit_mb=4096 -print_final_stats=1 -artifact_prefix="$artifacts/$name-" \
        "$corpus" "${seeds[@]}" >"$LOGS/fuzz-$name.log" 2>&1
    echo $? >"$LOGS/fuzz-$name.rc"
}
if [[ "$FUZZ_SECONDS" == "0" ]]; then
    echo "fuzzing disabled (PNP_FUZZ_SECONDS=0)"
    step_result "fuzz" "skip" "disabled"
else
    FUZZ_TREE=""
    if [[ -n "$(fuzz_targets "$ROOT/build-asan")" ]]; then
        FUZZ_TREE="$ROOT/build-asan"
        echo "fuzz targets of the asan tree (build-asan/fuzz)"
    else
        bash "$ROOT/scripts/build.sh" fuzz 2>&1 | tee "$LOGS/build-fuzz.log"
        rc=${PIPESTATUS[0]}
        if [[ $rc -eq 0 ]]; then
            FUZZ_TREE="$ROOT/build-fuzz"
            step_result "build fuzz (clang)" "ok"
        elif [[ $rc -eq 3 ]]; then
            echo "no usable clang: fuzz targets not built"
            step_result "build fuzz (clang)" "skip" "no clang >= 16"
        else
            FAILED=$((FAILED + 1))
            step_result "build fuzz (clang)" "FAIL" "see $LOGS/build-fuzz.log"
        fi
    fi
    FUZZERS=()
    [[ -n "$FUZZ_TREE" ]] && mapfile -t FUZZERS < <(fuzz_targets "$FUZZ_TREE")
    if [[ -n "$FUZZ_TREE" ]] && ((${#FUZZERS[@]} == 0)); then
        echo "no fuzz target in $FUZZ_TREE/fuzz: skipping"
        step_result "fuzz" "skip" "no fuzz target"
    fi
    # Each libFuzzer run is one process on one core.
    for ((i = 0; i < ${#FUZZERS[@]}; i += FUZZ_JOBS)); do
        for fz in "${FUZZERS[@]:i:FUZZ_JOBS}"; do
            rm -f "$LOGS/fuzz-$(basename "$fz").rc"
            run_fuzzer "$fz" "$FUZZ_TREE" &
        done
        wait
    done
    for fz in "${FUZZERS[@]}"; do
        name="$(basename "$fz")"
        rc="$(cat "$LOGS/fuzz-$name.rc" 2>/dev/null || echo 1)"
        echo "--- $name (exit $rc)"
        tail -n 15 "$LOGS/fuzz-$name.log"
        if [[ "$rc" == 0 ]]; then
            PASSED=$((PASSED + 1))
            step_result "fuzz $name" "ok" "${FUZZ_SECONDS}s"
        else
            FAILED=$((FAILED + 1))
            step_result "fuzz $name" "FAIL" "exit $rc, artifacts in $FUZZ_TREE/artifacts, log $LOGS/fuzz-$name.log"
        fi
    done
fi

# ---------------------------------------------------------------------------------
# 5. interop (node-opcua)
# ---------------------------------------------------------------------------------
# shellcheck source=../tests/interop/lib.sh
source "$ROOT/tests/interop/lib.sh"
if [[ "$INTEROP" == "off" ]]; then
    step_result "interop" "skip" "PNP_INTEROP=off"
else
    run_interop "interop node client vs node server" "$LOGS/interop-node-self.log" \
        bash "$ROOT/tests/interop/run_node_self_test.sh" "$(free_port 28500)"

    if [[ $RELEASE_OK -eq 1 && -x "$PNP_BIN" ]]; then
        run_interop "interop node client vs pnp" "$LOGS/interop-node-vs-pnp.log" \
            bash "$ROOT/tests/interop/run_node_client_vs_pnp.sh" "$PNP_BIN" "$(free_port 28520)"

        run_interop "interop node subscriber vs pnp" "$LOGS/interop-node-subscriber-vs-pnp.log" \
            bash "$ROOT/tests/interop/run_node_client_vs_pnp.sh" "$PNP_BIN" "$(free_port 28560)" \
            node_subscriber.js

        banner "tshark capture of pnp"
        if PNP_CAPTURE_DIR="$LOGS/capture" timeout -k 10 180 \
            bash "$ROOT/tests/interop/capture_tshark.sh" "$PNP_BIN" "$(free_port 28540)" \
            2>&1 | tee "$LOGS/capture-tshark.log"; then
            PASSED=$((PASSED + 1))
            step_result "tshark capture of pnp" "ok"
        else
            FAILED=$((FAILED + 1))
            step_result "tshark capture of pnp" "FAIL" "see $LOGS/capture"
        fi
    elif [[ "$INTEROP" == "on" ]]; then
        echo "$PNP_BIN missing (PNP_INTEROP=on)"
        FAILED=$((FAILED + 1))
        step_result "interop vs pnp" "FAIL" "$PNP_BIN missing"
    elif [[ $RELEASE_OK -ne 1 ]]; then
        echo "release build failed: skipping interop against pnp"
        step_result "interop vs pnp" "skip" "release build failed"
    else
        echo "$PNP_BIN not built: skipping interop against pnp"
        step_result "interop vs pnp" "skip" "no $PNP_BIN"
    fi
fi

# ---------------------------------------------------------------------------------
# summary
# ---------------------------------------------------------------------------------
banner "summary"
printf '%s\n' "${STEPS[@]}"
echo
echo "$PASSED passed, $FAILED failed, $SKIPPED skipped"
[[ $FAILED -eq 0 ]]
