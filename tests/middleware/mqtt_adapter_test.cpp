// pnp-mw-mqtt against a mosquitto of its own (on a free loopback port): server, chain nodes
// and client as processes; every payload size intact for qos0 and qos1, a small chain, and a
// broker that dies under a running client.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <thread>

#include "adapter_test.hpp"

using pnp::testing::ChildProcess;
using pnp::testing::ClientRun;
using pnp::testing::runClient;
using pnp::testing::testLog;

namespace {

const std::string kExe = PNP_MW_ADAPTER;
const std::string kMosquitto = "/usr/sbin/mosquitto";

bool portAccepts(int port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    ::close(fd);
    return ok;
}

// Exit code of a child that has exited, without reaping it (ChildProcess still owns the
// PID); -1 while it runs.
int exitCodeOf(pid_t pid) {
    siginfo_t info{};
    if (::waitid(P_PID, static_cast<id_t>(pid), &info, WEXITED | WNOHANG | WNOWAIT) != 0 ||
        info.si_pid == 0)
        return -1;
    return info.si_code == CLD_EXITED ? info.si_status : 128 + info.si_status;
}

// A mosquitto on a free loopback port, stopped by its PID.
class Broker {
  public:
    ~Broker() {
        process_.stop();
        if (!conf_.empty()) std::remove(conf_.c_str());
    }

    bool start(const std::string& name, std::string& err) {
        port_ = pnp::testing::freeLoopbackPort();
        conf_ = "/tmp/test_mw_mqtt_" + name + "_" + std::to_string(::getpid()) + ".conf";
        // set_tcp_nodelay: without it mosquitto's PUBACK + PUBLISH wait for delayed ACKs and
        // a qos1 request takes ~90 ms (see src/bench/adapters/mqtt/README.md).
        std::ofstream(conf_) << "listener " << port_ << " 127.0.0.1\n"
                             << "allow_anonymous true\n"
                             << "set_tcp_nodelay true\n";
        if (!process_.start({kMosquitto, "-c", conf_}, testLog("mqtt_" + name + "_broker"), err))
            return false;
        for (int i = 0; i < 200; ++i) {
            if (portAccepts(port_)) return true;
            if (exitCodeOf(process_.pid()) >= 0) break;
            std::this_thread::sleep_for(std::chrono::milliseconds(25));
        }
        err = "mosquitto does not accept on port " + std::to_string(port_) + ": " +
              process_.logTail();
        return false;
    }

    void kill9() { process_.kill9(); }
    std::string port() const { return std::to_string(port_); }

  private:
    ChildProcess process_;
    int port_ = 0;
    std::string conf_;
};

bool haveMosquitto() { return pnp::testing::fileExists(kMosquitto); }

struct Case {
    std::string variant, mode, receive;  // receive: the adapter's setting (sync or callback)
};

void PrintTo(const Case& c, std::ostream* os) {
    *os << c.variant << " " << c.mode << " " << c.receive;
}

class MiddlewareMqttRoundTrip : public ::testing::TestWithParam<Case> {};

TEST_P(MiddlewareMqttRoundTrip, EveryPayloadSizeIntact) {
    if (!haveMosquitto()) GTEST_SKIP() << kMosquitto << " not installed";
    const auto& [variant, mode, receive] = GetParam();
    const std::string name = variant + "_" + mode + "_" + receive;
    Broker broker;
    std::string err;
    ASSERT_TRUE(broker.start(name, err)) << err;
    ChildProcess server;
    ASSERT_TRUE(server.start(
        {kExe, "server", "--mode", mode, "--variant", variant, "--port", broker.port()},
        testLog("mqtt_" + name + "_server"), err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(10), err))
        << err << server.logTail();
    auto r =
        runClient({kExe, "client", "--mode", mode, "--variant", variant, "--port", broker.port(),
                   "--reps", "20", "--warmup", "2", "--sizes", "0,2,1000,32768"},
                  60, testLog("mqtt_" + name + "_client"));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 4u);  // one summary per size; the driver checked every reply
    const char* sizes[] = {"0", "2", "1000", "32768"};
    for (std::size_t i = 0; i < 4; ++i) {
        EXPECT_NE(r.lines[i].find("\"payload\":" + std::string(sizes[i]) + ","), std::string::npos)
            << r.lines[i];
        EXPECT_NE(r.lines[i].find("\"n\":20,"), std::string::npos) << r.lines[i];
        EXPECT_NE(r.lines[i].find("\"variant\":\"" + variant + "\""), std::string::npos)
            << r.lines[i];
    }
}

INSTANTIATE_TEST_SUITE_P(
    Variants, MiddlewareMqttRoundTrip,
    ::testing::Values(Case{"qos0", "echo", "sync"}, Case{"qos0", "ack", "sync"},
                      Case{"qos1", "echo", "sync"}, Case{"qos1", "ack", "sync"},
                      Case{"qos0", "echo", "callback"}, Case{"qos1", "echo", "callback"}),
    [](const auto& info) { return info.param.variant + info.param.mode + info.param.receive; });

