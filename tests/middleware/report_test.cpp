// pnp_bench_report: a hand-made results directory (tests/middleware/data/results: 3 adapters,
// idle + CPU load, chain and overhead entries, a failed run, a skipped adapter, malformed CSV
// rows, a run without CSV) turned into report.md and PNG box plots.
#include "bench/report/report.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>

namespace fs = std::filesystem;
using pnp::bench::report::Options;
using pnp::bench::report::writeReport;

namespace {

// A private copy of the data: the report writes into the directory.
class ReportTest : public ::testing::Test {
  protected:
    void SetUp() override {
        dir_ = fs::temp_directory_path() /
               ("pnp_mw_report_" + std::to_string(::getpid()) + "_" +
                ::testing::UnitTest::GetInstance()->current_test_info()->name());
        fs::remove_all(dir_);
        fs::copy(PNP_MW_REPORT_DATA, dir_, fs::copy_options::recursive);
    }
    void TearDown() override {
        if (!HasFailure()) fs::remove_all(dir_);
    }

    static std::string read(const fs::path& p) {
        std::ifstream in(p, std::ios::binary);
        std::stringstream ss;
        ss << in.rdbuf();
        return ss.str();
    }

    static bool hasGnuplot() { return std::system("command -v gnuplot >/dev/null 2>&1") == 0; }

    fs::path dir_;
};

// Keeps PATH without gnuplot for one test.
struct PathOverride {
    explicit PathOverride(const char* value)
        : old_(std::getenv("PATH") ? std::getenv("PATH") : "") {
        ::setenv("PATH", value, 1);
    }
    ~PathOverride() { ::setenv("PATH", old_.c_str(), 1); }
    std::string old_;
};

TEST_F(ReportTest, WritesTablesFromTheCsvsNextToTheThesisValues) {
    const fs::path report = writeReport(dir_, Options{.plots = false});
    EXPECT_EQ(report, dir_ / "report.md");
    const std::string md = read(report);
    // Header, machine, the exact load descriptions.
    EXPECT_NE(md.find("Duration: 123.4 s (0 h 2 min 3 s)"), std::string::npos) << md;
    EXPECT_NE(md.find("Test CPU 3000"), std::string::npos);
    EXPECT_NE(md.find("`stress-ng --cpu 2 --taskset 0,1 (test)`"), std::string::npos);
    // Mean table: OPC UA idle echo 2 B = mean of 10..18 µs = 14.0, 1024 B = 24.0.
    EXPECT_NE(md.find("| Echo | OPC UA cs | idle | 14.0 | 24.0 |"), std::string::npos) << md;
    // Mean with the 400 µs outlier under CPU load: (20+...+27+400)/9 = 65.3 µs; median 24.0.
    EXPECT_NE(md.find("| Echo | OPC UA cs | cpu | 65.3 | 32.0 |"), std::string::npos) << md;
    EXPECT_NE(md.find("| Echo | OPC UA cs | cpu | 24.0 | 32.0 |"), std::string::npos) << md;
    // ACK: tcp median 9.00 µs (three samples 8, 9, 10).
    EXPECT_NE(md.find("| ACK | TCP | idle | 9.00 | 11.0 |"), std::string::npos) << md;
    // The run without CSV falls back on summary.json's numbers, and says so.
    EXPECT_NE(md.find("| Echo | MQTT qos1 | idle | 66.0 | 69.0 |"), std::string::npos) << md;
    EXPECT_NE(md.find("mqtt/qos1 echo idle: samples/idle/mqtt-qos1-echo.csv not found"),
              std::string::npos)
        << md;
    // Thesis Table 4.3 and 4.2 values.
    EXPECT_NE(md.find("| Echo | OPC UA C/S | idle | 520 | 283 | 288 |"), std::string::npos) << md;
    EXPECT_NE(md.find("| ACK | UDP | idle | 259 | 223 |"), std::string::npos);
    EXPECT_NE(md.find("| MQTT | 5 | 105 | 1006 | 10006 | 17 |"), std::string::npos) << md;
    EXPECT_NE(md.find("| OPC UA C/S | 96 | 196 | 1096 | 10096 | 632 |"), std::string::npos);
    EXPECT_NE(md.find("Gigabit Ethernet"), std::string::npos);
    // Side by side: ours / thesis; sizes we did not measure are "–".
    EXPECT_NE(md.find("| Echo | OPC UA C/S = OPC UA cs | idle | 14.0 / 520 | – / 283 |"),
              std::string::npos)
        << md;
    EXPECT_NE(md.find("| Echo | MQTT = MQTT qos0 | idle | 40.0 / 584 |"), std::string::npos);
    // Our overhead.
    EXPECT_NE(md.find("| OPC UA cs | ok | 81 / 52 | 181 / 152 | 1081 / 1052 | 10081 / 10052 | "
                      "512 |"),
              std::string::npos)
        << md;
    // OPC UA vs raw TCP (14/12 = 1.17, 24/17 = 1.41) and vs MQTT (22 µs < 24 µs at 1024 B).
    EXPECT_NE(md.find("Echo, idle: OPC UA cs median / raw TCP median per payload size: 2 B "
                      "1.17×, 1024 B **1.41×**. Within the target (≤ 1.20×) at 1 of 2 payload "
                      "sizes; above it at 1024 B."),
              std::string::npos)
        << md;
    EXPECT_NE(md.find("OPC UA cs vs MQTT qos0: median below at 1 of 2 payload sizes; not below "
                      "at 1024 B (24.0 vs 22.0 µs)."),
              std::string::npos)
        << md;
    // Skipped adapter, failed run and chain with reasons; msgs/s, CPU, RSS.
    EXPECT_NE(md.find("dds (skipped): pnp-mw-dds not built: fastrtps not found"),
              std::string::npos);
    EXPECT_NE(md.find("mqtt/qos0 echo cpu (failed): broker died (exit 1)"), std::string::npos);
    EXPECT_NE(md.find("| TCP | ok | 500 | 10 × 50 | 5 | 10240 | 10 | 1200 | 1200 |"),
              std::string::npos)
        << md;
    EXPECT_NE(md.find("node 37 did not print READY within 10 s"), std::string::npos);
    EXPECT_NE(md.find("| OPC UA cs | echo | idle | 10 | 70000 (2 B) | 41000 (1024 B) | 50.0 | "
                      "40.0 | – | 4.0 | 2.0 | – |"),
              std::string::npos)
        << md;
    EXPECT_NE(md.find("| MQTT qos0 | echo | idle | 10 | "), std::string::npos);
    EXPECT_NE(md.find("30.5 |"), std::string::npos);  // broker CPU
    // Plots disabled: said so, none written.
    EXPECT_NE(md.find("no plots: disabled"), std::string::npos);
    EXPECT_FALSE(fs::exists(dir_ / "plots" / "compare-echo-idle.png"));
}

TEST_F(ReportTest, MalformedCsvRowsAreSkippedAndNoted) {
    const std::string md = read(writeReport(dir_, Options{.plots = false}));
    EXPECT_NE(md.find("mqtt/qos0 echo idle: 2 row(s) of samples/idle/mqtt-qos0-echo.csv skipped "
                      "(10 used); line 12: payload \"abc\" is not a size; line 13: 5 fields "
                      "instead of 6"),
              std::string::npos)
        << md;
    // The rows that were used still count: MQTT qos0 2 B mean 40.0.
    EXPECT_NE(md.find("| Echo | MQTT qos0 | idle | 40.0 | 22.0 |"), std::string::npos) << md;
}

TEST_F(ReportTest, ACsvWithoutHeaderIsAProblemNotACrash) {
    {
        std::ofstream out(dir_ / "samples/idle/tcp-tcp-echo.csv", std::ios::trunc);
        out << "\x01\x02garbage,,,\n1,2,3\n";
    }
    const std::string md = read(writeReport(dir_, Options{.plots = false}));
    EXPECT_NE(md.find("tcp/tcp echo idle: "), std::string::npos) << md;
    EXPECT_NE(md.find("no driver CSV header"), std::string::npos) << md;
    EXPECT_NE(md.find("no raw TCP run to compare"), std::string::npos) << md;
}

TEST_F(ReportTest, DrawsPngBoxPlotsWithGnuplot) {
    if (!hasGnuplot()) GTEST_SKIP() << "gnuplot not installed";
    const std::string md = read(writeReport(dir_));
    for (const char* name : {"echo-opcua-cs", "echo-tcp-tcp", "echo-mqtt-qos0", "compare-echo-idle",
                             "compare-ack-idle", "resting", "chain"}) {
        const fs::path png = dir_ / "plots" / (std::string(name) + ".png");
        ASSERT_TRUE(fs::exists(png)) << png << "\n" << md;
        const std::string bytes = read(png);
        EXPECT_GT(bytes.size(), 1000u) << png;
        EXPECT_EQ(bytes.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8)) << png;
        EXPECT_NE(md.find(std::string("(plots/") + name + ".png)"), std::string::npos) << md;
    }
    EXPECT_NE(md.find("beyond the whiskers"), std::string::npos);
    EXPECT_FALSE(fs::exists(dir_ / "plots" / "echo-dds-udp.png"));  // skipped adapter: no plot
}

