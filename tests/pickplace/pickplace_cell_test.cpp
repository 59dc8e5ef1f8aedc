// PickAndPlace in the simulated thesis cell, everything as real processes on loopback (each
// stopped by its PID): `pnp lds`, `pnp sim`, the robot, both tools' adapters, the Kelvin ADC
// board, the tool changer and `pnp component pick-place` with a test knowledge base (Turtle
// written here). One cell for the whole suite (a cell takes ~10 s to start on 2 cores); each
// test sets up the tool it needs. The world's ground truth says where the cube really is.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
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

const std::string kPnp = PNP_BINARY;
// The docks of the thesis cell (models/cells/thesis.yaml) as ThreeDFrames x,y,z,a,b,c.
const std::string kDock1 = "-0.125,0.513,-0.036,0,3.14159265358979,0";  // vacuum gripper
const std::string kDock2 = "0.125,0.513,-0.036,0,3.14159265358979,0";   // parallel gripper

std::string tmpPath(const std::string& name) { return pnp::testing::tmpPath("pickplace", name); }

int run(const std::string& command, std::string& out) {
    return pnp::testing::runShell(command, out);
}

struct Cell {
    ChildProcess lds_, sim_, ur_, robotiq_, ecbpi_, adc_, changer_, pickplace_;
    std::string lds, world, robot, changer, pickplace, parallelUri, vacuumUri, kbFile;
    std::string error;  // set up failed: why

    static int mdnsPort() { return 20000 + static_cast<int>((::getpid() + 7) % 20000); }

    bool start() {
        std::string line;
        kbFile = tmpPath("objects.ttl");
        {
            std::ofstream ttl(kbFile);
            ttl << "@prefix pnp: <urn:pnp:kb#> .\n"
                   "@prefix cell: <urn:pnp:kb:cell#> .\n"
                   "@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n"
                   "pnp:Cube rdfs:subClassOf pnp:Object .\n"
                   "cell:cube-green a pnp:Cube ; pnp:id \"cube-green\" ;\n"
                   "    pnp:pose \"0.05,0.10,0.02,0,0,0\" ; pnp:size \"0.04,0.04,0.04\" .\n"
                   "# Nothing is there in the world: a grasp on empty air.\n"
                   "cell:ghost a pnp:Cube ; pnp:id \"ghost\" ;\n"
                   "    pnp:pose \"0.15,-0.05,0.02,0,0,0\" ; pnp:size \"0.04,0.04,0.04\" .\n"
                   "cell:box-wide a pnp:Object ; pnp:id \"box-wide\" ;\n"
                   "    pnp:pose \"0.15,0.05,0.02,0,0,0\" ; pnp:size \"0.12,0.10,0.04\" .\n";
        }
        if (!lds_.start(
                {kPnp, "lds", "--port", "0", "--host", "127.0.0.1", "--public-host", "127.0.0.1"},
                tmpPath("lds.log"), error))
            return false;
        if (!lds_.waitForPrefix("listening on ", 20s, error, &line)) return false;
        lds = line.substr(13);
        const std::vector<std::string> net = {
            "--host", "127.0.0.1", "--public-host", "127.0.0.1",
            "--lds",  lds,         "--mdns-port",   std::to_string(mdnsPort())};
        auto with = [&](std::vector<std::string> argv) {
            argv.insert(argv.end(), net.begin(), net.end());
            return argv;
        };
        if (!sim_.start(with({kPnp, "sim", "--ephemeral-ports", "--port", "0"}), tmpPath("sim.log"),
                        error))
            return false;
        if (!sim_.waitForPrefix("{", 20s, error, &line)) return false;
        const auto info = nlohmann::json::parse(line);
        world = info.at("world");
        auto address = [&](const std::string& device) {
            for (const auto& d : info.at("devices"))
                if (d.at("device") == device) return d.at("address").get<std::string>();
            return std::string();
        };
        if (!ur_.start(with({kPnp, "device", "ur", "--controller", address("ur-controller"),
                             "--port", "0", "--world-to-base", "-0.3,0,0,0,0,0"}),
                       tmpPath("ur.log"), error))
            return false;
        parallelUri = "urn:pnp:test:pp-robotiq-" + std::to_string(::getpid());
        vacuumUri = "urn:pnp:test:pp-ecbpi-" + std::to_string(::getpid());
        if (!robotiq_.start(with({kPnp, "device", "robotiq", "--serial", address("robotiq-2f85"),
                                  "--ua-port", "0", "--application-uri", parallelUri}),
                            tmpPath("robotiq.log"), error))
            return false;
        if (!ecbpi_.start(with({kPnp, "device", "ecbpi", "--iolink", address("schmalz-ecbpi"),
                                "--port", "1", "--ua-port", "0", "--application-uri", vacuumUri}),
                          tmpPath("ecbpi.log"), error))
            return false;
        if (!adc_.start(with({kPnp, "device", "kelvin-adc", "--adc", address("kelvin-adc-input"),
                              "--port", "0"}),
                        tmpPath("adc.log"), error))
            return false;
        if (!ur_.waitForPrefix("listening on ", 30s, error, &line)) return false;
        robot = line.substr(13);
        if (!adc_.waitForPrefix("listening on ", 30s, error, &line)) return false;
        const std::string adc = line.substr(13);
        if (!changer_.start(with({kPnp, "component", "toolchanger", "--robot", robot, "--adc", adc,
                                  "--port", "0", "--no-mdns"}),
                            tmpPath("changer.log"), error))
            return false;
        // --allow-none: node-opcua's client below uses SecurityPolicy None (the secured
        // node-opcua interop: tests/cli/secure_interop_test.cpp).
        if (!pickplace_.start(with({kPnp, "component", "pick-place", "--kb-file", kbFile, "--port",
                                    "0", "--no-mdns", "--allow-none"}),
                              tmpPath("pickplace.log"), error))
            return false;
        if (!changer_.waitForPrefix("listening on ", 30s, error, &line)) return false;
        changer = line.substr(13);
        if (!pickplace_.waitForPrefix("listening on ", 30s, error, &line)) return false;
        pickplace = line.substr(13);
        return true;
    }

