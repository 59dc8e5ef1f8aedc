// pnp-mw-opcua: our OPC UA server and client as processes on loopback; every payload size
// intact (Call Echo, Write Ack); a chain of servers; no server, a clear reason.
#include <gtest/gtest.h>

#include <fstream>

#include "adapter_test.hpp"

using pnp::test::runClient;
using pnp::testing::ChildProcess;

namespace {

const std::string kExe = PNP_MW_ADAPTER;

void roundTrip(const std::string& mode) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    ChildProcess server;
    std::string err;
    ASSERT_TRUE(server.start({kExe, "server", "--mode", mode, "--port", port},
                             "/tmp/test_mw_opcua_server.log", err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(20), err)) << err;
    auto r = runClient({kExe, "client", "--mode", mode, "--port", port, "--reps", "20", "--warmup",
                        "2", "--sizes", "0,1,2,1000,32768,65536,200000"},
                       60, "/tmp/test_mw_opcua_client.log");
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
    const int base = pnp::testing::freeLoopbackPort();
    ChildProcess nodes[2];
    std::string err;
    // 3 streams x 4 hops = 12 nodes (servers) in two processes
    for (int k = 0; k < 2; ++k) {
        ASSERT_TRUE(
            nodes[k].start({kExe, "node", "--port", std::to_string(base), "--first",
                            std::to_string(k * 6), "--count", "6", "--streams", "3", "--hops", "4"},
                           "/tmp/test_mw_opcua_node" + std::to_string(k) + ".log", err))
            << err;
        ASSERT_TRUE(nodes[k].waitForLine("READY", std::chrono::seconds(30), err)) << err;
    }
    auto r = runClient({kExe, "client", "--mode", "chain", "--port", std::to_string(base),
                        "--streams", "3", "--hops", "4", "--runs", "10"},
                       60, "/tmp/test_mw_opcua_chain.log");
    ASSERT_EQ(r.exitCode, 0) << r.log << nodes[0].logTail() << nodes[1].logTail();
    ASSERT_EQ(r.lines.size(), 1u);
    EXPECT_NE(r.lines[0].find("\"n\":10"), std::string::npos) << r.lines[0];
}

TEST(MiddlewareOpcua, ClientWithoutServerFailsWithAReasonWithinItsTimeout) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    const auto t0 = std::chrono::steady_clock::now();
    auto r = runClient({kExe, "client", "--port", port, "--timeout-ms", "300"}, 30,
                       "/tmp/test_mw_opcua_noserver.log");
    const auto took = std::chrono::steady_clock::now() - t0;
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("connect opc.tcp://127.0.0.1:" + port), std::string::npos) << r.log;
    EXPECT_LT(took, std::chrono::seconds(3));
}
