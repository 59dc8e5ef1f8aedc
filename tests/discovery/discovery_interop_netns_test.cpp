// Interoperability of our discovery (issue 4, point 6) with other mDNS / LDS implementations,
// each in a network namespace of its own on one layer-2 segment (made by the test, removed
// after it; root needed, skipped otherwise):
//
//   - avahi (avahi-daemon on a private D-Bus system bus, avahi-browse, avahi-publish) next
//     to our `pnp lds`;
//   - node-opcua's LDS (node-opcua-server-discovery, tests/interop/node_lds.js) next to our
//     `pnp lds`, with `pnp ua serve` and a node-opcua server registering with either.
//
// Every process is started inside its host and stopped by its PID (ChildProcess), every file
// lives in a temporary folder removed at the end, every wait is bounded. What avahi and
// node-opcua do differently is in docs/discovery.md ("Interoperability").
#include <gtest/gtest.h>
#include <signal.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "support/child_process.hpp"
#include "support/netns.hpp"
#include "ua/client/client.hpp"
#include "ua/types/ns0_types_services.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY must be defined"
#endif
#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

namespace pnp::testing {
namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;
using namespace pnp::ua;

// A temporary folder, removed with everything in it.
class TempFolder {
  public:
    TempFolder() {
        std::string t = "/tmp/pnp_interop_" + std::to_string(::getpid()) + "_XXXXXX";
        if (!::mkdtemp(t.data())) throw std::runtime_error("mkdtemp failed");
        path_ = t;
    }
    ~TempFolder() {
        std::error_code ec;
        std::filesystem::remove_all(path_, ec);
    }
    TempFolder(const TempFolder&) = delete;
    TempFolder& operator=(const TempFolder&) = delete;
    const std::string& path() const { return path_; }
    std::string file(const std::string& name) const { return path_ + "/" + name; }
    void write(const std::string& name, const std::string& text) const {
        std::ofstream(file(name)) << text;
    }

