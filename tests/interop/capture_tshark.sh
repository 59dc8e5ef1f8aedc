#!/usr/bin/env bash
# Capture our server's traffic with tshark and check that Wireshark's OPC UA
# dissector decodes every packet cleanly.
#
# usage: tests/interop/capture_tshark.sh PNP_BINARY PORT
#
#   1. tshark captures on lo with capture filter "tcp port PORT" to a pcap
#   2. starts `PNP_BINARY ua serve --port PORT` (with the Robotics test model), runs
#      node_client.js against it
#   3. stops server and tshark by PID
#   4. decodes the pcap with `-d tcp.port==PORT,opcua` and FAILS if
#        - any packet is Malformed or carries an Expert Info of severity Error
#        - a TCP segment with payload is neither OPC UA nor part of a reassembled PDU
#          (retransmissions aside: their bytes were decoded in the original frame)
#        - the Info column names an unknown service
#        - fewer than PNP_CAPTURE_MIN_PACKETS (default 20) OPC UA packets were seen
#        - Hello or Acknowledge is missing
#      and prints a summary of the message types seen.
#   The node_client result is reported but does not decide the exit status
#   (run_node_client_vs_pnp.sh covers that); set PNP_CAPTURE_REQUIRE_CLIENT_OK=1
#   to make a client failure fatal here too.
#
# Needs root (or capture rights) for tshark. Output (pcap, decoded text, logs) goes
# to $PNP_CAPTURE_DIR (default: a new temp dir), kept for inspection.
set -uo pipefail
export INTEROP_NAME=capture-tshark
# shellcheck source=lib.sh
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"

