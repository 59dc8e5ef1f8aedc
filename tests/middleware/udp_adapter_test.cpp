// pnp-mw-udp: server and client as processes on loopback; every payload size intact; lost
// requests are retransmitted and late answers discarded; a chain; no server, a clear reason.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cstring>
#include <fstream>
#include <regex>
#include <thread>

#include "adapter_test.hpp"

using pnp::testing::ChildProcess;
using pnp::testing::runClient;
using pnp::testing::testLog;

namespace {

const std::string kExe = PNP_MW_ADAPTER;

void roundTrip(const std::string& mode) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    ChildProcess server;
    std::string err;
    ASSERT_TRUE(
        server.start({kExe, "server", "--mode", mode, "--port", port}, testLog("udp_server"), err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(10), err)) << err;
    auto r = runClient({kExe, "client", "--mode", mode, "--port", port, "--reps", "20", "--warmup",
                        "2", "--sizes", "0,1,2,1000,32768,65499"},
                       60, testLog("udp_client"));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 6u);  // one summary per size
    EXPECT_NE(r.lines[4].find("\"payload\":32768"), std::string::npos) << r.lines[4];
    EXPECT_NE(r.lines[4].find("\"n\":20"), std::string::npos) << r.lines[4];
    EXPECT_NE(r.lines[5].find("\"payload\":65499"), std::string::npos) << r.lines[5];
    EXPECT_NE(r.log.find("retransmissions"), std::string::npos) << r.log;
}

}  // namespace

TEST(MiddlewareUdp, EchoRoundTripsEveryPayloadIntact) { roundTrip("echo"); }
TEST(MiddlewareUdp, AckAnswersEveryPayloadWithOneByte) { roundTrip("ack"); }

TEST(MiddlewareUdp, PayloadLargerThanOneDatagramIsRefusedWithAReason) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    ChildProcess server;
    std::string err;
    ASSERT_TRUE(server.start({kExe, "server", "--mode", "echo", "--port", port},
                             testLog("udp_server_big"), err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(10), err)) << err;
    auto r = runClient(
        {kExe, "client", "--port", port, "--reps", "1", "--warmup", "0", "--sizes", "65500"}, 30,
        testLog("udp_big"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("does not fit into one UDP datagram"), std::string::npos) << r.log;
}

// A fake server on a thread of the test: it ignores the first copy of every request and
// answers the retransmission twice, first with the previous request's sequence number (a
// late answer the client must discard), then correctly.
TEST(MiddlewareUdp, LostRequestsAreRetransmittedAndLateAnswersDiscarded) {
    int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    ASSERT_GE(fd, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    socklen_t len = sizeof a;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    timeval tv{0, 100000};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    std::atomic<bool> stop{false};
    std::thread fake([&] {
        std::vector<unsigned char> buf(70000);
        std::uint64_t lastIgnored = 0;
        while (!stop) {
            sockaddr_in from{};
            socklen_t fl = sizeof from;
            const ssize_t n =
                ::recvfrom(fd, buf.data(), buf.size(), 0, reinterpret_cast<sockaddr*>(&from), &fl);
            if (n < 8) continue;
            std::uint64_t seq = 0;
            std::memcpy(&seq, buf.data(), 8);  // little-endian on every machine we run on
            if (seq != lastIgnored) {
                lastIgnored = seq;  // "lost"
                continue;
            }
            std::vector<unsigned char> stale(buf.begin(), buf.begin() + n);
            const std::uint64_t old = seq - 1;
            std::memcpy(stale.data(), &old, 8);
            ::sendto(fd, stale.data(), stale.size(), 0, reinterpret_cast<sockaddr*>(&from), fl);
            ::sendto(fd, buf.data(), static_cast<std::size_t>(n), 0,
                     reinterpret_cast<sockaddr*>(&from), fl);
        }
    });
    auto r = runClient({kExe, "client", "--mode", "echo", "--port",
                        std::to_string(ntohs(a.sin_port)), "--reps", "5", "--warmup", "0",
                        "--sizes", "2,1000", "--set", "retransmit-ms=50", "--timeout-ms", "2000"},
                       30, testLog("udp_retransmit"));
    stop = true;
    fake.join();
    ::close(fd);
    ASSERT_EQ(r.exitCode, 0) << r.log;
    // At least one retransmission and one discarded stale answer per request (more when the
    // machine is so slow that the answer takes longer than the retransmission interval).
    std::smatch m;
    ASSERT_TRUE(std::regex_search(
        r.log, m, std::regex("([0-9]+) retransmissions, ([0-9]+) late or foreign datagrams")))
        << r.log;
    EXPECT_GE(std::stoi(m[1]), 10) << r.log;
    EXPECT_GE(std::stoi(m[2]), 10) << r.log;
}

TEST(MiddlewareUdp, ChainCarriesThreeStreamsThroughTheNodes) {
    std::string err;
    auto r = pnp::testing::runSmallChain(kExe, "udp", 10, err);
    ASSERT_TRUE(err.empty()) << err;
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 1u);
    EXPECT_NE(r.lines[0].find("\"n\":10"), std::string::npos) << r.lines[0];
}

TEST(MiddlewareUdp, ClientWithoutServerFailsWithAReasonWithinItsTimeout) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    const auto t0 = std::chrono::steady_clock::now();
    auto r = runClient({kExe, "client", "--port", port, "--timeout-ms", "300"}, 30,
                       testLog("udp_noserver"));
    const auto took = std::chrono::steady_clock::now() - t0;
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("no answer from 127.0.0.1:" + port + " within 300 ms"), std::string::npos)
        << r.log;
    EXPECT_LT(took, std::chrono::seconds(3));
}