class MiddlewareMqttChain : public ::testing::TestWithParam<std::string> {};

TEST_P(MiddlewareMqttChain, ThreeStreamsOfFourHopsThroughTwoNodeProcesses) {
    if (!haveMosquitto()) GTEST_SKIP() << kMosquitto << " not installed";
    const std::string variant = GetParam();
    Broker broker;
    std::string err;
    ASSERT_TRUE(broker.start("chain_" + variant, err)) << err;
    ChildProcess nodes[2];
    for (int k = 0; k < 2; ++k) {
        ASSERT_TRUE(
            nodes[k].start({kExe, "node", "--variant", variant, "--port", broker.port(), "--first",
                            std::to_string(k * 6), "--count", "6", "--streams", "3", "--hops", "4"},
                           testLog("mqtt_chain_" + variant + "_node" + std::to_string(k)), err))
            << err;
    }
    for (auto& n : nodes)
        ASSERT_TRUE(n.waitForLine("READY", std::chrono::seconds(20), err)) << err << n.logTail();
    auto r = runClient({kExe, "client", "--mode", "chain", "--variant", variant, "--port",
                        broker.port(), "--streams", "3", "--hops", "4", "--runs", "10"},
                       60, testLog("mqtt_chain_" + variant));
    ASSERT_EQ(r.exitCode, 0) << r.log;
    ASSERT_EQ(r.lines.size(), 1u);
    EXPECT_NE(r.lines[0].find("\"n\":10,"), std::string::npos) << r.lines[0];
    EXPECT_NE(r.lines[0].find("\"payload\":10240,"), std::string::npos) << r.lines[0];
}

INSTANTIATE_TEST_SUITE_P(Variants, MiddlewareMqttChain, ::testing::Values("qos0", "qos1"));

class MiddlewareMqttBrokerDeath
    : public ::testing::TestWithParam<std::pair<std::string, std::string>> {};

// The broker is killed while the client is in its request loop: the client exits 1 with a
// reason well within the test's bound, and the server exits non-zero.
TEST_P(MiddlewareMqttBrokerDeath, ClientAndServerFailWithAReason) {
    if (!haveMosquitto()) GTEST_SKIP() << kMosquitto << " not installed";
    const auto& [variant, receive] = GetParam();
    const std::string name = "death_" + variant + "_" + receive;
    Broker broker;
    std::string err;
    ASSERT_TRUE(broker.start(name, err)) << err;
    ChildProcess server;
    ASSERT_TRUE(server.start({kExe, "server", "--mode", "echo", "--variant", variant, "--port",
                              broker.port(), "--set", "receive=" + receive},
                             testLog("mqtt_" + name + "_server"), err))
        << err;
    ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(10), err)) << err;
    ClientRun r;
    const auto t0 = std::chrono::steady_clock::now();
    std::thread client([&] {
        r = runClient(
            {kExe, "client", "--mode", "echo", "--variant", variant, "--port", broker.port(),
             "--sizes", "100", "--reps", "10000000", "--warmup", "0", "--timeout-ms", "3000"},
            60, testLog("mqtt_" + name + "_client"));
    });
    std::this_thread::sleep_for(std::chrono::milliseconds(1500));
    broker.kill9();
    client.join();
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_EQ(r.exitCode, 1) << r.log;
    EXPECT_NE(r.log.find("broker"), std::string::npos) << r.log;
    EXPECT_LT(seconds, 15.0);      // the broker died after 1.5 s; timeout 3 s
    EXPECT_TRUE(r.lines.empty());  // no summary of a run that did not finish
    int code = -1;
    for (int i = 0; i < 200 && code < 0; ++i) {
        code = exitCodeOf(server.pid());
        if (code < 0) std::this_thread::sleep_for(std::chrono::milliseconds(25));
    }
    EXPECT_GT(code, 0) << "the server still runs or exited 0";
    EXPECT_NE(server.logTail().find("broker"), std::string::npos) << server.logTail();
}

INSTANTIATE_TEST_SUITE_P(Variants, MiddlewareMqttBrokerDeath,
                         ::testing::Values(std::pair{std::string("qos0"), std::string("sync")},
                                           std::pair{std::string("qos1"), std::string("sync")},
                                           std::pair{std::string("qos1"), std::string("callback")}),
                         [](const auto& info) { return info.param.first + info.param.second; });

TEST(MiddlewareMqtt, ClientWithoutBrokerFailsWithAReason) {
    const std::string port = std::to_string(pnp::testing::freeLoopbackPort());
    auto r = runClient({kExe, "client", "--port", port, "--timeout-ms", "1000"}, 30,
                       testLog("mqtt_nobroker"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("cannot connect to the MQTT broker"), std::string::npos) << r.log;
}

TEST(MiddlewareMqtt, WildcardTopicPrefixIsRefused) {
    auto r = runClient({kExe, "client", "--set", "topic-prefix=a/#", "--timeout-ms", "1000"}, 30,
                       testLog("mqtt_badprefix"));
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.log.find("topic-prefix"), std::string::npos) << r.log;
}

}  // namespace
