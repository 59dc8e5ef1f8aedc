// node-opcua as the client of our Local Discovery Server: runs tests/interop/node_lds_client.js
// (RegisterServer2 + mDNS configuration, FindServersOnNetwork with a filter, FindServers, a
// refused registration, isOnline = false) against a server of this process. Skipped (not
// failed) when `node` or node-opcua is missing.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <string>

#include "support/loopback_server.hpp"
#include "ua/server/server.hpp"

#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

using namespace pnp::ua;

TEST(DiscoveryInterop, NodeOpcuaClient) {
    const std::string dir = std::string(PNP_SOURCE_DIR);
    const std::string script = dir + "/tests/interop/node_lds_client.js";
    if (std::system("command -v node >/dev/null 2>&1") != 0) GTEST_SKIP() << "`node` missing";
    if (::access((dir + "/node_modules/node-opcua").c_str(), R_OK) != 0)
        GTEST_SKIP() << "node_modules/node-opcua missing (npm ci)";

    server::ServerConfig cfg = pnp::testing::loopbackConfig();
    cfg.applicationUri = "urn:pnp:lds";
    cfg.discovery.localDiscoveryServer = true;
    cfg.discovery.registrationExpiry = std::chrono::seconds(30);
    server::Server server(cfg);
    server.start();

    // Bounded by `timeout` (the script has its own 45 s deadline); node-opcua's own logging
    // goes to stderr, the checks to stdout.
    const std::string log =
        ::testing::TempDir() + "pnp_lds_interop_" + std::to_string(::getpid()) + ".stderr";
    const std::string cmd =
        "timeout -k 5 60 node '" + script + "' '" + pnp::testing::url(server) + "' 2>'" + log + "'";
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string out;
    char buf[512];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    int status = ::pclose(p);
    std::printf("%s", out.c_str());
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
        << "node_lds_client.js failed (stderr in " << log << ")";
    EXPECT_NE(out.find(" 0 failed"), std::string::npos);
}
