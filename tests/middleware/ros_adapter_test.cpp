// pnp-mw-ros: a private ROS master (rosmaster --core on a free loopback port), server, chain
// nodes and client as processes; every payload size intact for topic and service, a small
// chain through one `node` process of six ROS node processes, and clear failures without a
// master or a server.
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "adapter_test.hpp"

using pnp::testing::ChildProcess;
using pnp::testing::ClientRun;
using pnp::testing::runClient;
using pnp::testing::testLog;

namespace {

const std::string kExe = PNP_MW_ADAPTER;

bool portAccepts(unsigned short port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = htons(port);
    const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    ::close(fd);
    return ok;
}

// A ROS master of this test alone; stopped by PID (ChildProcess) at the end.
class MiddlewareRos : public ::testing::Test {
  protected:
    void SetUp() override {
        const std::string rosmaster = pnp::testing::findInPath("rosmaster");
        if (rosmaster.empty()) GTEST_SKIP() << "rosmaster not installed (python3-rosmaster)";
        const unsigned short port = pnp::testing::freeLoopbackPort();
        std::string err;
        ASSERT_TRUE(master_.start({rosmaster, "--core", "-p", std::to_string(port)},
                                  testLog("ros_master"), err))
            << err;
        const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
        while (!portAccepts(port)) {
            ASSERT_TRUE(master_.running()) << "rosmaster exited: " << master_.logTail();
            ASSERT_LT(std::chrono::steady_clock::now(), end) << "rosmaster does not listen";
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
        masterSet_ = "master=http://127.0.0.1:" + std::to_string(port);
    }

    void roundTrip(const std::string& variant, const std::string& mode) {
        ChildProcess server;
        std::string err;
        ASSERT_TRUE(server.start(
            {kExe, "server", "--variant", variant, "--mode", mode, "--set", masterSet_},
            testLog("ros_server"), err))
            << err;
        ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(20), err))
            << err << server.logTail();
        auto r =
            runClient({kExe, "client", "--variant", variant, "--mode", mode, "--set", masterSet_,
                       "--reps", "20", "--warmup", "2", "--sizes", "0,2,1000,32768,65536"},
                      60, testLog("ros_client"));
        ASSERT_EQ(r.exitCode, 0) << r.log;
        ASSERT_EQ(r.lines.size(), 5u);  // one summary per size
        EXPECT_NE(r.lines[0].find("\"payload\":0,"), std::string::npos) << r.lines[0];
        EXPECT_NE(r.lines[3].find("\"payload\":32768"), std::string::npos) << r.lines[3];
        for (const auto& l : r.lines) {
            EXPECT_NE(l.find("\"n\":20"), std::string::npos) << l;
            EXPECT_NE(l.find("\"variant\":\"" + variant + "\""), std::string::npos) << l;
        }
    }

    ChildProcess master_;
    std::string masterSet_;
};

std::vector<pid_t> childrenOf(pid_t pid) {
    std::ifstream in("/proc/" + std::to_string(pid) + "/task/" + std::to_string(pid) + "/children");
    std::vector<pid_t> out;
    for (pid_t c; in >> c;) out.push_back(c);
    return out;
}

}  // namespace

TEST_F(MiddlewareRos, TopicEchoRoundTripsEveryPayloadIntact) { roundTrip("topic", "echo"); }
TEST_F(MiddlewareRos, TopicAckAnswersEveryPayloadWithOneByte) { roundTrip("topic", "ack"); }
TEST_F(MiddlewareRos, ServiceEchoRoundTripsEveryPayloadIntact) { roundTrip("service", "echo"); }
TEST_F(MiddlewareRos, ServiceAckAnswersEveryPayloadWithOneByte) { roundTrip("service", "ack"); }