    void stop() {
        for (ChildProcess* p :
             {&pickplace_, &changer_, &adc_, &ecbpi_, &robotiq_, &ur_, &sim_, &lds_})
            p->stop();
        std::remove(kbFile.c_str());
    }

    std::string diagnostics() {
        return "\nsim:\n" + sim_.logTail() + "\nur:\n" + ur_.logTail() + "\nchanger:\n" +
               changer_.logTail() + "\npick-place:\n" + pickplace_.logTail() + "\nrobotiq:\n" +
               robotiq_.logTail() + "\necbpi:\n" + ecbpi_.logTail();
    }
};

struct Eigen3 {
    double x = 0, y = 0, z = 0;
};

Cell* cell = nullptr;

class PickPlaceCell : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        cell = new Cell;
        if (!cell->start()) {
            std::cerr << "cell did not start: " << cell->error << cell->diagnostics() << "\n";
            cell->stop();
            delete cell;
            cell = nullptr;
        }
    }
    static void TearDownTestSuite() {
        if (cell != nullptr) cell->stop();
        delete cell;
        cell = nullptr;
    }
    void SetUp() override { ASSERT_NE(cell, nullptr) << "the cell did not start"; }

    int changeTool(const std::string& dock, const std::string& uri, std::string& out) {
        return run("timeout -k 5 120 " + kPnp + " skill run " + cell->changer +
                       " --skill ChangeTool --json --timeout 90000 ToolPosition=" + dock +
                       " ToolAppUri=" + uri + " 2>&1",
                   out);
    }
    int pickAndPlace(const std::string& object, const std::string& place, std::string& out,
                     int timeoutMs = 90000) {
        return run("timeout -k 5 120 " + kPnp + " skill run " + cell->pickplace +
                       " --skill PickAndPlace --json --timeout " + std::to_string(timeoutMs) +
                       " ObjectId=" + object + " PlacePosition=" + place + " 2>&1",
                   out);
    }
    nlohmann::json value(const std::string& node) {
        std::string r;
        run("timeout -k 5 30 " + kPnp + " ua read " + cell->world +
                " 'nsu=urn:pnp:sim:world;s=" + node + "' --json 2>&1",
            r);
        const auto at = r.find('{');
        if (at == std::string::npos) return {};
        try {
            return nlohmann::json::parse(r.substr(at)).at("results").at(0).at("value");
        } catch (const std::exception&) {
            return {};
        }
    }
    Eigen3 position(const std::string& node) {
        auto v = value(node);
        if (v.contains("Body")) v = v.at("Body");  // the ThreeDFrame structure as JSON
        if (!v.contains("CartesianCoordinates")) return {NAN, NAN, NAN};
        const auto c = v.at("CartesianCoordinates");
        return {c.at("X").get<double>(), c.at("Y").get<double>(), c.at("Z").get<double>()};
    }
    // Joints still within 1e-5 rad over 0.3 s, within 3 s.
    bool robotAtRest() {
        auto still = [](const nlohmann::json& a, const nlohmann::json& b) {
            if (a.size() != 6 || b.size() != 6) return false;
            for (std::size_t j = 0; j < 6; ++j)
                if (std::abs(a[j].get<double>() - b[j].get<double>()) > 1e-5) return false;
            return true;
        };
        const auto until = std::chrono::steady_clock::now() + 3s;
        nlohmann::json a = value("Robots.ur5.Joints");
        while (std::chrono::steady_clock::now() < until) {
            std::this_thread::sleep_for(300ms);
            nlohmann::json b = value("Robots.ur5.Joints");
            if (still(a, b)) return true;
            a = b;
        }
        return false;
    }
};

