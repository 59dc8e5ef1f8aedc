// Published values of the thesis (chapter 4.4 Table 4.2, chapter 4.5 Table 4.3), shown next to
// ours. The thesis measured on two machines over Gigabit Ethernet, we on one over loopback.
#pragma once

#include <string>
#include <vector>

namespace pnp::bench::report::thesis {

// Table 4.3: average RTT in µs; columns are the payload sizes 2, 4, ..., 32768.
struct RttRow {
    std::string mode;            // "echo" | "ack"
    std::string middleware;      // as printed in the thesis
    std::string load;            // "idle" | "cpu" | "net"
    std::vector<double> meanUs;  // 15 values; a value < 0: not legible in the source text
};
const std::vector<int>& table43Sizes();
const std::vector<RttRow>& table43();
// Why a row has fewer legible values than columns (empty if every row is complete).
const char* table43Note();

// Table 4.2: TCP/UDP payload bytes per message for payloads 0, 100, 1000, 10000 bytes and the
// bytes of connection establishment + shutdown.
struct OverheadRow {
    std::string middleware;
    int bytes[4];
    int connection;
};
const std::vector<int>& table42Payloads();
const std::vector<OverheadRow>& table42();

}  // namespace pnp::bench::report::thesis
