// The dashboard of the simulated cell in a real browser (issue 25, point 4): `pnp cell up`
// starts the whole cell with its dashboard; tests/dashboard/browser/dashboard_test.js drives
// headless Debian Chromium (puppeteer-core) against the page: it loads without a console
// error, shows every component of the cell, runs a robot skill from the page (its states
// appear), and a device that is killed (the Pick-and-Place component's process, SIGKILL)
// disappears from the page. The transition -> page latency (the event's Time against the
// browser's clock, same machine) is measured there; a screenshot of the cell is kept in
// $PNP_ARTIFACT_DIR (scripts/test.sh: build-logs/artifacts) or the build tree.
// Every process is stopped by PID; every wait is bounded. Skipped without node, the npm
// packages (npm ci) or Debian's chromium.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "support/child_process.hpp"
#include "support/json_lines.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY (path of the pnp executable) must be defined"
#endif
#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif
#ifndef PNP_ARTIFACT_DEFAULT_DIR
#error "PNP_ARTIFACT_DEFAULT_DIR must be defined"
#endif

namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using namespace std::chrono_literals;
using pnp::testing::ChildProcess;

std::string tmpPath(const std::string& name) {
    return ::testing::TempDir() + "pnp_dashboard_browser_" + std::to_string(::getpid()) + "_" +
           name;
}

fs::path artifactDir() {
    const char* dir = std::getenv("PNP_ARTIFACT_DIR");
    fs::path out =
        dir != nullptr && *dir != '\0' ? fs::path(dir) : fs::path(PNP_ARTIFACT_DEFAULT_DIR);
    std::error_code ec;
    fs::create_directories(out, ec);
    return out;
}

// The resident memory of a process, kB (0 when gone).
long rssKb(pid_t pid) {
    std::ifstream status("/proc/" + std::to_string(pid) + "/status");
    std::string key;
    while (status >> key) {
        if (key == "VmRSS:") {
            long kb = 0;
            status >> kb;
            return kb;
        }
        std::string rest;
        std::getline(status, rest);
    }
    return 0;
}