TEST_F(PickPlaceCell, VacuumPickAndPlaceSetsTheCubeDownWithinAMillimetreAndUpdatesTheKb) {
    std::string out;
    ASSERT_EQ(changeTool(kDock1, cell->vacuumUri, out), 0) << out << cell->diagnostics();
    out.clear();
    ASSERT_EQ(pickAndPlace("cube-green", "-0.05,-0.10,0,0,0,0", out), 0)
        << out << cell->diagnostics();
    EXPECT_NE(out.find("Completed"), std::string::npos) << out;
    for (const char* step :
         {"MovePickApproachBefore", "MovePick", "Grasp", "MovePickApproachAfter",
          "MovePlaceApproachBefore", "MovePlace", "Release", "MovePlaceApproachAfter"})
        EXPECT_NE(out.find(step), std::string::npos) << step << " missing in " << out;
    EXPECT_NE(out.find("CompositionOverheadMs"), std::string::npos) << out;
    std::cout << "PickAndPlace: " << out << std::endl;
    const Eigen3 c = position("Objects.cube-green.Pose");
    EXPECT_NEAR(c.x, -0.05, 1e-3);
    EXPECT_NEAR(c.y, -0.10, 1e-3);
    EXPECT_NEAR(c.z, 0.02, 1e-3);
    EXPECT_EQ(value("Objects.cube-green.Holder"), "table");

    // The knowledge base has the new pose: picking the cube up again finds it there.
    out.clear();
    ASSERT_EQ(pickAndPlace("cube-green", "0.05,0.10,0,0,0,0", out), 0)
        << out << cell->diagnostics();
    const Eigen3 back = position("Objects.cube-green.Pose");
    EXPECT_NEAR(back.x, 0.05, 1e-3);
    EXPECT_NEAR(back.y, 0.10, 1e-3);
    EXPECT_NEAR(back.z, 0.02, 1e-3);
}

TEST_F(PickPlaceCell, AGraspOnEmptyAirFailsNamingTheGraspAndLeavesTheRobotAtTheApproach) {
    std::string out;
    ASSERT_EQ(changeTool(kDock1, cell->vacuumUri, out), 0) << out << cell->diagnostics();
    out.clear();
    // The knowledge base says "ghost" stands at (0.15, -0.05): the world has nothing there.
    EXPECT_EQ(pickAndPlace("ghost", "-0.05,-0.10,0,0,0,0", out), 3) << out;
    EXPECT_NE(out.find("Grasp on "), std::string::npos) << out;
    EXPECT_NE(out.find(" failed: "), std::string::npos) << out;
    EXPECT_NE(out.find("back at the approach pose"), std::string::npos) << out;
    // The grip point (the world's TCP: the vacuum cup) is 5 cm above the ghost's top face.
    const Eigen3 tcp = position("Robots.ur5.TcpPose");
    EXPECT_NEAR(tcp.x, 0.15, 2e-3);
    EXPECT_NEAR(tcp.y, -0.05, 2e-3);
    EXPECT_NEAR(tcp.z, 0.09, 2e-3);
}

