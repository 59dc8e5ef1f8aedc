// `pnp device robotiq` end to end, as processes: `pnp sim` (the simulated 2F-85 on a
// pseudo-terminal, the thesis cell: the gripper in its dock, unpowered) and `pnp device robotiq
// --serial` on it. Plug & produce: no server while the tool is parked; `pnp sim tool attach`
// powers it and the gripper device comes up (Grasp on empty air fails saying so, MoveGripper
// completes); `detach` takes it away; attach again: back on the same endpoint. SIGTERM ends it.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdlib>
#include <string>

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

std::string tempPath(const std::string& what) {
    return ::testing::TempDir() + "pnp_device_robotiq_" + std::to_string(::getpid()) + "." + what;
}

// The value of "key":"..." after `from` in a JSON line ("" when absent).
std::string jsonString(const std::string& line, const std::string& key, std::size_t from = 0) {
    const std::string k = "\"" + key + "\":\"";
    const auto at = line.find(k, from);
    if (at == std::string::npos) return {};
    const auto start = at + k.size();
    return line.substr(start, line.find('"', start) - start);
}

bool accepts(const std::string& url) {
    ua::client::Client c;
    try {
        c.connect(url);
        c.disconnect();
        return true;
    } catch (const std::exception&) {
        return false;
    }
}

// `pnp sim tool attach|detach` (bounded by `timeout`): its exit status 0?
bool operatorAction(const std::string& action, const std::string& world) {
    std::string cmd = "timeout -k 5 30 '" + std::string(PNP_BINARY) + "' sim tool " + action;
    if (action == "attach") cmd += " parallel-gripper";
    cmd +=
        " --robot ur5 --world '" + world + "' >/dev/null 2>>'" + tempPath("operator.stderr") + "'";
    return std::system(cmd.c_str()) == 0;
}

TEST(DeviceRobotiqCli, ServesTheGripperOnlyWhileItIsAttached) {
    pnp::testing::useMachinePki();
    pnp::testing::ChildProcess sim;
    std::string error, line;
    ASSERT_TRUE(sim.start({PNP_BINARY, "sim", "--ephemeral-ports", "--port", "0", "--host",
                           "127.0.0.1", "--no-register"},
                          tempPath("sim.stderr"), error))
        << error;
    ASSERT_TRUE(sim.waitForPrefix("{", 60s, error, &line)) << error << sim.logTail();
    const std::string world = jsonString(line, "world");
    const auto robotiq = line.find("\"device\":\"robotiq-2f85\"");
    ASSERT_NE(robotiq, std::string::npos) << line;
    const std::string pty = jsonString(line, "address", robotiq);
    ASSERT_FALSE(world.empty()) << line;
    ASSERT_EQ(pty.rfind("/dev/", 0), 0u) << line;

    // The start-up deadlines above and the waits below are generous: a loaded machine (CI
    // runs the tests in parallel, the sanitizers slow every process) starts both processes
    // slowly. Likewise the polls' timeout and the grace time (the lifecycle's timing is
    // tool_adapter_test's): a simulator that is not scheduled for 100 ms is not unplugged.
    const unsigned short port = pnp::testing::freeLoopbackPort();
    pnp::testing::ChildProcess dev;
    ASSERT_TRUE(
        dev.start({PNP_BINARY, "device", "robotiq", "--serial", pty, "--port", std::to_string(port),
                   "--host", "127.0.0.1", "--no-register", "--name", "Robotiq", "--speed", "0.15",
                   "--poll-timeout", "500", "--grace", "3000"},
                  tempPath("device.stderr"), error))
        << error;
    ASSERT_TRUE(dev.waitForPrefix("{", 60s, error, &line)) << error << dev.logTail();
    const std::string url = jsonString(line, "endpointUrl");
    EXPECT_EQ(url, "opc.tcp://127.0.0.1:" + std::to_string(port));
    EXPECT_EQ(jsonString(line, "applicationUri"), "urn:pnp:127.0.0.1:" + std::to_string(port));
    EXPECT_NE(line.find("\"skills\":[\"Grasp\",\"Release\",\"MoveGripper\"]"), std::string::npos)
        << line;

    // Parked in its dock: no power, no server.
    std::this_thread::sleep_for(300ms);
    EXPECT_FALSE(accepts(url));

    // Attached: powered, served.
    ASSERT_TRUE(operatorAction("attach", world));
    ASSERT_TRUE(pnp::testing::waitUntil([&] { return accepts(url); }, 30000ms)) << dev.logTail();
    {
        auto ua = std::make_shared<ua::client::Client>();
        ua->connect(url);
        const auto sk = ua->namespaceIndex("urn:pnp:ua:skills", 5s);
        const auto di = ua->namespaceIndex("http://opcfoundation.org/UA/DI/", 5s);
        const std::string skills = "/1:Robotiq/" + std::to_string(sk) + ":Skills/1:";
        const ua::NodeId deviceSet(di, ua::UInt32{5001});
        skill::client::GraspGripperSkillClient grasp(
            ua, ua->resolve(deviceSet, skills + "Grasp", 5s), 5s);
        auto g = grasp.run(40.0, 20s);
        EXPECT_EQ(g.result, skill::SkillResult::Failed);
        EXPECT_EQ(g.message.rfind("Grasp failed: no object between the fingers", 0), 0u)
            << g.message;
        skill::client::MoveGripperSkillClient move(
            ua, ua->resolve(deviceSet, skills + "MoveGripper", 5s), 5s);
        auto m = move.run(0.04, 40.0, 20s);
        EXPECT_EQ(m.result, skill::SkillResult::Completed) << m.message;
        ua->disconnect();
    }

    // Detached: the server goes.
    ASSERT_TRUE(operatorAction("detach", world));
    EXPECT_TRUE(pnp::testing::waitUntil([&] { return !accepts(url); }, 30000ms)) << dev.logTail();

    // Attached again: the same endpoint.
    ASSERT_TRUE(operatorAction("attach", world));
    EXPECT_TRUE(pnp::testing::waitUntil([&] { return accepts(url); }, 30000ms)) << dev.logTail();

    dev.stop();
    sim.stop();
}

}  // namespace
