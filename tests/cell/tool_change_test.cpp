// The Plug & Produce moment of the cell as a user runs it: `pnp lds`, `pnp sim`, the robot,
// both tools' adapters, the Kelvin ADC board and the tool changer component as real
// processes on loopback (each stopped by its PID). ChangeTool moves the robot through the
// docking sequence; the world's ground truth says which tool is really locked, the tool's
// adapter comes up with power and its skills are detected, the previous tool's are gone; a
// grasp on empty air fails; a halt mid-change stops the robot and the next change works.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <nlohmann/json.hpp>
#include <optional>
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

// An ISO-8601 UTC time as `pnp ua monitor --json` prints it (2026-11-27T16:55:00.1234567Z).
std::optional<std::chrono::system_clock::time_point> isoTime(const std::string& text) {
    std::tm tm{};
    int sec = 0;
    if (std::sscanf(text.c_str(), "%4d-%2d-%2dT%2d:%2d:%2d", &tm.tm_year, &tm.tm_mon, &tm.tm_mday,
                    &tm.tm_hour, &tm.tm_min, &sec) != 6)
        return std::nullopt;
    tm.tm_year -= 1900;
    tm.tm_mon -= 1;
    tm.tm_sec = sec;
    auto t = std::chrono::system_clock::from_time_t(::timegm(&tm));
    if (const auto dot = text.find('.'); dot != std::string::npos) {
        long long scale = 1000000;  // µs of the first digit
        for (std::size_t i = dot + 1; i < text.size() && std::isdigit(text[i]) && scale > 0;
             ++i, scale /= 10)
            t += std::chrono::microseconds((text[i] - '0') * scale / 10);
    }
    return t;
}

TEST_F(ToolChange, HaltMidChangeStopsTheRobotAndTheNextChangeWorks) {
    std::string out, error, line;
    auto still = [](const nlohmann::json& a, const nlohmann::json& b) {
        if (a.size() != 6 || b.size() != 6) return false;
        for (std::size_t j = 0; j < 6; ++j)
            if (std::abs(a[j].get<double>() - b[j].get<double>()) > 1e-5) return false;
        return true;
    };
    // The robot's joints as the world publishes them, each change with the world's time stamp:
    // when the robot came to rest is then judged on the world's clock, not on how long a
    // read takes (seconds in a sanitized build on a loaded machine).
    ChildProcess monitor;
    ASSERT_TRUE(
        monitor.start({kPnp, "ua", "monitor", world, "nsu=urn:pnp:sim:world;s=Robots.ur5.Joints",
                       "--interval", "20", "--json"},
                      tmpPath("halt-monitor.log"), error))
        << error;
    struct Sample {
        nlohmann::json joints;
        std::chrono::system_clock::time_point at;
    };
    auto nextSample = [&](std::chrono::milliseconds timeout) -> std::optional<Sample> {
        std::string l, e;
        if (!monitor.waitForPrefix("{", timeout, e, &l)) return std::nullopt;
        const auto j = nlohmann::json::parse(l, nullptr, false);
        if (j.is_discarded() || !j.contains("value") || !j.contains("sourceTimestamp"))
            return std::nullopt;
        const auto at = isoTime(j.at("sourceTimestamp").get<std::string>());
        if (!at) return std::nullopt;
        return Sample{j.at("value"), *at};
    };
    const auto first = nextSample(30s);
    ASSERT_TRUE(first.has_value()) << "no joints from the world\n" << monitor.logTail();

    // The operator's Ctrl-C while the robot is on its way to dock 1: `pnp skill run` halts the
    // skill and unlocks it (exit 3). It is sent once the world says the robot moves, so the
    // time the command needs to connect does not matter.
    ChildProcess cli;
    ASSERT_TRUE(
        cli.start({kPnp, "skill", "run", changer, "--skill", "ChangeTool", "--json", "--timeout",
                   "60000", "ToolPosition=" + kDock1, "ToolAppUri=" + vacuumUri},
                  tmpPath("halt-cli.log"), error))
        << error;
    bool moving = false;
    const auto movingBy = std::chrono::steady_clock::now() + 30s;
    while (!moving && std::chrono::steady_clock::now() < movingBy) {
        const auto s = nextSample(1s);
        moving = s && !still(first->joints, s->joints);
        if (!s && !cli.running()) break;
    }
    ASSERT_TRUE(moving) << "the robot never moved\n" << cli.logTail() << diagnostics();
    std::this_thread::sleep_for(300ms);  // well under way
    const auto halt = std::chrono::system_clock::now();
    ::kill(cli.pid(), SIGINT);
    const std::optional<int> code = cli.waitExit(30s);
    out = cli.readAll(2s);
    ASSERT_TRUE(code.has_value()) << "pnp skill run did not end 30 s after SIGINT";
    EXPECT_EQ(*code, 3) << out << cli.logTail();
    EXPECT_NE(out.find("\"Aborted\""), std::string::npos) << out;
    EXPECT_NE(out.find("Halted"), std::string::npos) << out;
    // The robot comes to rest where it was: within 3 s of the halt on the world's clock
    // (braking along the path at the move's deceleration), then no joint moves more than
    // 1e-5 rad (5 µm at the TCP) while the world publishes nothing new for 2 s.
    std::vector<Sample> after;
    bool quiet = false;
    const auto collectUntil = std::chrono::steady_clock::now() + 30s;
    while (!quiet && std::chrono::steady_clock::now() < collectUntil) {
        if (auto s = nextSample(2s))
            after.push_back(std::move(*s));
        else
            quiet = true;
    }
    ASSERT_TRUE(quiet) << "the robot still moves 30 s after the halt";
    auto restedAt = halt;
    for (const auto& s : after)
        if (s.at > halt && !after.empty() && !still(s.joints, after.back().joints)) restedAt = s.at;
    EXPECT_LE(restedAt - halt, std::chrono::seconds(3))
        << "still moving "
        << std::chrono::duration_cast<std::chrono::milliseconds>(restedAt - halt).count()
        << " ms after the halt";
    EXPECT_TRUE(monitor.running()) << "the world's monitor ended: " << monitor.logTail();
    monitor.stop();
    EXPECT_NE(read("Robots.ur5.Changer").find("Open"), std::string::npos);
    // Nothing was locked; the next change (after the reset the run does) completes.
    out.clear();
    ASSERT_EQ(changeTool(kDock1, vacuumUri, out), 0) << out << diagnostics();
    EXPECT_NE(read("Robots.ur5.Tool").find("vacuum-gripper"), std::string::npos);
}

}  // namespace
