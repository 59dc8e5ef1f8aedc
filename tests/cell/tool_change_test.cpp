// The Plug & Produce moment of the cell as a user runs it: `pnp lds`, `pnp sim`, the robot,
// both tools' adapters, the Kelvin ADC board and the tool changer component as real
// processes on loopback (each stopped by its PID). ChangeTool moves the robot through the
// docking sequence; the world's ground truth says which tool is really locked, the tool's
// adapter comes up with power and its skills are detected, the previous tool's are gone; a
// grasp on empty air fails; a halt mid-change stops the robot and the next change works.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "support/child_process.hpp"
#include "support/shell.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY must be defined"
#endif

namespace {

using namespace std::chrono_literals;
using pnp::testing::ChildProcess;

std::string tmpPath(const std::string& name) { return pnp::testing::tmpPath("toolchange", name); }

int run(const std::string& command, std::string& out) {
    return pnp::testing::runShell(command, out);
}

const std::string kPnp = PNP_BINARY;

struct Eigen3d {
    double x = 0, y = 0, z = 0;
};
// The docks of the thesis cell (models/cells/thesis.yaml) as ThreeDFrames x,y,z,a,b,c.
const std::string kDock1 = "-0.125,0.513,-0.036,0,3.14159265358979,0";  // vacuum gripper
const std::string kDock2 = "0.125,0.513,-0.036,0,3.14159265358979,0";   // parallel gripper

class ToolChange : public ::testing::Test {
  protected:
    void SetUp() override {
        std::string error, line;
        // Everything registers with one LDS (no multicast needed on loopback).
        ASSERT_TRUE(lds_.start(
            {kPnp, "lds", "--port", "0", "--host", "127.0.0.1", "--public-host", "127.0.0.1"},
            tmpPath("lds.log"), error))
            << error;
        ASSERT_TRUE(lds_.waitForPrefix("listening on ", 20s, error, &line)) << lds_.logTail();
        lds = line.substr(13);
        const std::vector<std::string> net = {
            "--host", "127.0.0.1", "--public-host", "127.0.0.1",
            "--lds",  lds,         "--mdns-port",   std::to_string(mdnsPort())};
        auto with = [&](std::vector<std::string> argv) {
            argv.insert(argv.end(), net.begin(), net.end());
            return argv;
        };
        ASSERT_TRUE(sim_.start(with({kPnp, "sim", "--ephemeral-ports", "--port", "0"}),
                               tmpPath("sim.log"), error))
            << error;
        ASSERT_TRUE(sim_.waitForPrefix("{", 20s, error, &line)) << sim_.logTail();
        const auto info = nlohmann::json::parse(line);
        world = info.at("world");
        auto address = [&](const std::string& device) {
            for (const auto& d : info.at("devices"))
                if (d.at("device") == device) return d.at("address").get<std::string>();
            ADD_FAILURE() << "no " << device << " in " << line;
            return std::string();
        };
        ASSERT_TRUE(ur_.start(with({kPnp, "device", "ur", "--controller", address("ur-controller"),
                                    "--port", "0", "--world-to-base", "-0.3,0,0,0,0,0"}),
                              tmpPath("ur.log"), error))
            << error;
        // The tools' ApplicationUris are what ChangeTool's ToolAppUri names: stable, given.
        parallelUri = "urn:pnp:test:robotiq-" + std::to_string(::getpid());
        vacuumUri = "urn:pnp:test:ecbpi-" + std::to_string(::getpid());
        ASSERT_TRUE(
            robotiq_.start(with({kPnp, "device", "robotiq", "--serial", address("robotiq-2f85"),
                                 "--ua-port", "0", "--application-uri", parallelUri}),
                           tmpPath("robotiq.log"), error))
            << error;
        ASSERT_TRUE(
            ecbpi_.start(with({kPnp, "device", "ecbpi", "--iolink", address("schmalz-ecbpi"),
                               "--port", "1", "--ua-port", "0", "--application-uri", vacuumUri}),
                         tmpPath("ecbpi.log"), error))
            << error;
        ASSERT_TRUE(adc_.start(with({kPnp, "device", "kelvin-adc", "--adc",
                                     address("kelvin-adc-input"), "--port", "0"}),
                               tmpPath("adc.log"), error))
            << error;
        ASSERT_TRUE(ur_.waitForPrefix("listening on ", 30s, error, &line)) << ur_.logTail();
        robot = line.substr(13);
        ASSERT_TRUE(adc_.waitForPrefix("listening on ", 30s, error, &line)) << adc_.logTail();
        const std::string adc = line.substr(13);
        ASSERT_TRUE(changer_.start(with({kPnp, "component", "toolchanger", "--robot", robot,
                                         "--adc", adc, "--port", "0", "--no-mdns"}),
                                   tmpPath("changer.log"), error))
            << error;
        ASSERT_TRUE(changer_.waitForPrefix("listening on ", 30s, error, &line))
            << changer_.logTail();
        changer = line.substr(13);
    }

