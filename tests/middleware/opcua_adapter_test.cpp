// pnp-mw-opcua: our OPC UA server and client as processes on loopback; every payload size
// intact (Call Echo, Write Ack); a chain of servers; no server, a clear reason.
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
    ASSERT_TRUE(server.start({kExe, "server", "--mode", mode, "--port", port},
                             testLog("opcua_server"), err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(20), err)) << err;
    auto r = runClient({kExe, "client", "--mode", mode, "--port", port, "--reps", "20", "--warmup",
                        "2", "--sizes", "0,1,2,1000,32768,65536,200000"},
                       60, testLog("opcua_client"));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 7u);  // one summary per size
    EXPECT_NE(r.lines[4].find("\"payload\":32768"), std::string::npos) << r.lines[4];
    EXPECT_NE(r.lines[4].find("\"n\":20"), std::string::npos) << r.lines[4];
    EXPECT_NE(r.lines[5].find("\"payload\":65536"), std::string::npos) << r.lines[5];
    EXPECT_NE(r.lines[6].find("\"payload\":200000"), std::string::npos) << r.lines[6];
}

}  // namespace

TEST(MiddlewareOpcua, EchoCallRoundTripsEveryPayloadIntact) { roundTrip("echo"); }
TEST(MiddlewareOpcua, AckWriteAnswersEveryPayloadWithOneByte) { roundTrip("ack"); }

TEST(MiddlewareOpcua, ChainCarriesThreeStreamsThroughTheNodes) {
    std::string err;
    auto r = pnp::testing::runSmallChain(kExe, "opcua", 30, err);
    ASSERT_TRUE(err.empty()) << err;
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 1u);
    EXPECT_NE(r.lines[0].find("\"n\":10"), std::string::npos) << r.lines[0];
}

TEST(MiddlewareOpcua, ClientWithoutServerFailsWithAReasonWithinItsTimeout) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    const auto t0 = std::chrono::steady_clock::now();
    auto r = runClient({kExe, "client", "--port", port, "--timeout-ms", "300"}, 30,
                       testLog("opcua_noserver"));
    const auto took = std::chrono::steady_clock::now() - t0;
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("connect opc.tcp://127.0.0.1:" + port), std::string::npos) << r.log;
    EXPECT_LT(took, std::chrono::seconds(3));
}
