// `pnp device ur` end to end, as processes: `pnp sim` (the simulated UR controller on RTDE)
// and `pnp device ur --controller` on it, driven by our OPC UA client: a JointPtpMove reaches
// its target (the axes' ActualPosition show it); SIGTERM during a move halts the arm short of
// its goal and the device exits 0.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <string>
#include <thread>
#include <vector>

#include "skill/client/skill_client.hpp"
#include "skill/client/typed_clients.hpp"
#include "support/child_process.hpp"
#include "support/machine_pki.hpp"
#include "support/wait.hpp"
#include "ua/client/client.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY (path of the pnp executable) must be defined"
#endif

using namespace std::chrono_literals;
using namespace pnp;

namespace {

std::string tmp(const std::string& what) {
    return ::testing::TempDir() + "pnp_device_ur_" + std::to_string(::getpid()) + "." + what;
}

// `pnp device ur` on the simulator's RTDE address; its endpoint URL in *url.
bool startDevice(pnp::testing::ChildProcess& p, const std::string& rtde, const std::string& log,
                 std::string* url, std::string& error) {
    if (!p.start({PNP_BINARY, "device", "ur", "--controller", rtde, "--port", "0", "--host",
                  "127.0.0.1", "--no-register", "--name", "Robo"},
                 log, error))
        return false;
    std::string line;
    if (!p.waitForPrefix("listening on ", 20s, error, &line)) return false;
    *url = line.substr(std::string("listening on ").size());
    return true;
}

std::vector<double> axes(ua::client::Client& c, const std::string& what) {
    std::vector<double> q;
    for (int i = 1; i <= 6; ++i)
        q.push_back(
            *c.readValue(
                  ua::NodeId(1, "Robo.Axes.Axis" + std::to_string(i) + ".ParameterSet." + what), 5s)
                 .scalar<double>());
    return q;
}

TEST(DeviceUrCli, MovesTheSimulatedArmAndHaltsOnSigterm) {
    pnp::testing::useMachinePki();
    pnp::testing::ChildProcess sim;
    std::string error, line;
    ASSERT_TRUE(sim.start({PNP_BINARY, "sim", "--ephemeral-ports", "--port", "0", "--host",
                           "127.0.0.1", "--no-register"},
                          tmp("sim.stderr"), error))
        << error;
    ASSERT_TRUE(sim.waitForPrefix("{", 20s, error, &line)) << error << sim.logTail();
    // The RTDE device's address from the JSON line.
    const auto rtdeAt = line.find("\"protocol\":\"rtde\"");
    ASSERT_NE(rtdeAt, std::string::npos) << line;
    const auto addrKey = line.find("\"address\":\"", rtdeAt);
    ASSERT_NE(addrKey, std::string::npos) << line;
    const auto addrStart = addrKey + std::string("\"address\":\"").size();
    const std::string rtde = line.substr(addrStart, line.find('"', addrStart) - addrStart);

    pnp::testing::ChildProcess dev;
    std::string url;
    ASSERT_TRUE(startDevice(dev, rtde, tmp("device.stderr"), &url, error))
        << error << dev.logTail();
    {
        auto c = std::make_shared<ua::client::Client>();
        c->connect(url);
        skill::client::JointPtpMoveSkillClient move(c, ua::NodeId(1, "Robo.JointPtpMove"), 5s);
        const std::vector<double> goal{0.4, -1.3, 1.3, -1.6, -1.5, 0.3};
        auto r = move.run(skill::client::JointMove{goal, {}, {}, ""}, 30s);
        ASSERT_EQ(r.result, skill::SkillResult::Completed) << r.message;
        std::vector<double> q;
        EXPECT_TRUE(pnp::testing::waitUntil(
            [&] {
                q = axes(*c, "ActualPosition");
                for (std::size_t i = 0; i < q.size(); ++i)
                    if (std::abs(q[i] - goal[i]) > 1e-3) return false;
                return true;
            },
            3000ms))
            << q[0] << " " << q[1] << " " << q[2];

        // A long move, then SIGTERM: the device halts it and exits 0.
        skill::client::SkillClient s(c, ua::NodeId(1, "Robo.JointPtpMove"), 5s);
        s.setParameters({{"TargetJointPosition",
                          ua::Variant(std::vector<double>{-2.4, -1.3, 1.3, -1.6, -1.5, 0.3})}},
                        5s);
        s.start(5s);
        ASSERT_TRUE(pnp::testing::waitUntil(
            [&] { return std::abs(axes(*c, "ActualSpeed")[0]) > 0.5; }, 5000ms));
        c->disconnect();
    }
    const pid_t pid = dev.pid();
    ASSERT_EQ(::kill(pid, SIGTERM), 0);
    // WNOWAIT: the exit status without reaping (dev.stop() reaps, so its pid stays ours).
    siginfo_t info{};
    bool exited = false;
    for (int i = 0; i < 500 && !exited; ++i) {  // at most 10 s
        info = {};
        exited = ::waitid(P_PID, static_cast<id_t>(pid), &info, WEXITED | WNOHANG | WNOWAIT) == 0 &&
                 info.si_pid == pid;
        if (!exited) std::this_thread::sleep_for(20ms);
    }
    ASSERT_TRUE(exited) << "the device did not exit within 10 s";
    EXPECT_TRUE(info.si_code == CLD_EXITED && info.si_status == 0)
        << info.si_code << " " << info.si_status << dev.logTail();
    dev.stop();
    EXPECT_NE(dev.logTail().find("SIGTERM, stopping"), std::string::npos) << dev.logTail();

    // A new device on the same arm: at rest, short of the goal.
    pnp::testing::ChildProcess again;
    ASSERT_TRUE(startDevice(again, rtde, tmp("device2.stderr"), &url, error))
        << error << again.logTail();
    auto c = std::make_shared<ua::client::Client>();
    c->connect(url);
    const auto q = axes(*c, "ActualPosition");
    EXPECT_GT(q[0], -2.3) << "the arm went on to the goal";
    EXPECT_LT(q[0], 0.35);
    for (double v : axes(*c, "ActualSpeed")) EXPECT_EQ(v, 0.0);
    c->disconnect();
    again.stop();
    sim.stop();
}

}  // namespace