    void TearDown() override {
        for (ChildProcess* p : {&changer_, &adc_, &ecbpi_, &robotiq_, &ur_, &sim_, &lds_})
            p->stop();
    }

    static int mdnsPort() { return 20000 + static_cast<int>(::getpid() % 20000); }

    // `pnp skill run` on the tool changer; the exit code, stdout in `out`.
    int changeTool(const std::string& dock, const std::string& uri, std::string& out,
                   int timeoutMs = 60000) {
        return run("timeout -k 5 120 " + kPnp + " skill run " + changer +
                       " --skill ChangeTool --json --timeout " + std::to_string(timeoutMs) +
                       " ToolPosition=" + dock + " ToolAppUri=" + uri + " 2>&1",
                   out);
    }

    std::string read(const std::string& node) {
        std::string out;
        run("timeout -k 5 30 " + kPnp + " ua read " + world + " 'nsu=urn:pnp:sim:world;s=" + node +
                "' --json 2>&1",
            out);
        return out;
    }

    // The skills the network offers now (names with their component's ApplicationUri).
    std::string skills() {
        std::string out;
        run("timeout -k 5 30 " + kPnp + " skills --once --no-mdns --lds " + lds + " --json 2>&1",
            out);
        return out;
    }

    // The value of a ground truth variable.
    nlohmann::json value(const std::string& node) {
        const std::string r = read(node);
        const auto at = r.find('{');
        if (at == std::string::npos) return {};
        return nlohmann::json::parse(r.substr(at)).at("results").at(0).at("value");
    }

    Eigen3d cubeCentre() {
        const auto v = value("Objects.cube-green.Pose").at("Body").at("CartesianCoordinates");
        return {v.at("X").get<double>(), v.at("Y").get<double>(), v.at("Z").get<double>()};
    }

    // A move skill of the robot to a TCP pose x,y,z,a,b,c (world frame, the tool's TCP).
    int move(const std::string& skill, const std::string& target, std::string& out) {
        return run("timeout -k 5 60 " + kPnp + " skill run " + robot + " --skill " + skill +
                       " --timeout 30000 TargetPosition=" + target + " 2>&1",
                   out);
    }

    std::string diagnostics() {
        return "\nsim:\n" + sim_.logTail() + "\nur:\n" + ur_.logTail() + "\nchanger:\n" +
               changer_.logTail() + "\nrobotiq:\n" + robotiq_.logTail() + "\necbpi:\n" +
               ecbpi_.logTail();
    }