  private:
    std::string path_;
};

std::string readFile(const std::string& path) {
    std::ifstream f(path);
    return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

// Polls pred every 50 ms until it holds or the timeout passes.
bool eventually(const std::function<bool()>& pred, std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    for (;;) {
        if (pred()) return true;
        if (Clock::now() >= end) return false;
        std::this_thread::sleep_for(50ms);
    }
}

// Runs fn on a thread inside the network namespace ns (our client's sockets and threads are
// made there) and waits for it; an exception of fn is rethrown.
template <class F>
auto inNamespace(const std::string& ns, F fn) -> decltype(fn()) {
    std::optional<decltype(fn())> result;
    std::exception_ptr error;
    std::thread t([&] {
        try {
            EnterNetNs inside(ns);
            result.emplace(fn());
        } catch (...) {
            error = std::current_exception();
        }
    });
    t.join();
    if (error) std::rethrow_exception(error);
    return std::move(*result);
}

// fn(client) with our client, from inside ns; a default result when the call fails.
template <class F>
auto ask(const std::string& ns, F fn) -> decltype(fn(std::declval<client::Client&>())) {
    try {
        return inNamespace(ns, [&] {
            client::ClientConfig cc;
            cc.requestTimeout = cc.connectTimeout = 2s;
            client::Client c(cc);
            return fn(c);
        });
    } catch (const std::exception&) {
        return {};
    }
}
std::vector<ServerOnNetwork> findServersOnNetwork(const std::string& ns, const std::string& url) {
    return ask(ns, [&](client::Client& c) {
        return c.discoveryRequest(url, FindServersOnNetworkRequest{}, 2s).servers;
    });
}
std::vector<ApplicationDescription> findServers(const std::string& ns, const std::string& url) {
    return ask(ns, [&](client::Client& c) { return c.findServers(url, 2s); });
}

std::string describe(const std::vector<ServerOnNetwork>& list) {
    std::string s;
    for (const auto& r : list) {
        s += "\n  " + r.serverName + " " + r.discoveryUrl + " caps=";
        for (const auto& c : r.serverCapabilities) s += c + ",";
    }
    return s.empty() ? " (none)" : s;
}
std::string describe(const std::vector<ApplicationDescription>& list) {
    std::string s;
    for (const auto& a : list) {
        s += "\n  " + a.applicationUri + " \"" + a.applicationName.text + "\"";
        for (const auto& u : a.discoveryUrls) s += " " + u;
    }
    return s.empty() ? " (none)" : s;
}

bool hasCap(const std::vector<std::string>& caps, const std::string& cap) {
    return std::find(caps.begin(), caps.end(), cap) != caps.end();
}

const ServerOnNetwork* findRecord(const std::vector<ServerOnNetwork>& list,
                                  const std::function<bool(const ServerOnNetwork&)>& pred) {
    for (const auto& r : list)
        if (pred(r)) return &r;
    return nullptr;
}

// The hosts of a test on one segment, 10.79.0.0/24, and the processes running in them,
// stopped by PID (in reverse start order) before the namespaces go.
class Segment {
  public:
    Segment() {
        lab_.segment("lan");
        folder_ = std::make_unique<TempFolder>();
    }
    ~Segment() {
        while (!processes_.empty()) processes_.pop_back();
    }

    // A host on the segment with address 10.79.0.<n> on eth0, and a route for multicast
    // (bonjour, unlike avahi and us, sends to 224.0.0.251 without choosing an interface:
    // without a route its socket fails with ENETUNREACH and node-opcua's mDNS goes silent).
    std::string host(const std::string& name, int n) {
        lab_.attach(name, "lan", "eth0", address(n) + "/24");
        const std::string ns = lab_.host(name);
        shell("ip -n " + ns + " route add 224.0.0.0/4 dev eth0");
        return ns;
    }
    static std::string address(int n) { return "10.79.0." + std::to_string(n); }

    // Starts argv inside host (stderr to a log in the temporary folder). The first element
    // is the program's full path.
    ChildProcess& start(const std::string& host, const std::string& tag,
                        std::vector<std::string> argv) {
        processes_.push_back(std::make_unique<ChildProcess>());
        auto& p = *processes_.back();
        std::string error;
        if (!p.start(lab_.inHost(host, std::move(argv)), log(tag), error))
            throw std::runtime_error(tag + ": " + error);
        return p;
    }
    // Waits for a stdout line starting with prefix; throws with the log otherwise.
    static void expectLine(ChildProcess& p, const std::string& tag, const std::string& prefix,
                           std::chrono::milliseconds timeout, std::string* line = nullptr) {
        std::string error;
        if (!p.waitForPrefix(prefix, timeout, error, line))
            throw std::runtime_error(tag + ": " + error + "\n--- log ---\n" + p.logTail());
    }
    // `pnp args...` inside host; waits for its "listening on" line.
    ChildProcess& pnp(const std::string& host, const std::string& tag,
                      std::vector<std::string> args) {
        args.insert(args.begin(), PNP_BINARY);
        auto& p = start(host, tag, std::move(args));
        expectLine(p, tag, "listening on ", 10s);
        return p;
    }
    void stop(ChildProcess& p) {
        for (auto it = processes_.begin(); it != processes_.end(); ++it)
            if (it->get() == &p) {
                processes_.erase(it);
                return;
            }
    }
    std::string log(const std::string& tag) const { return folder_->file(tag + ".log"); }
    const TempFolder& folder() const { return *folder_; }
    std::string ns(const std::string& host) { return lab_.host(host); }

  private:
    Lab lab_;
    std::unique_ptr<TempFolder> folder_;
    std::vector<std::unique_ptr<ChildProcess>> processes_;
};

// ---- avahi ---------------------------------------------------------------------------------

const char* kAvahiPidFile = "/run/avahi-daemon/pid";

bool processAlive(const std::string& pidFile) {
    const std::string text = readFile(pidFile);
    const long pid = std::atol(text.c_str());
    return pid > 0 && ::kill(static_cast<pid_t>(pid), 0) == 0;
}

// avahi-daemon on a private D-Bus system bus inside one host: dbus-daemon (--nofork, so its
// PID is ours) and avahi-daemon are stopped by PID; avahi-daemon's fixed pid file
// (/run/avahi-daemon/pid) is removed when it still names our daemon.
class Avahi {
  public:
    Avahi(Segment& seg, const std::string& host) : seg_(seg), host_(host) {
        const auto& f = seg.folder();
        bus_ = "unix:path=" + f.file("bus");
        f.write("bus.conf",
                R"(<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-Bus Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>system</type>
  <listen>)" + bus_ +
                    R"(</listen>
  <auth>EXTERNAL</auth>
  <policy context="default">
    <allow user="*"/>
    <allow own="*"/>
    <allow send_type="method_call"/>
    <allow send_destination="*"/>
    <allow receive_sender="*"/>
  </policy>
</busconfig>
)");
        f.write("avahi.conf", R"([server]
use-ipv4=yes
use-ipv6=no
allow-interfaces=eth0
enable-dbus=yes
ratelimit-interval-usec=0
[wide-area]
enable-wide-area=no
[publish]
publish-hinfo=no
publish-workstation=no
)");
        dbus_ = &seg.start(host, "dbus-daemon",
                           {findInPath("dbus-daemon"), "--config-file=" + f.file("bus.conf"),
                            "--nofork", "--nopidfile", "--print-address"});
        Segment::expectLine(*dbus_, "dbus-daemon", "unix:path=", 10s);
        daemon_ =
            &seg.start(host, "avahi-daemon",
                       {env(), "DBUS_SYSTEM_BUS_ADDRESS=" + bus_, findInPath("avahi-daemon"), "-f",
                        f.file("avahi.conf"), "--no-chroot", "--no-drop-root", "--no-rlimits"});
        const std::string log = seg.log("avahi-daemon");
        if (!eventually(
                [&] { return readFile(log).find("Server startup complete") != std::string::npos; },
                10s))
            throw std::runtime_error("avahi-daemon did not start:\n" + readFile(log));
    }
    ~Avahi() {
        const pid_t pid = daemon_ ? daemon_->pid() : -1;
        if (daemon_) seg_.stop(*daemon_);
        if (pid > 0 && std::atol(readFile(kAvahiPidFile).c_str()) == pid)
            std::remove(kAvahiPidFile);
        if (dbus_) seg_.stop(*dbus_);
    }
    Avahi(const Avahi&) = delete;
    Avahi& operator=(const Avahi&) = delete;

    // One resolved `avahi-browse -rp _opcua-tcp._tcp` line of instance (its first "=" line
    // on eth0/IPv4), split at ';': [0] "=", [3] name, [6] host, [7] address, [8] port,
    // [9] TXT. nullopt when none came within the timeout. Each call runs a browse of its own.
    std::optional<std::vector<std::string>> resolve(const std::string& instance,
                                                    std::chrono::milliseconds timeout) {
        auto& p = seg_.start(host_, "avahi-browse-" + instance,
                             {env(), "DBUS_SYSTEM_BUS_ADDRESS=" + bus_, findInPath("avahi-browse"),
                              "-rp", "_opcua-tcp._tcp"});
        std::string line, error;
        const bool ok = p.waitForPrefix("=;eth0;IPv4;" + instance + ";_opcua-tcp._tcp;local;",
                                        timeout, error, &line);
        seg_.stop(p);
        if (!ok) return std::nullopt;
        std::vector<std::string> fields;
        std::size_t start = 0;
        for (int i = 0; i < 9; ++i) {
            const auto semi = line.find(';', start);
            fields.push_back(line.substr(start, semi - start));
            start = semi + 1;
        }
        fields.push_back(line.substr(start));
        return fields;
    }
    // `avahi-publish -s name _opcua-tcp._tcp port txt...`: waits until avahi established it.
    ChildProcess& publish(const std::string& name, int port, const std::vector<std::string>& txt) {
        std::vector<std::string> argv{env(),
                                      "DBUS_SYSTEM_BUS_ADDRESS=" + bus_,
                                      findInPath("avahi-publish"),
                                      "-s",
                                      name,
                                      "_opcua-tcp._tcp",
                                      std::to_string(port)};
        argv.insert(argv.end(), txt.begin(), txt.end());
        auto& p = seg_.start(host_, "avahi-publish", argv);
        const std::string log = seg_.log("avahi-publish");
        if (!eventually([&] { return readFile(log).find("Established") != std::string::npos; },
                        10s))
            throw std::runtime_error("avahi-publish: not established:\n" + readFile(log));
        return p;
    }

    static std::string env() {
        const std::string e = findInPath("env");
        return e.empty() ? "/usr/bin/env" : e;
    }

  private:
    Segment& seg_;
    std::string host_;
    std::string bus_;
    ChildProcess* dbus_ = nullptr;
    ChildProcess* daemon_ = nullptr;
};

class AvahiInterop : public ::testing::Test {
  protected:
    void SetUp() override {
        if (!canCreateNetworkNamespaces())
            GTEST_SKIP() << "needs root and iproute2 (network namespaces); CI runs as root";
        for (const char* tool : {"avahi-daemon", "avahi-browse", "avahi-publish", "dbus-daemon"})
            if (findInPath(tool).empty())
                GTEST_SKIP() << tool
                             << " not installed (apt-get install avahi-daemon avahi-utils dbus; "
                                "scripts/setup.sh does)";
        if (fileExists(kAvahiPidFile) && processAlive(kAvahiPidFile))
            GTEST_SKIP() << "another avahi-daemon runs (" << kAvahiPidFile
                         << "): its pid file is fixed, so a second one cannot start";
        if (fileExists(kAvahiPidFile)) std::remove(kAvahiPidFile);  // stale
    }
    void TearDown() override {
        // Left by our daemon if the test stopped between its start and the Avahi object.
        if (fileExists(kAvahiPidFile) && !processAlive(kAvahiPidFile)) std::remove(kAvahiPidFile);
    }
};

// Hosts: avahi .1, our LDS-ME .2, a pnp server registered with it .3.
TEST_F(AvahiInterop, AvahiBrowseListsOurLdsAndTheServersRegisteredWithIt) {
    Segment seg;
    seg.host("avahi", 1);
    seg.host("lds", 2);
    seg.host("dev", 3);
    Avahi avahi(seg, "avahi");
    seg.pnp("lds", "pnp-lds",
            {"lds", "--port", "4840", "--public-host", Segment::address(2), "--name", "pnp-lds",
             "--mdns-interface", "eth0"});
    seg.pnp("dev", "pnp-dev",
            {"ua", "serve", "--port", "4841", "--public-host", Segment::address(3), "--lds",
             "opc.tcp://" + Segment::address(2) + ":4840", "--name", "pnp-dev"});

    auto lds = avahi.resolve("pnp-lds", 10s);
    ASSERT_TRUE(lds) << "avahi-browse did not resolve our LDS-ME";
    EXPECT_EQ((*lds)[6], "pnp-lds-host.local");
    EXPECT_EQ((*lds)[7], Segment::address(2));
    EXPECT_EQ((*lds)[8], "4840");
    EXPECT_NE((*lds)[9].find("\"caps=LDS"), std::string::npos) << (*lds)[9];
    EXPECT_NE((*lds)[9].find("\"path="), std::string::npos) << (*lds)[9];

    // Announced by our LDS-ME for the server (address and port from its discovery URL).
    auto dev = avahi.resolve("pnp-dev", 10s);
    ASSERT_TRUE(dev) << "avahi-browse did not resolve the server registered with our LDS-ME";
    EXPECT_EQ((*dev)[7], Segment::address(3));
    EXPECT_EQ((*dev)[8], "4841");
    EXPECT_NE((*dev)[9].find("\"caps="), std::string::npos) << (*dev)[9];
}

TEST_F(AvahiInterop, AvahiPublishedServiceInOurFindServersOnNetworkUntilItsGoodbye) {
    Segment seg;
    const std::string avahiNs = seg.host("avahi", 1);
    const std::string ldsNs = seg.host("lds", 2);
    Avahi avahi(seg, "avahi");
    seg.pnp("lds", "pnp-lds",
            {"lds", "--port", "4840", "--public-host", Segment::address(2), "--name", "pnp-lds",
             "--mdns-interface", "eth0"});
    const std::string ldsUrl = "opc.tcp://" + Segment::address(2) + ":4840";
    auto& pub = avahi.publish("avahi-pub", 4999, {"path=/ua/robot", "caps=DA,NA"});

    // avahi's A record is for the machine's host name (shared by all namespaces), with the
    // address of the avahi host's interface.
    const std::string wantUrl = "opc.tcp://" + Segment::address(1) + ":4999/ua/robot";
    std::vector<ServerOnNetwork> list;
    const auto isPub = [](const ServerOnNetwork& r) { return r.serverName == "avahi-pub"; };
    ASSERT_TRUE(eventually(
        [&] {
            list = findServersOnNetwork(ldsNs, ldsUrl);
            return findRecord(list, isPub) != nullptr;
        },
        10s))
        << "not in our FindServersOnNetwork:" << describe(list);
    const auto* r = findRecord(list, isPub);
    EXPECT_EQ(r->discoveryUrl, wantUrl);
    EXPECT_TRUE(hasCap(r->serverCapabilities, "DA")) << describe(list);
    EXPECT_TRUE(hasCap(r->serverCapabilities, "NA")) << describe(list);

    // avahi-publish stopped (SIGTERM): avahi sends the goodbye, the record goes.
    const auto t0 = Clock::now();
    seg.stop(pub);
    EXPECT_TRUE(eventually(
        [&] {
            list = findServersOnNetwork(ldsNs, ldsUrl);
            return !list.empty() && findRecord(list, isPub) == nullptr;
        },
        5s))
        << "still listed after the goodbye:" << describe(list);
    std::printf(
        "[ figures  ] avahi-publish stopped -> gone from our FindServersOnNetwork: %.0f ms\n",
        std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    (void)avahiNs;
}

// ---- node-opcua ----------------------------------------------------------------------------

class NodeOpcuaLdsInterop : public ::testing::Test {
  protected:
    void SetUp() override {
        if (!canCreateNetworkNamespaces())
            GTEST_SKIP() << "needs root and iproute2 (network namespaces); CI runs as root";
        node_ = findInPath("node");
        if (node_.empty()) GTEST_SKIP() << "`node` is not installed";
        if (::access(
                (std::string(PNP_SOURCE_DIR) + "/node_modules/node-opcua-server-discovery").c_str(),
                R_OK) != 0)
            GTEST_SKIP() << "node_modules/node-opcua-server-discovery missing (npm ci)";
    }

    // node tests/interop/node_lds.js args... inside host; waits for "listening on" (node-opcua
    // makes its certificates at the first start: up to a minute).
    ChildProcess& startNode(Segment& seg, const std::string& host, const std::string& tag,
                            std::vector<std::string> args) {
        args.insert(args.begin(),
                    {Avahi::env(), "PNP_NODE_PKI_DIR=" + seg.folder().file("pki"), node_,
                     std::string(PNP_SOURCE_DIR) + "/tests/interop/node_lds.js"});
        auto& p = seg.start(host, tag, std::move(args));
        Segment::expectLine(p, tag, "listening on ", 60s);
        return p;
    }

    std::string node_;
};

// Hosts: node-opcua's LDS .1, our LDS-ME .2; pnp servers .3 (registered with ours) and .4
// (registered with node's).
TEST_F(NodeOpcuaLdsInterop, EachLdsSeesTheOtherAndWhatRegisteredWithIt) {
    Segment seg;
    const std::string nodeNs = seg.host("node", 1);
    const std::string ldsNs = seg.host("lds", 2);
    seg.host("dev", 3);
    seg.host("dev2", 4);
    const std::string nodeUrl = "opc.tcp://" + Segment::address(1) + ":4840";
    const std::string ourUrl = "opc.tcp://" + Segment::address(2) + ":4840";
    startNode(seg, "node", "node-lds", {"lds", "4840", Segment::address(1)});
    // Discovery interop with node-opcua over SecurityPolicy None: its servers register
    // without having been trusted (the secured registration of a node-opcua server with our
    // LDS: tests/cli/secure_interop_test.cpp, case e).
    seg.pnp("lds", "pnp-lds",
            {"lds", "--port", "4840", "--public-host", Segment::address(2), "--name", "pnp-lds",
             "--mdns-interface", "eth0", "--allow-none"});

    // (a) node's LDS announces itself (instance = its ApplicationUri, SRV target = the host
    // of its endpoint URL, path=/DiscoveryServer, caps=LDS): in our FindServersOnNetwork.
    std::vector<ServerOnNetwork> ours, nodes;
    const auto isNodeLds = [&](const ServerOnNetwork& r) {
        return r.discoveryUrl == nodeUrl + "/DiscoveryServer";
    };
    EXPECT_TRUE(eventually(
        [&] {
            ours = findServersOnNetwork(ldsNs, ourUrl);
            const auto* r = findRecord(ours, isNodeLds);
            return r && hasCap(r->serverCapabilities, "LDS");
        },
        10s))
        << "(a) node-opcua's LDS not in our FindServersOnNetwork:" << describe(ours);

    // (b) ours in node's FindServersOnNetwork. node-opcua builds the discovery URL from the
    // SRV target (our host label, a .local name: a client needs mDNS name resolution to use
    // it), not from the A record's address, and appends path= as is.
    const auto isOurLds = [&](const ServerOnNetwork& r) { return r.serverName == "pnp-lds"; };
    EXPECT_TRUE(eventually(
        [&] {
            nodes = findServersOnNetwork(nodeNs, nodeUrl);
            const auto* r = findRecord(nodes, isOurLds);
            return r && hasCap(r->serverCapabilities, "LDS") &&
                   r->discoveryUrl == "opc.tcp://pnp-lds-host.local:4840/";
        },
        10s))
        << "(b) our LDS-ME not (or not as expected) in node-opcua's FindServersOnNetwork:"
        << describe(nodes);

    // (c) a pnp server registered with ours: announced by our LDS-ME, so in node's list.
    seg.pnp("dev", "pnp-dev",
            {"ua", "serve", "--port", "4840", "--public-host", Segment::address(3), "--lds", ourUrl,
             "--name", "pnp-dev"});
    EXPECT_TRUE(eventually(
        [&] {
            nodes = findServersOnNetwork(nodeNs, nodeUrl);
            return findRecord(nodes, [](const ServerOnNetwork& r) {
                       return r.serverName == "pnp-dev" &&
                              r.discoveryUrl.find(":4840") != std::string::npos;
                   }) != nullptr;
        },
        10s))
        << "(c) server registered with our LDS-ME not in node-opcua's FindServersOnNetwork:"
        << describe(nodes);

    // (d) a pnp server registered with node's LDS (RegisterServer2 over SecurityPolicy None:
    // node_lds.js sets allowUnsecuredRegistration): in node's FindServers, and node announces
    // it by mDNS, so it reaches our FindServersOnNetwork too. Port 4842, not the LDS's 4840:
    // node-opcua's FindServers rewrites the host of every discovery URL with the port of the
    // requested endpoint URL to the requested host (adaptDiscoveryUrls, meant for its own
    // URLs), registered servers on other hosts included. Its announcement has the URL's host
    // as SRV target ("10.79.0.4") but A records with node's own addresses for that name: we
    // take an IPv4-literal SRV target as is (ua::discovery::urlHost).
    seg.pnp("dev2", "pnp-dev2",
            {"ua", "serve", "--port", "4842", "--public-host", Segment::address(4), "--lds",
             nodeUrl, "--name", "pnp-dev2", "--insecure"});
    const std::string dev2Uri = "urn:pnp:" + Segment::address(4) + ":4842";
    const std::string dev2Url = "opc.tcp://" + Segment::address(4) + ":4842";
    std::vector<ApplicationDescription> apps;
    EXPECT_TRUE(eventually(
        [&] {
            apps = findServers(nodeNs, nodeUrl);
            for (const auto& a : apps)
                if (a.applicationUri == dev2Uri && a.discoveryUrls.size() == 1 &&
                    a.discoveryUrls[0] == dev2Url)
                    return true;
            return false;
        },
        10s))
        << "(d) server registered with node-opcua's LDS not in its FindServers:" << describe(apps);
    EXPECT_TRUE(eventually(
        [&] {
            ours = findServersOnNetwork(ldsNs, ourUrl);
            return findRecord(ours, [&](const ServerOnNetwork& r) {
                       return r.serverName == "pnp-dev2" && r.discoveryUrl == dev2Url;
                   }) != nullptr;
        },
        10s))
        << "(d) server registered with node-opcua's LDS (announced by it) not in our "
           "FindServersOnNetwork:"
        << describe(ours);
}

// (e) A node-opcua server (OPCUAServer, RegisterServerMethod.LDS) registering with our LDS-ME
// (host .2) from host .5. node-opcua re-registers every 8 minutes only, so our LDS runs with
// Part 12's 10-minute expiry here instead of the 2 s default.
TEST_F(NodeOpcuaLdsInterop, NodeOpcuaServerRegistersWithOurLds) {
    Segment seg;
    const std::string ldsNs = seg.host("lds", 2);
    seg.host("nsrv", 5);
    const std::string ourUrl = "opc.tcp://" + Segment::address(2) + ":4840";
    seg.pnp("lds", "pnp-lds",
            {"lds", "--port", "4840", "--public-host", Segment::address(2), "--name", "pnp-lds",
             "--mdns-interface", "eth0", "--registration-expiry", "600000",
             // node-opcua registers over the most secure endpoint offered, with a certificate
             // nobody trusted yet: this None interop test offers None only.
             "--insecure"});
    auto& server =
        startNode(seg, "nsrv", "node-server", {"server", "4843", Segment::address(5), ourUrl});
    const std::string uri = "urn:pnp:node-opcua-registering-server";
    const std::string url = "opc.tcp://" + Segment::address(5) + ":4843";
    std::vector<ApplicationDescription> apps;
    const auto registered = [&] {
        apps = findServers(ldsNs, ourUrl);
        for (const auto& a : apps)
            if (a.applicationUri == uri && std::find(a.discoveryUrls.begin(), a.discoveryUrls.end(),
                                                     url) != a.discoveryUrls.end())
                return true;
        return false;
    };
    ASSERT_TRUE(eventually(registered, 30s))
        << "node-opcua server not in our FindServers:" << describe(apps) << "\n--- log ---\n"
        << server.logTail();

    // It registered with RegisterServer2 and an MdnsDiscoveryConfiguration (mdnsServerName =
    // its ApplicationUri): in our FindServersOnNetwork.
    std::vector<ServerOnNetwork> ours;
    EXPECT_TRUE(eventually(
        [&] {
            ours = findServersOnNetwork(ldsNs, ourUrl);
            return findRecord(ours, [&](const ServerOnNetwork& r) {
                       return r.serverName == uri && r.discoveryUrl == url;
                   }) != nullptr;
        },
        10s))
        << describe(ours);

    // Stopped (SIGTERM): node-opcua unregisters (isOnline = false) on shutdown.
    seg.stop(server);
    EXPECT_TRUE(eventually([&] { return !registered() && !apps.empty(); }, 10s))
        << "still registered after the node-opcua server stopped:" << describe(apps);
}

}  // namespace
}  // namespace pnp::testing