TEST_F(PickPlaceCell, AnObjectWiderThanTheFingersIsRefusedBeforeAnyMotion) {
    std::string out;
    ASSERT_EQ(changeTool(kDock2, cell->parallelUri, out), 0) << out << cell->diagnostics();
    const nlohmann::json before = value("Robots.ur5.Joints");
    out.clear();
    EXPECT_EQ(pickAndPlace("box-wide", "-0.05,-0.10,0,0,0,0", out), 3) << out;
    EXPECT_NE(out.find("refused before any motion"), std::string::npos) << out;
    EXPECT_NE(out.find("box-wide is 0.100 m wide"), std::string::npos) << out;
    EXPECT_NE(out.find("0.085 m"), std::string::npos) << out;
    const nlohmann::json after = value("Robots.ur5.Joints");
    ASSERT_EQ(before.size(), 6u);
    ASSERT_EQ(after.size(), 6u);
    for (std::size_t j = 0; j < 6; ++j)
        EXPECT_NEAR(before[j].get<double>(), after[j].get<double>(), 1e-6) << "joint " << j;
}

TEST_F(PickPlaceCell, HaltMidMoveHaltsTheRobotsMoveAndTheNextRunCompletes) {
    std::string out;
    ASSERT_EQ(changeTool(kDock2, cell->parallelUri, out), 0) << out << cell->diagnostics();
    out.clear();
    // The run's deadline halts PickAndPlace 1.2 s in: the robot is on its way to the cube.
    EXPECT_EQ(pickAndPlace("cube-green", "-0.05,-0.10,0,0,0,0", out, 1200), 3) << out;
    EXPECT_TRUE(robotAtRest()) << "the robot still moves 3 s after the halt";
    const std::string log = cell->pickplace_.logTail();
    EXPECT_NE(log.find("halted during MovePickApproachBefore (CartesianLinearMove@"),
              std::string::npos)
        << log;
    // The halted move skill is reset by the next run, which completes.
    out.clear();
    ASSERT_EQ(pickAndPlace("cube-green", "-0.05,-0.10,0,0,0,0", out), 0)
        << out << cell->diagnostics();
    const Eigen3 c = position("Objects.cube-green.Pose");
    EXPECT_NEAR(c.x, -0.05, 1e-3);
    EXPECT_NEAR(c.y, -0.10, 1e-3);
    EXPECT_NEAR(c.z, 0.02, 1e-3);
}

}  // namespace

namespace {

// node-opcua as an independent client (tests/interop/node_pickplace_client.js): finds
// PickAndPlace by browsing, writes its parameters, calls Start and reads until it completed —
// standard services only. The tool attached by the tests before stays on. Skipped (not
// failed) when `node` or node-opcua is missing.
TEST_F(PickPlaceCell, NodeOpcuaClientRunsPickAndPlaceWithStandardServices) {
    const std::string dir = PNP_SOURCE_DIR;
    if (std::system("command -v node >/dev/null 2>&1") != 0) GTEST_SKIP() << "`node` missing";
    if (::access((dir + "/node_modules/node-opcua").c_str(), R_OK) != 0)
        GTEST_SKIP() << "node_modules/node-opcua missing (npm ci)";
    std::string out;
    ASSERT_EQ(changeTool(kDock2, cell->parallelUri, out), 0) << out << cell->diagnostics();
    // Wherever the tests before left the cube: the knowledge base knows.
    out.clear();
    const std::string log = tmpPath("node.stderr");
    const int rc =
        run("timeout -k 5 150 node '" + dir + "/tests/interop/node_pickplace_client.js' '" +
                cell->pickplace + "' cube-green 0.05,0.10,0,0,0,0 2>'" + log + "'",
            out);
    EXPECT_EQ(rc, 0) << out << "\nnode stderr in " << log << cell->diagnostics();
    EXPECT_NE(out.find(" 0 failed"), std::string::npos) << out;
    std::cout << out;
    const Eigen3 c = position("Objects.cube-green.Pose");
    EXPECT_NEAR(c.x, 0.05, 1e-3);
    EXPECT_NEAR(c.y, 0.10, 1e-3);
    EXPECT_NEAR(c.z, 0.02, 1e-3);
}

}  // namespace
