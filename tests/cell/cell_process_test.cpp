// The simulated cell as a user runs it: `pnp sim`, `pnp device ur` and `pnp robot square`
// as real processes on loopback (each stopped by its PID), and `pnp sim` refusing a bad
// cell file with file, line and problem.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/child_process.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY must be defined"
#endif

namespace {

using namespace std::chrono_literals;

std::string tmpPath(const std::string& name) {
    return ::testing::TempDir() + "pnp_cell_" + std::to_string(::getpid()) + "_" + name;
}

// Runs a command (bounded by `timeout -k`), returns its exit status and stdout.
int run(const std::string& command, std::string& out) {
    FILE* p = ::popen(command.c_str(), "r");
    if (p == nullptr) return -1;
    char buf[4096];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    const int status = ::pclose(p);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(CellProcesses, SquareTestThroughSimulatorAdapterAndSkills) {
    pnp::testing::ChildProcess sim;
    std::string error, line;
    ASSERT_TRUE(sim.start({PNP_BINARY, "sim", "--ephemeral-ports", "--port", "0", "--host",
                           "127.0.0.1", "--public-host", "127.0.0.1", "--no-register"},
                          tmpPath("sim.stderr"), error))
        << error;
    ASSERT_TRUE(sim.waitForPrefix("{", 20s, error, &line)) << error << sim.logTail();
    const auto info = nlohmann::json::parse(line);
    // The robot's controller, the three tools' devices and the changer's ADC input.
    ASSERT_EQ(info.at("devices").size(), 5u) << line;
    const auto& ur = info.at("devices").at(0);
    EXPECT_EQ(ur.at("device"), "ur-controller");
    EXPECT_EQ(ur.at("protocol"), "rtde");
    const std::string world = info.at("world");
    EXPECT_EQ(info.at("rate"), 500.0);

    pnp::testing::ChildProcess device;
    ASSERT_TRUE(device.start(
        {PNP_BINARY, "device", "ur", "--controller", ur.at("address").get<std::string>(), "--port",
         "0", "--host", "127.0.0.1", "--public-host", "127.0.0.1", "--no-register",
         "--world-to-base", "-0.3,0,0,0,0,0"},
        tmpPath("device.stderr"), error))
        << error;
    ASSERT_TRUE(device.waitForPrefix("listening on ", 20s, error, &line))
        << error << device.logTail();
    const std::string url = line.substr(std::string("listening on ").size());

    std::string out;
    const int rc = run("timeout -k 5 120 " + std::string(PNP_BINARY) + " robot square " + url +
                           " --world " + world + " --size 0.1 --json 2>" + tmpPath("square.stderr"),
                       out);
    ASSERT_EQ(rc, 0) << out << "\nsim:\n" << sim.logTail() << "\ndevice:\n" << device.logTail();
    const auto result = nlohmann::json::parse(out.substr(out.find('{')));
    std::printf("square: %s\n", result.dump().c_str());
    EXPECT_EQ(result.at("moves").size(), 6u);
    for (const auto& m : result.at("moves")) EXPECT_EQ(m.at("result"), "Completed") << m.dump();
    EXPECT_GT(result.at("samples").get<int>(), 100);
    // The targets: LIN path within 0.1 mm of the square, PTP end pose within 0.01 mm,
    // both read from the world's ground truth.
    EXPECT_LE(result.at("maxDeviationMm").get<double>(), 0.1);
    EXPECT_LE(result.at("maxEndErrorMm").get<double>(), 0.01);
    EXPECT_TRUE(sim.running());
    EXPECT_TRUE(device.running());
    device.stop();
    sim.stop();
}

TEST(CellProcesses, SimRefusesABadCellFileWithFileLineAndProblem) {
    const std::string file = tmpPath("bad.yaml");
    {
        std::ofstream f(file);
        f << "pnp-cell: 1\nname: bad\nrobots:\n  - name: r\n    model: ur99\n";
    }
    std::string out;
    const int rc = run("timeout -k 5 30 " + std::string(PNP_BINARY) + " sim --cell " + file +
                           " --no-register 2>&1",
                       out);
    EXPECT_EQ(rc, 2) << out;
    EXPECT_NE(out.find(file + ":5:"), std::string::npos) << out;
    EXPECT_NE(out.find("ur99"), std::string::npos) << out;
}

}  // namespace
