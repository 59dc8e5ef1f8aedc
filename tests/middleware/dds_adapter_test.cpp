// pnp-mw-dds: server, chain nodes and client as processes on loopback; every payload size
// intact over both transports. Each test uses a DDS domain of its own (from the pid), so
// tests running in parallel do not discover each other.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <iostream>
#include <sstream>

#include "adapter_test.hpp"
#include "support/netns.hpp"

using pnp::testing::ChildProcess;  // tests/support/child_process.hpp
using pnp::testing::runClient;
using pnp::testing::testLog;

namespace {

const std::string kExe = PNP_MW_ADAPTER;

// Domains 0..232 exist; one per test process, `k` for a second one within a test.
std::string domainSetting(int k = 0) {
    return "domain=" + std::to_string((static_cast<int>(::getpid()) * 2 + k) % 233);
}

std::string logPath(const std::string& what) { return testLog("dds_" + what); }

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

// UDP datagrams received in a network namespace so far (/proc/net/snmp, Udp: InDatagrams).
long udpInDatagrams(const std::string& ns) {
    FILE* p = ::popen(("ip netns exec " + ns + " cat /proc/net/snmp").c_str(), "r");
    if (!p) return -1;
    std::vector<std::string> udp;
    char buf[1024];
    while (std::fgets(buf, sizeof buf, p))
        if (std::string(buf).rfind("Udp: ", 0) == 0) udp.emplace_back(buf);
    ::pclose(p);
    if (udp.size() < 2) return -1;  // header line, value line
    std::istringstream names(udp[0]), values(udp[1]);
    std::string name, value;
    while (names >> name && values >> value)
        if (name == "InDatagrams") return std::stol(value);
    return -1;
}

// Chain of 3 streams x 4 hops, all 12 nodes in ONE process, `udp`, in a namespace of its own
// (so nothing else is counted): the UDP datagrams received during `runs` chain runs.
long chainDatagramsInOneProcess(const std::string& intraprocess, int runs) {
    pnp::testing::Lab lab;
    const std::string ns = lab.host("dds");
    ChildProcess nodes;
    std::string err;
    const std::vector<std::string> common = {
        "--variant", "udp",    "--set", domainSetting(), "--streams",
        "3",         "--hops", "4",     "--set",         "intraprocess=" + intraprocess};
    std::vector<std::string> node = {kExe, "node", "--first", "0", "--count", "12"};
    node.insert(node.end(), common.begin(), common.end());
    EXPECT_TRUE(nodes.start(node, logPath("intra_nodes"), err, ns)) << err;
    EXPECT_TRUE(nodes.waitForLine("READY", std::chrono::seconds(10), err)) << err;
    const long before = udpInDatagrams(ns);
    std::vector<std::string> client = {"ip",     "netns",  "exec",  ns,       kExe,
                                       "client", "--mode", "chain", "--runs", std::to_string(runs)};
    client.insert(client.end(), common.begin(), common.end());
    auto r = runClient(client, 60, logPath("intra_client"));
    EXPECT_EQ(r.exitCode, 0) << r.log;
    const long after = udpInDatagrams(ns);
    EXPECT_GE(before, 0);
    return after - before;
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

// Fast DDS would hand samples between the participants of one process directly; the adapter
// turns that off, so every one of the 5 hops of a stream (client -> 4 nodes -> client) is a
// datagram. The same run with intra-process delivery on is the control: it must count fewer.
TEST(MiddlewareDds, ChainNodesInOneProcessTalkOverTheTransport) {
    if (!pnp::testing::canCreateNetworkNamespaces())
        GTEST_SKIP() << "needs root and iproute2 (network namespaces); CI runs as root";
    constexpr int kRuns = 100;
    const long hops = 3L * 5 * (kRuns + 2);  // streams x hops x (runs + the driver's 2 warm-up)
    const long off = chainDatagramsInOneProcess("off", kRuns);
    const long full = chainDatagramsInOneProcess("full", kRuns);
    std::cout << "UDP datagrams received in " << kRuns + 2 << " chain runs: intra-process off "
              << off << ", full " << full << " (" << hops << " hops)" << std::endl;
    EXPECT_GE(off, hops) << "intra-process off: " << off << ", on: " << full;
    EXPECT_LT(full, hops) << "intra-process off: " << off << ", on: " << full;
}

// As the runner places them: server and client on two hosts (network namespaces on one
// segment, no multicast route), discovery by unicast to --host from --local.
TEST(MiddlewareDds, ClientAndServerOnTwoHostsFindEachOtherByUnicast) {
    if (!pnp::testing::canCreateNetworkNamespaces())
        GTEST_SKIP() << "needs root and iproute2 (network namespaces); CI runs as root";
    pnp::testing::Lab lab;
    lab.segment("lan");
    lab.attach("server", "lan", "eth0", "10.77.0.1/24");
    lab.attach("client", "lan", "eth0", "10.77.0.2/24");
    for (const std::string variant : {"udp", "shm"}) {
        const std::string domain = domainSetting();
        ChildProcess server;
        std::string err;
        ASSERT_TRUE(server.start({kExe, "server", "--variant", variant, "--mode", "echo", "--host",
                                  "10.77.0.1", "--set", domain},
                                 logPath("netns_server"), err, lab.host("server")))
            << err;
        ASSERT_TRUE(server.waitForLine("READY", std::chrono::seconds(10), err)) << err;
        auto r = runClient({"ip",      "netns",     "exec",    lab.host("client"), kExe,
                            "client",  "--variant", variant,   "--mode",           "echo",
                            "--host",  "10.77.0.1", "--local", "10.77.0.2",        "--set",
                            domain,    "--reps",    "20",      "--warmup",         "2",
                            "--sizes", "0,2,32768"},
                           60, logPath("netns_client"));
        ASSERT_EQ(r.exitCode, 0) << variant << ": " << r.log;
        ASSERT_EQ(r.lines.size(), 3u) << variant;
        EXPECT_NE(r.lines[2].find("\"payload\":32768,"), std::string::npos) << r.lines[2];
        EXPECT_NE(r.lines[2].find("\"n\":20,"), std::string::npos) << r.lines[2];
    }
}