if [[ $# -lt 2 ]]; then
    echo "usage: $0 PNP_BINARY PORT" >&2
    exit 2
fi
PNP_BINARY="$1"
PORT="$2"
MIN_PACKETS="${PNP_CAPTURE_MIN_PACKETS:-20}"

if [[ ! -x "$PNP_BINARY" ]]; then
    ilog "not an executable: $PNP_BINARY"
    exit 2
fi
if ! command -v tshark >/dev/null 2>&1; then
    ilog "tshark not installed (scripts/setup.sh installs it)"
    exit 2
fi
if [[ "$(id -u)" != "0" ]]; then
    ilog "warning: not root; capturing on lo may fail"
fi
require_node_modules || exit 2
if port_listening "$PORT"; then
    ilog "port $PORT is already in use"
    exit 2
fi

OUT="${PNP_CAPTURE_DIR:-$(mktemp -d /tmp/pnp-capture.XXXXXX)}"
mkdir -p "$OUT"
PCAP="$OUT/opcua-$PORT.pcap"
rm -f "$PCAP"

TSHARK_PID=""
SERVER_PID=""
# shellcheck disable=SC2317 # invoked via trap
cleanup() {
    local rc=$?
    [[ -n "$SERVER_PID" ]] && stop_pid "$SERVER_PID" TERM 5
    [[ -n "$TSHARK_PID" ]] && stop_pid "$TSHARK_PID" INT 5
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# ---- 1. capture ---------------------------------------------------------------------
ilog "tshark -i lo -f 'tcp port $PORT' -w $PCAP"
tshark -i lo -f "tcp port $PORT" -w "$PCAP" -q >"$OUT/tshark-capture.log" 2>&1 </dev/null &
TSHARK_PID=$!
if ! wait_for_line "$OUT/tshark-capture.log" "Capture started|Capturing on" 10 "$TSHARK_PID"; then
    cat "$OUT/tshark-capture.log" >&2
    echo "not ok - tshark capture on lo"
    exit 1
fi
# "Capturing on" can precede the actual start by a little: give dumpcap a moment.
wait_for_line "$OUT/tshark-capture.log" "Capture started" 2 "$TSHARK_PID" 2>/dev/null || true
sleep 0.5

# ---- 2. server + client ---------------------------------------------------------------
"$PNP_BINARY" ua serve --port "$PORT" --no-register --allow-none --user operator:secret "${ROBOTICS_SERVE_ARGS[@]}" \
    >"$OUT/pnp-server.log" 2>&1 </dev/null &
SERVER_PID=$!
client_rc=99
if wait_for_port "$PORT" 10 "$SERVER_PID"; then
    timeout -k 5 70 node "$INTEROP_DIR/node_client.js" "opc.tcp://127.0.0.1:$PORT" \
        >"$OUT/node-client.out" 2>"$OUT/node-client.stderr"
    client_rc=$?
else
    ilog "server did not come up; its output:"
    tail -n 30 "$OUT/pnp-server.log" >&2
fi

# ---- 3. stop everything by PID --------------------------------------------------------
stop_pid "$SERVER_PID" TERM 5
SERVER_PID=""
sleep 0.5 # let the FIN/RST packets reach the capture
stop_pid "$TSHARK_PID" INT 5
TSHARK_PID=""

client_summary="$(grep -E '^node_client: ' "$OUT/node-client.out" 2>/dev/null | tail -n 1)"
ilog "node_client exit code $client_rc ${client_summary:+($client_summary)}"
if [[ $client_rc -ne 0 && -f "$OUT/node-client.out" ]]; then
    grep -E '^not ok' "$OUT/node-client.out" | head -n 20 >&2
fi

if [[ ! -s "$PCAP" ]]; then
    echo "not ok - capture file $PCAP is empty or missing"
    exit 1
fi

# ---- 4. decode + checks ---------------------------------------------------------------
# Two passes (-2): a chunk larger than one TCP segment is reassembled from several frames,
# and only the second pass marks the earlier ones with tcp.reassembled_in.
DECODE=(-2 -r "$PCAP" -d "tcp.port==$PORT,opcua")
tshark "${DECODE[@]}" -V >"$OUT/decoded.txt" 2>"$OUT/tshark-decode.stderr"
tshark "${DECODE[@]}" -Y opcua -T fields -e frame.number -e _ws.col.Info \
    >"$OUT/opcua-info.tsv" 2>>"$OUT/tshark-decode.stderr"

fail=0
total_frames="$(tshark -r "$PCAP" 2>/dev/null | wc -l)"
opcua_packets="$(wc -l <"$OUT/opcua-info.tsv")"

malformed="$(grep -c 'Malformed' "$OUT/decoded.txt" || true)"
expert_err="$(grep -c 'Expert Info (Error' "$OUT/decoded.txt" || true)"
expert_warn="$(grep -c 'Expert Info (Warning' "$OUT/decoded.txt" || true)"
bad_frames="$(tshark "${DECODE[@]}" -Y '_ws.malformed || _ws.expert.severity == error' \
    -T fields -e frame.number 2>/dev/null | tr '\n' ' ')"
# A retransmitted segment repeats bytes already decoded in the original frame (the kernel
# retransmits on loopback too, e.g. after a full window under CPU load): not counted.
undecoded="$(tshark "${DECODE[@]}" -Y 'tcp.len > 0 && !opcua && !tcp.reassembled_in &&
        !tcp.analysis.retransmission && !tcp.analysis.fast_retransmission &&
        !tcp.analysis.spurious_retransmission' \
    -T fields -e frame.number 2>>"$OUT/tshark-decode.stderr" | tr '\n' ' ')" ||
    { echo "not ok - tshark could not apply the undecoded-payload filter"; fail=1; }
unknown="$(grep -ci 'unknown' "$OUT/opcua-info.tsv" || true)"

echo "capture: $PCAP ($total_frames frames, $opcua_packets OPC UA packets)"
echo "message types seen:"
# Info looks like "UA Secure Conversation Message: ReadRequest" or "Hello message";
# one frame can carry several messages, separated by ", ".
cut -f2 "$OUT/opcua-info.tsv" | tr ',' '\n' | sed -E 's/^ +//; s/^.*: //; s/ message$//' |
    grep -v '^$' | sort | uniq -c | sort -rn | sed 's/^/  /'

if ((malformed > 0 || expert_err > 0)) || [[ -n "${bad_frames// /}" ]]; then
    echo "not ok - malformed packets / expert errors: Malformed=$malformed ExpertError=$expert_err frames: ${bad_frames:-?}"
    grep -n -B2 -A2 -E 'Malformed|Expert Info \(Error' "$OUT/decoded.txt" | head -n 40
    fail=1
else
    echo "ok - no Malformed packet, no Expert Info (Error) ($expert_warn warnings)"
fi
if [[ -n "${undecoded// /}" ]]; then
    echo "not ok - TCP payload not decoded as OpcUa in frames: $undecoded"
    fail=1
else
    echo "ok - every TCP payload decoded as OpcUa"
fi
if ((unknown > 0)); then
    echo "not ok - $unknown packets with an unknown service/message type:"
    grep -i 'unknown' "$OUT/opcua-info.tsv" | head -n 10
    fail=1
else
    echo "ok - no unknown service types"
fi
if ((opcua_packets < MIN_PACKETS)); then
    echo "not ok - only $opcua_packets OPC UA packets (expected >= $MIN_PACKETS)"
    fail=1
else
    echo "ok - $opcua_packets OPC UA packets (>= $MIN_PACKETS)"
fi
for m in "Hello" "Acknowledge"; do
    if ! awk -F'\t' -v m="$m message" '$2 == m { found = 1 } END { exit !found }' "$OUT/opcua-info.tsv"; then
        echo "not ok - no $m message in the capture"
        fail=1
    fi
done
if [[ "${PNP_CAPTURE_REQUIRE_CLIENT_OK:-0}" == "1" && $client_rc -ne 0 ]]; then
    echo "not ok - node_client failed (exit $client_rc)"
    fail=1
fi

echo "capture artifacts: $OUT"
exit "$fail"