    ChildProcess lds_, sim_, ur_, robotiq_, ecbpi_, adc_, changer_;
    std::string lds, world, robot, changer, parallelUri, vacuumUri;
};

TEST_F(ToolChange, ChangeToolLocksTheRightToolAndItsSkillsComeAndGo) {
    std::string out;
    // Nothing attached yet: no gripper skills anywhere.
    EXPECT_EQ(skills().find("GraspGripperSkillType"), std::string::npos) << skills();

    ASSERT_EQ(changeTool(kDock1, vacuumUri, out), 0) << out << diagnostics();
    EXPECT_NE(out.find("Completed"), std::string::npos) << out;
    EXPECT_NE(out.find("PhaseDurations"), std::string::npos) << out;
    // The world: the vacuum gripper is locked on the flange and powered.
    EXPECT_NE(read("Robots.ur5.Tool").find("vacuum-gripper"), std::string::npos);
    EXPECT_NE(read("Robots.ur5.Changer").find("Locked"), std::string::npos);
    EXPECT_NE(read("Tools.vacuum-gripper.Powered").find("true"), std::string::npos);
    // Its skills are detected (by the component, which waited for them, and by anyone).
    std::string now = skills();
    EXPECT_NE(now.find(vacuumUri), std::string::npos) << now;
    EXPECT_EQ(now.find(parallelUri), std::string::npos) << now;

    // Change to the parallel gripper: the vacuum gripper goes back to dock 1 and unplugs.
    out.clear();
    ASSERT_EQ(changeTool(kDock2, parallelUri, out), 0) << out << diagnostics();
    EXPECT_NE(read("Robots.ur5.Tool").find("parallel-gripper"), std::string::npos);
    EXPECT_NE(read("Tools.vacuum-gripper.Dock").find("dock-1"), std::string::npos);
    EXPECT_NE(read("Tools.vacuum-gripper.Powered").find("false"), std::string::npos);
    now = skills();
    EXPECT_NE(now.find(parallelUri), std::string::npos) << now;
    EXPECT_EQ(now.find(vacuumUri), std::string::npos) << now;

    // A grasp on empty air (the robot is above the docks): Failed, saying why.
    out.clear();
    const int rc =
        run("timeout -k 5 60 " + kPnp + " skill run GraspGripperSkillType --no-mdns --lds " + lds +
                " --timeout 20000 2>&1",
            out);
    EXPECT_EQ(rc, 3) << out;
    EXPECT_NE(out.find("no object"), std::string::npos) << out;
    EXPECT_EQ(value("Tools.parallel-gripper.Held"), "");
    // The fingers closed on nothing: open them, or they would hit the cube's top face.
    out.clear();
    ASSERT_EQ(
        run("timeout -k 5 60 " + kPnp + " skill run ReleaseGripperSkillType --no-mdns --lds " +
                lds + " --timeout 20000 2>&1",
            out),
        0)
        << out;

    // Around the cube it holds: the tool changer set the gripper's grip point as the robot's
    // tool frame, so the TCP goes to the cube's centre (the flange pointing down).
    // Up out of the docks first: below them the tool hangs beside the table, and a path
    // through the table would end in a protective stop (the world's contact force).
    const std::string down = ",0,3.14159265358979,0";  // as the tool hung in its dock
    out.clear();
    ASSERT_EQ(move("CartesianLinearMove", "0.125,0.513,0.15" + down, out), 0) << out;
    ASSERT_EQ(move("CartesianPtpMove", "0.05,0.10,0.10" + down, out), 0) << out << diagnostics();
    ASSERT_EQ(move("CartesianLinearMove", "0.05,0.10,0.02" + down, out), 0) << out;
    out.clear();
    ASSERT_EQ(run("timeout -k 5 60 " + kPnp + " skill run GraspGripperSkillType --no-mdns --lds " +
                      lds + " --timeout 20000 2>&1",
                  out),
              0)
        << out << diagnostics();
    EXPECT_EQ(value("Tools.parallel-gripper.Held"), "cube-green");
    // Carried to the thesis's place position and set down: it ends where the world says.
    ASSERT_EQ(move("CartesianLinearMove", "0.05,0.10,0.10" + down, out), 0) << out;
    EXPECT_NEAR(cubeCentre().z, 0.10, 1e-3);
    ASSERT_EQ(move("CartesianPtpMove", "-0.05,-0.10,0.10" + down, out), 0) << out;
    ASSERT_EQ(move("CartesianLinearMove", "-0.05,-0.10,0.025" + down, out), 0) << out;
    out.clear();
    ASSERT_EQ(
        run("timeout -k 5 60 " + kPnp + " skill run ReleaseGripperSkillType --no-mdns --lds " +
                lds + " --timeout 20000 2>&1",
            out),
        0)
        << out;
    EXPECT_EQ(value("Tools.parallel-gripper.Held"), "");
    EXPECT_EQ(value("Objects.cube-green.Holder"), "table");
    const Eigen3d c = cubeCentre();
    EXPECT_NEAR(c.x, -0.05, 1e-3);
    EXPECT_NEAR(c.y, -0.10, 1e-3);
    EXPECT_NEAR(c.z, 0.02, 1e-9);
}

TEST_F(ToolChange, HaltMidChangeStopsTheRobotAndTheNextChangeWorks) {
    std::string out, error;
    auto joints = [&] {
        const std::string r = read("Robots.ur5.Joints");
        const auto at = r.find('{');
        if (at == std::string::npos) return nlohmann::json();
        return nlohmann::json::parse(r.substr(at)).at("results").at(0).at("value");
    };
    auto still = [](const nlohmann::json& a, const nlohmann::json& b) {
        if (a.size() != 6 || b.size() != 6) return false;
        for (std::size_t j = 0; j < 6; ++j)
            if (std::abs(a[j].get<double>() - b[j].get<double>()) > 1e-5) return false;
        return true;
    };
    // The operator's Ctrl-C while the robot is on its way to dock 1: `pnp skill run` halts the
    // skill and unlocks it (exit 3). It is sent once the world says the robot moves, so the
    // time the command needs to connect does not matter.
    const nlohmann::json before = joints();
    ChildProcess cli;
    ASSERT_TRUE(
        cli.start({kPnp, "skill", "run", changer, "--skill", "ChangeTool", "--json", "--timeout",
                   "60000", "ToolPosition=" + kDock1, "ToolAppUri=" + vacuumUri},
                  tmpPath("halt-cli.log"), error))
        << error;
    bool moving = false;
    for (int i = 0; i < 200 && !moving && cli.running(); ++i) {  // at most ~20 s
        std::this_thread::sleep_for(100ms);
        moving = !still(before, joints());
    }
    ASSERT_TRUE(moving) << "the robot never moved\n" << cli.logTail() << diagnostics();
    std::this_thread::sleep_for(300ms);  // well under way
    ::kill(cli.pid(), SIGINT);
    const std::optional<int> code = cli.waitExit(20s);
    out = cli.readAll(2s);
    ASSERT_TRUE(code.has_value()) << "pnp skill run did not end 20 s after SIGINT";
    EXPECT_EQ(*code, 3) << out << cli.logTail();
    EXPECT_NE(out.find("\"Aborted\""), std::string::npos) << out;
    EXPECT_NE(out.find("Halted"), std::string::npos) << out;
    // The robot comes to rest where it was: within 3 s of the halt (braking along the path at
    // the move's deceleration), no joint moves more than 1e-5 rad (5 µm at the TCP) in 0.3 s.
    bool atRest = false;
    const auto until = std::chrono::steady_clock::now() + 3s;
    nlohmann::json a = joints(), b;
    while (!atRest && std::chrono::steady_clock::now() < until) {
        std::this_thread::sleep_for(300ms);
        b = joints();
        atRest = still(a, b);
        a = b;
    }
    EXPECT_TRUE(atRest) << "still moving 3 s after the halt: " << a.dump();
    EXPECT_NE(read("Robots.ur5.Changer").find("Open"), std::string::npos);
    // Nothing was locked; the next change (after the reset the run does) completes.
    out.clear();
    ASSERT_EQ(changeTool(kDock1, vacuumUri, out), 0) << out << diagnostics();
    EXPECT_NE(read("Robots.ur5.Tool").find("vacuum-gripper"), std::string::npos);
}

}  // namespace
