// node-opcua as an independent client of RobotDevice: the device runs in this process over
// the fake arm (127.0.0.1, ephemeral port); tests/device/node_robot_client.js finds the
// Robotics nodes and the CartesianLinearMove skill by browsing, runs the move with standard
// services only and prints the axes' ActualPosition afterwards, which must be where the arm
// is. Skipped (not failed) when `node` or node-opcua is missing.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <sstream>
#include <string>

#include "robot_rig.hpp"
#include "ua/spatial/spatial.hpp"

#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

namespace {

TEST(RobotDeviceInterop, NodeOpcuaRunsACartesianLinearMoveAndReadsTheAxes) {
    const std::string dir = PNP_SOURCE_DIR;
    const std::string script = dir + "/tests/device/node_robot_client.js";
    if (std::system("command -v node >/dev/null 2>&1") != 0) GTEST_SKIP() << "`node` missing";
    if (::access((dir + "/node_modules/node-opcua").c_str(), R_OK) != 0)
        GTEST_SKIP() << "node_modules/node-opcua missing (npm ci)";

    pnp::testing::Rig rig;
    Eigen::Isometry3d target = rig.flangeAt(rig.arm.q());
    target.translation() += Eigen::Vector3d(0.04, -0.03, 0.05);
    const auto f = pnp::ua::spatial::toFrame(target);
    char frame[256];
    std::snprintf(frame, sizeof frame, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g",
                  f.cartesianCoordinates.x, f.cartesianCoordinates.y, f.cartesianCoordinates.z,
                  f.orientation.a, f.orientation.b, f.orientation.c);

    // Bounded by `timeout` (the script has its own deadline); node-opcua's logging goes to
    // stderr, the checks to stdout.
    const std::string log =
        ::testing::TempDir() + "pnp_device_interop_" + std::to_string(::getpid()) + ".stderr";
    const std::string cmd = "timeout -k 5 90 node '" + script + "' '" +
                            pnp::testing::url(rig.server) + "' '" + frame + "' 2>'" + log + "'";
    FILE* p = ::popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    std::string out;
    char buf[512];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    const int status = ::pclose(p);
    std::printf("%s", out.c_str());
    ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
        << "node_robot_client.js failed (exit status " << status << ", node stderr in " << log
        << "):\n"
        << out;
    EXPECT_NE(out.find(" 0 failed"), std::string::npos) << out;

    // The arm is at the target, and node-opcua saw its joints.
    EXPECT_TRUE(pnp::testing::waitUntil([&] { return rig.arm.atRest(); }, 1000ms));
    const Eigen::Isometry3d reached = rig.flangeAt(rig.arm.q());
    EXPECT_LE((reached.translation() - target.translation()).norm(), 1e-5);
    const auto at = out.find("final-joints: [");
    ASSERT_NE(at, std::string::npos) << out;
    std::string list = out.substr(at + 15, out.find(']', at) - at - 15);
    for (char& c : list)
        if (c == ',') c = ' ';
    std::istringstream in(list);
    const auto q = rig.arm.q();
    for (std::size_t i = 0; i < q.size(); ++i) {
        double v = 0.0;
        ASSERT_TRUE(in >> v) << list;
        EXPECT_NEAR(v, q[i], 1e-12) << "axis " << i + 1;
    }
}

}  // namespace
