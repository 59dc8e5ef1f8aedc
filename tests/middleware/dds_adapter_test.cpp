// pnp-mw-dds: server, chain nodes and client as processes on loopback; every payload size
// intact over both transports. Each test uses a DDS domain of its own (from the pid), so
// tests running in parallel do not discover each other.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>

#include "adapter_test.hpp"

using pnp::test::runClient;
using pnp::testing::ChildProcess;  // tests/support/child_process.hpp

namespace {

const std::string kExe = PNP_MW_ADAPTER;

// Domains 0..232 exist; one per test process, `k` for a second one within a test.
std::string domainSetting(int k = 0) {
    return "domain=" + std::to_string((static_cast<int>(::getpid()) * 2 + k) % 233);
}

std::string logPath(const std::string& what) {
    return "/tmp/test_mw_dds_" + what + "_" + std::to_string(::getpid()) + ".log";
}

void roundTrip(const std::string& variant, const std::string& mode) {
    const std::string domain = domainSetting();
    ChildProcess server;
    std::string err;
    ASSERT_TRUE(
        server.start({kExe, "server", "--variant", variant, "--mode", mode, "--set", domain},
                     logPath("server"), err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(10), err)) << err;
    auto r = runClient({kExe, "client", "--variant", variant, "--mode", mode, "--set", domain,
                        "--reps", "20", "--warmup", "2", "--sizes", "0,2,1000,32768,65536"},
                       60, logPath("client"));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 5u);  // one summary per size
    const char* sizes[] = {"0", "2", "1000", "32768", "65536"};
    for (std::size_t i = 0; i < 5; ++i) {
        EXPECT_NE(r.lines[i].find("\"payload\":" + std::string(sizes[i]) + ","), std::string::npos)
            << r.lines[i];
        EXPECT_NE(r.lines[i].find("\"n\":20,"), std::string::npos) << r.lines[i];
        EXPECT_NE(r.lines[i].find("\"variant\":\"" + variant + "\""), std::string::npos)
            << r.lines[i];
    }
}

void chain(const std::string& variant) {
    const std::string domain = domainSetting();
    ChildProcess nodes[2];
    std::string err;
    // 3 streams x 4 hops = 12 nodes in two processes; stream 1 crosses between them.
    for (int k = 0; k < 2; ++k) {
        ASSERT_TRUE(
            nodes[k].start({kExe, "node", "--variant", variant, "--set", domain, "--first",
                            std::to_string(k * 6), "--count", "6", "--streams", "3", "--hops", "4"},
                           logPath("node" + std::to_string(k)), err))
            << err;
        ASSERT_TRUE(nodes[k].waitForLine("READY", std::chrono::seconds(10), err)) << err;
    }
    auto r = runClient({kExe, "client", "--variant", variant, "--mode", "chain", "--set", domain,
                        "--streams", "3", "--hops", "4", "--runs", "10"},
                       60, logPath("chain"));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 1u);
    EXPECT_NE(r.lines[0].find("\"n\":10,"), std::string::npos) << r.lines[0];
    EXPECT_NE(r.lines[0].find("\"payload\":10240,"), std::string::npos) << r.lines[0];
}

}  // namespace

TEST(MiddlewareDds, UdpEchoRoundTripsEveryPayloadIntact) { roundTrip("udp", "echo"); }
TEST(MiddlewareDds, UdpAckAnswersEveryPayloadWithOneByte) { roundTrip("udp", "ack"); }
TEST(MiddlewareDds, ShmEchoRoundTripsEveryPayloadIntact) { roundTrip("shm", "echo"); }
TEST(MiddlewareDds, ShmAckAnswersEveryPayloadWithOneByte) { roundTrip("shm", "ack"); }

TEST(MiddlewareDds, UdpChainCarriesThreeStreamsThroughTwoNodeProcesses) { chain("udp"); }
TEST(MiddlewareDds, ShmChainCarriesThreeStreamsThroughTwoNodeProcesses) { chain("shm"); }

TEST(MiddlewareDds, ClientWithoutServerFailsWithAReasonWithinItsTimeout) {
    const auto t0 = std::chrono::steady_clock::now();
    auto r = runClient({kExe, "client", "--set", domainSetting(), "--timeout-ms", "500"}, 30,
                       logPath("noserver"));
    const auto took = std::chrono::steady_clock::now() - t0;
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("no DDS peer matched within 500 ms"), std::string::npos) << r.log;
    EXPECT_LT(took, std::chrono::seconds(5));  // the timeout plus process start and teardown
}

TEST(MiddlewareDds, ChainClientWithoutNodesFailsWithAReason) {
    auto r = runClient({kExe, "client", "--mode", "chain", "--set", domainSetting(), "--streams",
                        "2", "--hops", "3", "--timeout-ms", "500"},
                       30, logPath("nonodes"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("no DDS peer matched within 500 ms"), std::string::npos) << r.log;
}
