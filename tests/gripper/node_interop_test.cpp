// node-opcua as an independent client of GripperDevice: the device runs in this process over
// the fake gripper (127.0.0.1, ephemeral port); tests/gripper/node_gripper_client.js finds the
// IGripperType device and its Grasp skill by browsing, reads the grip point and runs the
// grasp with standard services only — once on an object (Completed), once on empty air
// (Failed, saying so). Skipped (not failed) when `node` or node-opcua is missing.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <string>

#include "gripper_rig.hpp"

#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

namespace {

// Runs the script (bounded by `timeout`); its checks on stdout.
std::string runScript(const std::string& url, const std::string& force, const std::string& expect,
                      int& status) {
    const std::string dir = PNP_SOURCE_DIR;
    const std::string log =
        ::testing::TempDir() + "pnp_gripper_interop_" + std::to_string(::getpid()) + ".stderr";
    const std::string cmd = "timeout -k 5 90 node '" + dir +
                            "/tests/gripper/node_gripper_client.js' '" + url + "' '" + force +
                            "' '" + expect + "' 2>'" + log + "'";
    FILE* p = ::popen(cmd.c_str(), "r");
    if (p == nullptr) {
        status = -1;
        return {};
    }
    std::string out;
    char buf[512];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    status = ::pclose(p);
    std::printf("%s", out.c_str());
    return out;
}

TEST(GripperDeviceInterop, NodeOpcuaRunsAGraspWithStandardServices) {
    const std::string dir = PNP_SOURCE_DIR;
    if (std::system("command -v node >/dev/null 2>&1") != 0) GTEST_SKIP() << "`node` missing";
    if (::access((dir + "/node_modules/node-opcua").c_str(), R_OK) != 0)
        GTEST_SKIP() << "node_modules/node-opcua missing (npm ci)";

    pnp::testing::GripperRig rig;
    rig.hardware.timeScale = 20.0;
    int status = 0;
    std::string out = runScript(pnp::testing::url(rig.server), "42", "completed", status);
    ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << out;
    EXPECT_NE(out.find(" 0 failed"), std::string::npos) << out;
    EXPECT_NE(out.find("offset-z: 0.2028"), std::string::npos) << out;
    EXPECT_NE(out.find("span: [0, 0.085]"), std::string::npos) << out;
    EXPECT_EQ(rig.hardware.grasps.load(), 1);
    EXPECT_DOUBLE_EQ(rig.hardware.lastForce.load(), 42.0);
    EXPECT_TRUE(rig.hardware.holding.load());

    // Empty air: node-opcua sees the run fail with the reason.
    rig.hardware.objectPresent = false;
    out = runScript(pnp::testing::url(rig.server), "20",
                    "failed:Grasp failed: no object between the fingers", status);
    ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << out;
    EXPECT_EQ(rig.hardware.grasps.load(), 2);
}

}  // namespace
