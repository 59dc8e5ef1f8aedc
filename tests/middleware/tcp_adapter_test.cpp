// pnp-mw-tcp: server and client as processes on loopback; every payload size intact.
#include <gtest/gtest.h>

#include <fstream>

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
        server.start({kExe, "server", "--mode", mode, "--port", port}, testLog("tcp_server"), err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(10), err)) << err;
    auto r = runClient({kExe, "client", "--mode", mode, "--port", port, "--reps", "20", "--warmup",
                        "2", "--sizes", "0,1,2,1000,32768,65536"},
                       60, testLog("tcp_client"));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 6u);  // one summary per size
    EXPECT_NE(r.lines[4].find("\"payload\":32768"), std::string::npos) << r.lines[4];
    EXPECT_NE(r.lines[4].find("\"n\":20"), std::string::npos) << r.lines[4];
}

}  // namespace

TEST(MiddlewareTcp, EchoRoundTripsEveryPayloadIntact) { roundTrip("echo"); }
TEST(MiddlewareTcp, AckAnswersEveryPayloadWithOneByte) { roundTrip("ack"); }

TEST(MiddlewareTcp, ChainCarriesThreeStreamsThroughTheNodes) {
    std::string err;
    auto r = pnp::testing::runSmallChain(kExe, "tcp", 10, err);
    ASSERT_TRUE(err.empty()) << err;
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 1u);
    EXPECT_NE(r.lines[0].find("\"n\":10"), std::string::npos) << r.lines[0];
}

TEST(MiddlewareTcp, ClientWithoutServerFailsWithAReason) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    auto r = runClient({kExe, "client", "--port", port, "--timeout-ms", "300"}, 30,
                       testLog("tcp_noserver"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("connect"), std::string::npos) << r.log;
}
