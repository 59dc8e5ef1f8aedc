// node-opcua as an independent client of a pnp skill server: starts `pnp demo-skills` as a
// child process on a free port (stopped by its PID whatever happens) and runs
// tests/interop/node_skill_client.js against it, which drives the Delay skill with standard
// OPC UA services only (browse, write, call, events, DI locking by two sessions). Skipped (not
// failed) when `node` or node-opcua is missing.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>

#include "support/child_process.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY (path of the pnp executable) must be defined"
#endif
#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

TEST(SkillInterop, NodeOpcuaClientDrivesDelaySkill) {
    const std::string dir = std::string(PNP_SOURCE_DIR);
    const std::string script = dir + "/tests/interop/node_skill_client.js";
    if (std::system("command -v node >/dev/null 2>&1") != 0) GTEST_SKIP() << "`node` missing";
    if (::access((dir + "/node_modules/node-opcua").c_str(), R_OK) != 0)
        GTEST_SKIP() << "node_modules/node-opcua missing (npm ci)";

    const std::string tmp =
        ::testing::TempDir() + "pnp_skill_interop_" + std::to_string(::getpid());
    pnp::testing::ChildProcess server;
    std::string error;
    ASSERT_TRUE(server.start(
        {PNP_BINARY, "demo-skills", "--port", "0", "--host", "127.0.0.1", "--no-register",
         "--allow-none"},  // this test is about the skill model over None (secured: secure_interop)
        tmp + ".server.stderr", error))
        << error;
    std::string line;
    ASSERT_TRUE(server.waitForPrefix("listening on ", std::chrono::seconds(20), error, &line))
        << error << "\nserver stderr:\n"
        << server.logTail();
    const std::string url = line.substr(std::string("listening on ").size());
    ASSERT_EQ(url.rfind("opc.tcp://", 0), 0u) << line;

    // Bounded by `timeout` (the script has its own 30 s deadline); node-opcua's own logging
    // goes to stderr, the checks to stdout.
    const std::string log = tmp + ".node.stderr";
    const std::string cmd = "timeout -k 5 60 node '" + script + "' '" + url + "' 2>'" + log + "'";
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string out;
    char buf[512];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    const int status = ::pclose(p);
    const bool running = server.running();
    server.stop();
    std::printf("%s", out.c_str());
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
        << "node_skill_client.js failed (exit status " << status << ", node stderr in " << log
        << "):\n"
        << out << "\nserver stderr:\n"
        << server.logTail();
    EXPECT_NE(out.find(" 0 failed"), std::string::npos) << out;
    EXPECT_TRUE(running) << "the server exited during the run:\n" << server.logTail();
}