TEST_F(ReportTest, WithoutGnuplotEverythingElseIsWritten) {
    std::string md;
    {
        PathOverride path("/nonexistent");
        md = read(writeReport(dir_));
    }
    EXPECT_NE(md.find("no plots: gnuplot not found"), std::string::npos) << md;
    EXPECT_NE(md.find("| Echo | OPC UA cs | idle | 14.0 | 24.0 |"), std::string::npos);
}

TEST_F(ReportTest, MissingSummaryIsAnErrorNamingIt) {
    fs::remove(dir_ / "summary.json");
    try {
        writeReport(dir_);
        FAIL() << "no exception";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("summary.json"), std::string::npos) << e.what();
    }
}

TEST_F(ReportTest, MalformedSummaryIsAnErrorNamingIt) {
    {
        std::ofstream out(dir_ / "summary.json", std::ios::trunc);
        out << "{\"runs\": [ {\"adapter\": ";
    }
    EXPECT_THROW(writeReport(dir_), std::runtime_error);
    {
        std::ofstream out(dir_ / "summary.json", std::ios::trunc);
        out << "{\"runs\": 5}";
    }
    try {
        writeReport(dir_);
        FAIL() << "no exception";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("\"runs\" is not an array"), std::string::npos)
            << e.what();
    }
}

TEST_F(ReportTest, CsvPathOutsideTheResultsDirectoryIsNotRead) {
    std::string s = read(dir_ / "summary.json");
    const std::string from = "\"samples/idle/tcp-tcp-echo.csv\"";
    s.replace(s.find(from), from.size(), "\"../../etc/passwd\"");
    {
        std::ofstream out(dir_ / "summary.json", std::ios::trunc);
        out << s;
    }
    const std::string md = read(writeReport(dir_, Options{.plots = false}));
    EXPECT_NE(md.find("is not inside the results directory"), std::string::npos) << md;
}

}  // namespace