TEST_F(MiddlewareRos, ChainCarriesThreeStreamsThroughSixNodeProcesses) {
    ChildProcess nodes;
    std::string err;
    // 3 streams x 2 hops = 6 ROS nodes, each a child process of this one `node` process
    ASSERT_TRUE(nodes.start({kExe, "node", "--first", "0", "--count", "6", "--streams", "3",
                             "--hops", "2", "--set", masterSet_},
                            testLog("ros_nodes"), err))
        << err;
    ASSERT_TRUE(nodes.waitForLine("READY", std::chrono::seconds(60), err))
        << err << nodes.logTail();
    const std::vector<pid_t> children = childrenOf(nodes.pid());
    EXPECT_EQ(children.size(), 6u);
    auto r = runClient({kExe, "client", "--mode", "chain", "--streams", "3", "--hops", "2",
                        "--runs", "10", "--set", masterSet_},
                       60, testLog("ros_chain"));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 1u);
    EXPECT_NE(r.lines[0].find("\"n\":10"), std::string::npos) << r.lines[0];
    EXPECT_NE(r.lines[0].find("\"payload\":10240"), std::string::npos) << r.lines[0];
    // SIGTERM to the parent stops and reaps every node process.
    nodes.stop();
    for (pid_t c : children) EXPECT_NE(::kill(c, 0), 0) << "node process " << c << " left behind";
}

TEST_F(MiddlewareRos, ChainNodesDieWithTheirKilledParent) {
    ChildProcess nodes;
    std::string err;
    ASSERT_TRUE(nodes.start({kExe, "node", "--first", "0", "--count", "2", "--streams", "1",
                             "--hops", "2", "--set", masterSet_},
                            testLog("ros_nodes_kill"), err))
        << err;
    ASSERT_TRUE(nodes.waitForLine("READY", std::chrono::seconds(60), err))
        << err << nodes.logTail();
    const std::vector<pid_t> children = childrenOf(nodes.pid());
    ASSERT_EQ(children.size(), 2u);
    nodes.kill9();  // no SIGTERM forwarding: PR_SET_PDEATHSIG must end them
    for (pid_t c : children) {
        const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(10);
        while (::kill(c, 0) == 0 && std::chrono::steady_clock::now() < end)
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
        EXPECT_NE(::kill(c, 0), 0) << "node process " << c << " outlived its parent";
    }
}

TEST_F(MiddlewareRos, TopicClientWithoutServerFailsWithAReason) {
    auto r = runClient({kExe, "client", "--set", masterSet_, "--timeout-ms", "500"}, 30,
                       testLog("ros_noserver"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("no ROS topic server"), std::string::npos) << r.log;
}

TEST_F(MiddlewareRos, ClientsOfAFrozenServerFailWithinTheirTimeout) {
    for (const std::string variant : {"topic", "service"}) {
        ChildProcess server;
        std::string err;
        ASSERT_TRUE(server.start(
            {kExe, "server", "--variant", variant, "--mode", "echo", "--set", masterSet_},
            testLog("ros_frozen"), err))
            << err;
        ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(20), err)) << err;
        ::kill(server.pid(), SIGSTOP);  // registered with the master, but never answers
        const auto t0 = std::chrono::steady_clock::now();
        auto r = runClient({kExe, "client", "--variant", variant, "--set", masterSet_,
                            "--timeout-ms", "500", "--sizes", "2", "--reps", "5"},
                           30, testLog("ros_frozen_client"));
        const auto took = std::chrono::steady_clock::now() - t0;
        ::kill(server.pid(), SIGCONT);
        EXPECT_EQ(r.exitCode, 1) << variant << ": " << r.log;
        EXPECT_NE(r.log.find("500 ms"), std::string::npos) << variant << ": " << r.log;
        EXPECT_LT(took, std::chrono::seconds(10)) << variant;
    }
}

TEST(MiddlewareRosNoMaster, ClientsWithoutMasterFailWithAReason) {
    // A port nobody listens on: the master is unreachable.
    const std::string master =
        "master=http://127.0.0.1:" + std::to_string(pnp::testing::freeLoopbackPort());
    for (const std::string variant : {"topic", "service"}) {
        const auto t0 = std::chrono::steady_clock::now();
        auto r = runClient(
            {kExe, "client", "--variant", variant, "--set", master, "--timeout-ms", "500"}, 30,
            testLog("ros_nomaster"));
        const auto took = std::chrono::steady_clock::now() - t0;
        EXPECT_EQ(r.exitCode, 1) << variant;
        EXPECT_NE(r.log.find("unreachable"), std::string::npos) << variant << ": " << r.log;
        EXPECT_LT(took, std::chrono::seconds(10)) << variant;
    }
}