TEST(DashboardBrowser, TheCellLiveInChromium) {
    const std::string node = pnp::testing::findInPath("node");
    if (node.empty()) GTEST_SKIP() << "`node` is not installed";
    const std::string modules = std::string(PNP_SOURCE_DIR) + "/node_modules/";
    if (!fs::exists(modules + "puppeteer-core") || !fs::exists(modules + "three"))
        GTEST_SKIP() << "node_modules/puppeteer-core or three missing (npm ci)";
    if (::access("/usr/bin/chromium", X_OK) != 0)
        GTEST_SKIP() << "/usr/bin/chromium missing (apt-get install chromium)";

    // The cell, with its dashboard on a free port.
    ChildProcess cell;
    std::string error, line;
    ASSERT_TRUE(cell.start(
        {PNP_BINARY, "cell", "up", "--dashboard-port", "0", "--log-dir", tmpPath("cell-logs")},
        tmpPath("cell.stderr"), error))
        << error;
    ASSERT_TRUE(cell.waitForPrefix("{", 180s, error, &line)) << error << "\n" << cell.logTail();
    const Json up = Json::parse(line, nullptr, false);
    ASSERT_TRUE(up.is_object()) << line;
    ASSERT_TRUE(up.contains("dashboard")) << "no dashboard in " << line << "\n" << cell.logTail();
    EXPECT_TRUE(up.at("problems").empty()) << up.at("problems").dump();
    const std::string url = up.at("dashboard").get<std::string>();
    pid_t pickPlace = 0, dashboard = 0;
    std::string robotUrl;
    for (const auto& c : up.at("children")) {
        if (c.value("name", "") == "pick-place") pickPlace = c.value("pid", 0);
        if (c.value("name", "") == "dashboard") dashboard = c.value("pid", 0);
        if (c.value("name", "") == "ur") robotUrl = c.value("url", "");
    }
    ASSERT_FALSE(robotUrl.empty()) << line;
    ASSERT_GT(pickPlace, 0) << line;
    ASSERT_GT(dashboard, 0) << line;

    // The browser: a joint move of the robot started from the page, then the Pick-and-Place
    // component killed while the page watches.
    const fs::path screenshot = artifactDir() / "dashboard-cell.png";
    ChildProcess browser;
    ASSERT_TRUE(browser.start(
        {node, std::string(PNP_SOURCE_DIR) + "/tests/dashboard/browser/dashboard_test.js", "--url",
         url, "--screenshot", screenshot.string(), "--run", "UR5/JointPtpMove", "--params",
         R"({"TargetJointPosition":"[0.3,-1.5707963267949,1.5707963267949,-1.5707963267949,-1.5707963267949,0]"})",
         "--expect-states", "Running,Ready", "--wait-gone", "PickAndPlace", "--min-components", "4",
         "--timeout-ms", "150000"},
        tmpPath("browser.stderr"), error))
        << error;
    ASSERT_TRUE(browser.waitForPrefix(R"({"event":"waiting-gone")", 150s, error))
        << error << "\n"
        << browser.logTail();
    // More transitions for the latency's median, from another client while the page
    // watches: the same move five times (the robot is there: each run is short).
    const int runs =
        std::system(("timeout -k 5 60 '" + std::string(PNP_BINARY) + "' skill run " + robotUrl +
                     " --skill JointPtpMove --repeat 5 --timeout 20000 "
                     "'TargetJointPosition=[0.3,-1.5707963267949,1.5707963267949,-1.5707963267949,"
                     "-1.5707963267949,0]' > '" +
                     tmpPath("runs.out") + "' 2>&1")
                        .c_str());
    EXPECT_EQ(runs, 0) << "pnp skill run --repeat 5: see " << tmpPath("runs.out");
    const long rss = rssKb(dashboard);
    ASSERT_EQ(::kill(pickPlace, SIGKILL), 0);
    const auto exit = browser.waitExit(60s);
    const std::string out = browser.readAll(5s);
    ASSERT_TRUE(exit.has_value()) << "the browser test did not end\n" << browser.logTail();
    const auto lines = pnp::testing::jsonLines(out);
    ASSERT_FALSE(lines.empty()) << out << "\n" << browser.logTail();
    const Json& r = lines.back();
    EXPECT_EQ(*exit, 0) << r.dump(2) << "\n" << browser.logTail();
    EXPECT_TRUE(r.value("ok", false)) << r.dump(2);
    EXPECT_TRUE(r.at("consoleErrors").empty()) << r.at("consoleErrors").dump(2);
    // Every component of the cell: the robot, the tool changer, Pick-and-Place and the MES
    // (the tools' adapters serve only while their tool is powered).
    EXPECT_EQ(r.at("components").value("expected", 0), 4) << r.dump(2);
    EXPECT_EQ(r.at("components").value("shown", 0), 4) << r.dump(2);
    const Json states = r.at("run").value("statesSeen", Json::array());
    EXPECT_NE(std::find(states.begin(), states.end(), "Running"), states.end()) << r.dump(2);
    EXPECT_TRUE(r.contains("gone")) << r.dump(2);
    EXPECT_TRUE(fs::exists(screenshot) && fs::file_size(screenshot) > 10000) << screenshot;

    // The figures (issue 25): transition -> visible in the page, the dashboard's memory.
    const Json latency = r.value("latency", Json::object());
    std::printf(
        "[ figures  ] transition -> page: median %s ms, p95 %s ms over %s transitions; "
        "page ready %s ms; dashboard RSS %.1f MB; screenshot %s\n",
        latency.value("medianMs", Json()).dump().c_str(),
        latency.value("p95Ms", Json()).dump().c_str(),
        latency.value("count", Json()).dump().c_str(),
        r.at("responsiveness").value("readyMs", Json()).dump().c_str(), rss / 1024.0,
        screenshot.c_str());
    ASSERT_GE(latency.value("count", 0), 10) << r.dump(2);
    EXPECT_LE(latency.at("medianMs").get<double>(), 50.0) << r.dump(2);
#ifndef PNP_SANITIZED_BUILD
    EXPECT_LE(rss, 50 * 1024) << "the dashboard's RSS for the thesis cell";
#endif

    browser.stop();
    cell.stop(20s);
}

}  // namespace
