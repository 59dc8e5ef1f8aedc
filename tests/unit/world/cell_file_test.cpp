#include "world/cell_file.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <random>
#include <string>

#include "kinematics/robot_model.hpp"

namespace pnp::world {
namespace {

constexpr double kPi = std::numbers::pi;
const std::filesystem::path kThesisCell =
    std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml";

// A minimal valid cell; tests append sections to it. Lines 1-2.
const std::string kHead = "pnp-cell: 1\nname: t\n";

// A parallel gripper `name` with changer id `id`, as a `tools:` item (7 lines).
std::string tool(const std::string& name, int id) {
    return "  - name: " + name +
           "\n"
           "    kind: parallel-gripper\n"
           "    device: robotiq-2f85\n"
           "    changer-id: " +
           std::to_string(id) +
           "\n"
           "    mass: 0.9\n"
           "    tcp: {xyz: [0, 0, 0.2]}\n"
           "    stroke: 0.085\n";
}

// A UR5 `name` as a `robots:` item (5 lines), with `extra` lines appended.
std::string robot(const std::string& name, const std::string& extra = "") {
    return "  - name: " + name +
           "\n"
           "    model: ur5\n"
           "    base: {xyz: [0, 0, 0]}\n"
           "    home: [0, -1.57, 1.57, -1.57, -1.57, 0]\n"
           "    controller: {protocol: rtde, port: 0}\n" +
           extra;
}

// Asserts that `text` fails with `code` at `line`, the message being
// "t.yaml:LINE: ..." and containing `what`.
void expectError(const std::string& text, ErrorCode code, int line, const std::string& what) {
    SCOPED_TRACE(text);
    const Result<CellDescription> r = parseCellDescription(text, "t.yaml");
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, code) << r.error().message;
    EXPECT_EQ(r.error().line, line) << r.error().message;
    const std::string prefix = "t.yaml:" + std::to_string(line) + ": ";
    EXPECT_EQ(r.error().message.rfind(prefix, 0), 0u) << r.error().message;
    EXPECT_NE(r.error().message.find(what), std::string::npos) << r.error().message;
}

double maxDifference(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
    return (a.matrix() - b.matrix()).cwiseAbs().maxCoeff();
}

// --- the default file -----------------------------------------------------------------------

TEST(ThesisCell, LoadsWithTheThesisContent) {
    const Result<CellDescription> r = loadCellFile(kThesisCell);
    ASSERT_TRUE(r.ok()) << r.error().message;
    const CellDescription& cell = *r;
    EXPECT_EQ(cell.version, 1);
    EXPECT_EQ(cell.name, "thesis");
    ASSERT_EQ(cell.robots.size(), 1u);
    ASSERT_EQ(cell.tables.size(), 1u);
    ASSERT_EQ(cell.tools.size(), 3u);  // two in docks, the WSG 50 on the shelf
    ASSERT_EQ(cell.docks.size(), 2u);
    ASSERT_EQ(cell.objects.size(), 1u);

    const RobotDescription& ur5 = cell.robots[0];
    EXPECT_EQ(ur5.modelName, "ur5");
    EXPECT_EQ(ur5.model.name, kinematics::ur5().name);
    EXPECT_DOUBLE_EQ(ur5.model.dh[1].a, -0.425);
    Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
    base.translation() = Eigen::Vector3d(-0.3, 0, 0);
    EXPECT_LT(maxDifference(ur5.base, base), 1e-15);
    EXPECT_EQ(ur5.controller.protocol, "rtde");
    EXPECT_EQ(ur5.controller.port, 30004);
    EXPECT_FALSE(ur5.tool.has_value());
    EXPECT_NEAR(ur5.home[1], -kPi / 2, 1e-12);

    // Docks: (∓0.125, 0.513, -0.036), rotated π about y: x -> -x, z -> -z.
    Eigen::Isometry3d rotatedPiAboutY = Eigen::Isometry3d::Identity();
    rotatedPiAboutY.linear() = Eigen::Vector3d(-1, 1, -1).asDiagonal();
    const DockDescription* dock1 = cell.findDock("dock-1");
    const DockDescription* dock2 = cell.findDock("dock-2");
    ASSERT_TRUE(dock1 && dock2);
    Eigen::Isometry3d expected = rotatedPiAboutY;
    expected.translation() = Eigen::Vector3d(-0.125, 0.513, -0.036);
    EXPECT_LT(maxDifference(dock1->pose, expected), 1e-12);
    expected.translation() = Eigen::Vector3d(0.125, 0.513, -0.036);
    EXPECT_LT(maxDifference(dock2->pose, expected), 1e-12);

    ASSERT_TRUE(dock1->tool && dock2->tool);
    const ToolDescription* vacuum = cell.findTool(*dock1->tool);
    const ToolDescription* parallel = cell.findTool(*dock2->tool);
    ASSERT_TRUE(vacuum && parallel);
    EXPECT_EQ(vacuum->kind, ToolKind::kVacuumGripper);
    EXPECT_EQ(vacuum->device, "schmalz-ecbpi");
    EXPECT_EQ(vacuum->changerId, 2);
    EXPECT_NEAR(vacuum->tcp.translation().z(), 0.1868, 1e-12);
    EXPECT_GT(vacuum->cupDiameter, 0.0);
    EXPECT_EQ(parallel->kind, ToolKind::kParallelGripper);
    EXPECT_EQ(parallel->device, "robotiq-2f85");
    EXPECT_EQ(parallel->changerId, 1);
    EXPECT_NEAR(parallel->tcp.translation().z(), 0.2028, 1e-12);
    EXPECT_DOUBLE_EQ(parallel->stroke, 0.085);

    const ObjectDescription* cube = cell.findObject("cube-green");
    ASSERT_NE(cube, nullptr);
    EXPECT_EQ(cube->shape, Shape::kBox);
    EXPECT_EQ(cube->color, "green");
    EXPECT_EQ(cube->on, std::optional<std::string>("table"));
    EXPECT_LT(cube->size.maxCoeff(), parallel->stroke);  // graspable by the 2F-85
    EXPECT_LT((cube->pose.translation() - Eigen::Vector3d(0.05, 0.10, 0.02)).norm(), 1e-12);
    // It stands on the table's top face, and both place positions are on the table.
    const TableDescription* table = cell.findTable("table");
    ASSERT_NE(table, nullptr);
    EXPECT_NEAR(cube->pose.translation().z() - cube->size.z() / 2, table->pose.translation().z(),
                1e-12);
    for (const Eigen::Vector3d& place :
         {Eigen::Vector3d(-0.05, -0.10, 0), Eigen::Vector3d(0.05, 0.10, 0)}) {
        const Eigen::Vector3d local = table->pose.inverse() * place;
        EXPECT_LE(std::abs(local.x()), table->size.x() / 2);
        EXPECT_LE(std::abs(local.y()), table->size.y() / 2);
        EXPECT_NEAR(local.z(), 0.0, 1e-12);
    }
    // The docks are off the table (their tools hang below its top face).
    EXPECT_GT(dock1->pose.translation().y(), table->size.y() / 2);
    EXPECT_GT(cube->line, 0);
}

TEST(ThesisCell, LoadingIsDeterministic) {
    const Result<CellDescription> a = loadCellFile(kThesisCell);
    const Result<CellDescription> b = loadCellFile(kThesisCell);
    ASSERT_TRUE(a.ok() && b.ok());
    ASSERT_EQ(a->docks.size(), b->docks.size());
    for (std::size_t i = 0; i < a->docks.size(); ++i) {
        EXPECT_EQ(a->docks[i].name, b->docks[i].name);
        EXPECT_EQ(a->docks[i].pose.matrix(), b->docks[i].pose.matrix());
        EXPECT_EQ(a->docks[i].line, b->docks[i].line);
    }
    EXPECT_EQ(a->objects[0].pose.matrix(), b->objects[0].pose.matrix());
    // Errors too.
    const std::string bad = kHead + "tools:\n" + tool("g", 11);
    EXPECT_EQ(parseCellDescription(bad, "x").error().message,
              parseCellDescription(bad, "x").error().message);
}

// --- poses ----------------------------------------------------------------------------------

TEST(Pose, RpyIsUrdfFixedAxesXyz) {
    // Pitch π/2 about y: x -> -z.
    Eigen::Isometry3d p = poseFromXyzRpy(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0, kPi / 2, 0));
    EXPECT_LT((p.linear() * Eigen::Vector3d::UnitX() - Eigen::Vector3d(0, 0, -1)).norm(), 1e-12);
    EXPECT_LT((p.translation() - Eigen::Vector3d(1, 2, 3)).norm(), 1e-15);
    // Roll then yaw about the fixed axes: R = Rz(π/2) Rx(π/2): x -> y, y -> z, z -> x.
    p = poseFromXyzRpy(Eigen::Vector3d::Zero(), Eigen::Vector3d(kPi / 2, 0, kPi / 2));
    EXPECT_LT((p.linear() * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), 1e-12);
    EXPECT_LT((p.linear() * Eigen::Vector3d::UnitY() - Eigen::Vector3d::UnitZ()).norm(), 1e-12);
    EXPECT_LT((p.linear() * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitX()).norm(), 1e-12);
}

TEST(Pose, FileRpyGivesTheSameIsometry) {
    const std::string text = kHead +
                             "docks:\n"
                             "  - name: d\n"
                             "    pose: {xyz: [0.1, -0.2, 0.3], rpy: [0.3, -0.4, 2.5]}\n"
                             "  - name: e\n"
                             "    pose: {xyz: [1, 2, 3]}\n";
    const Result<CellDescription> r = parseCellDescription(text, "t.yaml");
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_LT(maxDifference(r->docks[0].pose, poseFromXyzRpy(Eigen::Vector3d(0.1, -0.2, 0.3),
                                                             Eigen::Vector3d(0.3, -0.4, 2.5))),
              1e-15);
    EXPECT_TRUE(r->docks[1].pose.linear().isIdentity(0.0));  // rpy defaults to 0
    EXPECT_FALSE(r->docks[0].tool.has_value());
    EXPECT_EQ(r->docks[0].line, 4);
    EXPECT_EQ(r->docks[1].line, 6);
}

TEST(Pose, RpyRoundTrips) {
    std::mt19937 rng(42);  // fixed seed: deterministic
    std::uniform_real_distribution<double> angle(-kPi, kPi), pitch(-kPi / 2 + 1e-3, kPi / 2 - 1e-3);
    for (int i = 0; i < 1000; ++i) {
        const Eigen::Vector3d rpy(angle(rng), pitch(rng), angle(rng));
        const Eigen::Isometry3d p = poseFromXyzRpy(Eigen::Vector3d::Zero(), rpy);
        EXPECT_LT((rpyFromRotation(p.linear()) - rpy).norm(), 1e-9) << rpy.transpose();
    }
    // Gimbal lock: the angles differ but the rotation is the same.
    for (double sign : {1.0, -1.0}) {
        const Eigen::Isometry3d p =
            poseFromXyzRpy(Eigen::Vector3d::Zero(), Eigen::Vector3d(0.7, sign * kPi / 2, -0.2));
        const Eigen::Isometry3d q =
            poseFromXyzRpy(Eigen::Vector3d::Zero(), rpyFromRotation(p.linear()));
        EXPECT_LT(maxDifference(p, q), 1e-9);
    }
}

// --- accepted variants ----------------------------------------------------------------------

TEST(CellFile, AcceptsOptionalAndNullKeys) {
    const std::string text = kHead + "robots:\n" + robot("r", "    tool: g\n") +  // 3-9
                             "tools:\n" + tool("g", 10) +                         // 10-17
                             "docks:\n"                                           // 18
                             "  - name: d\n"                                      // 19
                             "    pose: {xyz: [0, 0, 0]}\n"                       // 20
                             "    tool: ~\n"                                      // 21
                             "objects:\n"
                             "tables: []\n";
    const Result<CellDescription> r = parseCellDescription(text, "t.yaml");
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_EQ(r->robots[0].tool, std::optional<std::string>("g"));
    EXPECT_EQ(r->robots[0].controller.port, 0);  // ephemeral
    EXPECT_EQ(r->tools[0].changerId, 10);
    EXPECT_FALSE(r->docks[0].tool.has_value());
    EXPECT_TRUE(r->objects.empty());
    EXPECT_TRUE(r->tables.empty());
    EXPECT_EQ(r->robots[0].line, 4);
    EXPECT_EQ(r->tools[0].line, 11);
}

// --- file-level errors ----------------------------------------------------------------------

TEST(CellFileErrors, MissingFile) {
    const Result<CellDescription> r = loadCellFile("/nonexistent/dir/cell.yaml");
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kUnreadable);
    EXPECT_EQ(r.error().message, "/nonexistent/dir/cell.yaml: no such file");
    EXPECT_EQ(r.error().line, 0);
}

TEST(CellFileErrors, Directory) {
    const Result<CellDescription> r = loadCellFile(PNP_MODELS_DIR);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kUnreadable);
    EXPECT_NE(r.error().message.find("not a regular file"), std::string::npos);
}

TEST(CellFileErrors, FileOfTwoMebibytesIsRefused) {
    const std::filesystem::path path = std::filesystem::temp_directory_path() /
                                       ("pnp-world-big-" + std::to_string(::getpid()) + ".yaml");
    {
        std::ofstream out(path, std::ios::binary);
        out << kHead << "# " << std::string(2 * 1024 * 1024, 'x') << "\n";
    }
    const Result<CellDescription> r = loadCellFile(path);
    std::filesystem::remove(path);
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().code, ErrorCode::kTooLarge);
    EXPECT_EQ(r.error().message.rfind(path.string() + ": file is 209", 0), 0u) << r.error().message;

    // The text API has the same bound.
    const Result<CellDescription> t =
        parseCellDescription(kHead + "#" + std::string(kMaxCellFileBytes, 'x'), "t.yaml");
    ASSERT_FALSE(t.ok());
    EXPECT_EQ(t.error().code, ErrorCode::kTooLarge);
}

TEST(CellFileErrors, Syntax) {
    expectError("pnp-cell: 1\nname: t\nrobots: [a, b\n", ErrorCode::kSyntax, 4,
                "YAML syntax error");
    expectError("pnp-cell: 1\nname: t\n  bad: indentation\n", ErrorCode::kSyntax, 3,
                "YAML syntax error");
    expectError("pnp-cell: 1\nname: t\n---\npnp-cell: 1\n", ErrorCode::kSyntax, 4,
                "more than one YAML document");
    expectError("", ErrorCode::kMissingKey, 1, "empty file");
    expectError("# only a comment\n", ErrorCode::kMissingKey, 1, "empty file");
    expectError("\n\n- pnp-cell: 1\n", ErrorCode::kWrongType, 3, "expected a mapping");
    // Deep nesting: yaml-cpp's depth guard refuses it (no stack overflow).
    const std::size_t depth = 400000;
    expectError(kHead + "robots: " + std::string(depth, '[') + std::string(depth, ']') + "\n",
                ErrorCode::kSyntax, 3, "YAML syntax error");
}

TEST(CellFileErrors, Version) {
    expectError("name: t\npnp-cell: 2\n", ErrorCode::kVersion, 2,
                "pnp-cell: unsupported format version '2' (this program reads 1)");
    expectError("pnp-cell: 1.0\nname: t\n", ErrorCode::kVersion, 1, "version '1.0'");
    expectError("pnp-cell: [1]\nname: t\n", ErrorCode::kVersion, 1, "version a list");
    expectError("name: t\n", ErrorCode::kMissingKey, 1, "missing key 'pnp-cell'");
    // A newer version is refused as such, not for its new keys.
    expectError("pnp-cell: 2\nname: t\nconveyors: []\n", ErrorCode::kVersion, 1, "version '2'");
}

// --- keys -----------------------------------------------------------------------------------

TEST(CellFileErrors, UnknownKeys) {
    expectError(kHead + "robot:\n", ErrorCode::kUnknownKey, 3,
                "unknown key 'robot' (allowed: pnp-cell, name, robots, tables, tools, docks, "
                "objects)");
    expectError(kHead + "robots:\n" + robot("r", "    hom: [0, 0, 0, 0, 0, 0]\n"),
                ErrorCode::kUnknownKey, 9, "robots[0]: unknown key 'hom'");
    expectError(kHead + "docks:\n  - name: d\n    pose: {xyz: [0, 0, 0], rpz: [0, 0, 0]}\n",
                ErrorCode::kUnknownKey, 5, "docks[0].pose: unknown key 'rpz' (allowed: xyz, rpy)");
    expectError(
        kHead + "robots:\n" + robot("r") + robot("s").replace(robot("s").find("port"), 4, "prot"),
        ErrorCode::kUnknownKey, 13, "robots[1].controller: unknown key 'prot'");
    // A vacuum gripper has no stroke.
    expectError(kHead +
                    "tools:\n"
                    "  - name: v\n"
                    "    kind: vacuum-gripper\n"
                    "    device: schmalz-ecbpi\n"
                    "    changer-id: 2\n"
                    "    mass: 0.3\n"
                    "    tcp: {xyz: [0, 0, 0.18]}\n"
                    "    stroke: 0.03\n",
                ErrorCode::kUnknownKey, 10, "tools[0]: unknown key 'stroke'");
    expectError(kHead + "name: u\n", ErrorCode::kUnknownKey, 3,
                "key 'name' repeated (first at line 2)");
}

TEST(CellFileErrors, MissingKeys) {
    expectError("pnp-cell: 1\n", ErrorCode::kMissingKey, 1, "missing key 'name'");
    // The line of the mapping that lacks it.
    std::string noHome = robot("r");
    noHome.erase(noHome.find("    home"), noHome.find("    controller") - noHome.find("    home"));
    expectError(kHead + "robots:\n" + noHome, ErrorCode::kMissingKey, 4,
                "robots[0]: missing key 'home'");
    expectError(kHead + "docks:\n  - name: d\n    pose: {rpy: [0, 0, 0]}\n", ErrorCode::kMissingKey,
                5, "docks[0].pose: missing key 'xyz'");
    expectError(kHead + "tools:\n" + tool("g", 1).substr(0, tool("g", 1).find("    stroke")),
                ErrorCode::kMissingKey, 4, "tools[0]: missing key 'stroke'");
    expectError(kHead + "tables:\n  - name: tab\n    size: [1, 1, 1]\n", ErrorCode::kMissingKey, 4,
                "tables[0]: missing key 'pose'");
}

// --- values ---------------------------------------------------------------------------------

TEST(CellFileErrors, WrongTypes) {
    expectError("pnp-cell: 1\nname: [a]\n", ErrorCode::kWrongType, 2,
                "name: expected a string, got a list");
    expectError(kHead + "robots: {}\n", ErrorCode::kWrongType, 3, "robots: expected a list");
    expectError(kHead + "robots:\n  - r\n", ErrorCode::kWrongType, 4,
                "robots[0]: expected a mapping, got 'r'");
    expectError(kHead + "docks:\n  - name: d\n    pose: {xyz: [0, 0]}\n", ErrorCode::kWrongType, 5,
                "docks[0].pose.xyz: expected 3 values, got 2");
    expectError(kHead + "docks:\n  - name: d\n    pose:\n      xyz: [0, zero, 0]\n",
                ErrorCode::kWrongType, 6, "docks[0].pose.xyz[1]: expected a number, got 'zero'");
    expectError(kHead + "docks:\n  - name: d\n    pose:\n", ErrorCode::kWrongType, 5,
                "docks[0].pose: expected a mapping, got nothing");
    std::string text = kHead + "tools:\n" + tool("g", 1);
    expectError(text.replace(text.find("0.9"), 3, "heavy"), ErrorCode::kWrongType, 8,
                "tools[0].mass: expected a number, got 'heavy'");
    text = kHead + "tools:\n" + tool("g", 1);
    expectError(text.replace(text.find("changer-id: 1"), 13, "changer-id: 1.5"),
                ErrorCode::kWrongType, 7, "tools[0].changer-id: expected an integer, got '1.5'");
    expectError(kHead + "robots:\n" + robot("r").replace(robot("r").rfind(", 0]"), 4, "]"),
                ErrorCode::kWrongType, 7, "robots[0].home: expected 6 values, got 5");
}

TEST(CellFileErrors, OutOfRangeNumbers) {
    const std::string tools = kHead + "tools:\n" + tool("g", 1);
    auto with = [&](const std::string& from, const std::string& to) {
        std::string t = tools;
        return t.replace(t.find(from), from.size(), to);
    };
    expectError(with("mass: 0.9", "mass: .nan"), ErrorCode::kOutOfRange, 8,
                "tools[0].mass: must be a finite number");
    expectError(with("mass: 0.9", "mass: 0"), ErrorCode::kOutOfRange, 8,
                "tools[0].mass: 0 is out of range (0, 50]");
    expectError(with("mass: 0.9", "mass: -1"), ErrorCode::kOutOfRange, 8, "out of range");
    expectError(with("changer-id: 1", "changer-id: 11"), ErrorCode::kOutOfRange, 7,
                "tools[0].changer-id: 11 is out of range [1, 10]");
    expectError(with("changer-id: 1", "changer-id: 0"), ErrorCode::kOutOfRange, 7,
                "out of range [1, 10]");
    expectError(with("[0, 0, 0.2]", "[0, .inf, 0.2]"), ErrorCode::kOutOfRange, 9,
                "tools[0].tcp.xyz[1]: must be a finite number");
    expectError(with("stroke: 0.085", "stroke: 0"), ErrorCode::kOutOfRange, 10,
                "tools[0].stroke: 0 is out of range (0, 1]");
    expectError(kHead + "tables:\n  - name: tab\n    pose: {xyz: [0, 0, 0]}\n    size: [1, 0, 1]\n",
                ErrorCode::kOutOfRange, 6, "tables[0].size[1]: 0 is out of range (0, 100]");
    expectError(kHead + "docks:\n  - name: d\n    pose: {xyz: [0, 0, 1e6]}\n",
                ErrorCode::kOutOfRange, 5, "docks[0].pose.xyz[2]: 1e+06 is out of range");

    const std::string robots = kHead + "robots:\n" + robot("r");
    auto robotWith = [&](const std::string& from, const std::string& to) {
        std::string t = robots;
        return t.replace(t.find(from), from.size(), to);
    };
    expectError(robotWith("-1.57, 1.57", "-1.57, 7.0"), ErrorCode::kOutOfRange, 7,
                "robots[0].home[2]: 7 rad is outside the joint limits of ur5 [-6.28319, 6.28319]");
    expectError(robotWith("port: 0", "port: 65536"), ErrorCode::kOutOfRange, 8,
                "robots[0].controller.port: 65536 is out of range [0, 65535]");
    expectError(robotWith("port: 0", "port: -1"), ErrorCode::kOutOfRange, 8, "out of range");
    expectError(robotWith("model: ur5", "model: ur7"), ErrorCode::kOutOfRange, 5,
                "robots[0].model: unknown robot model 'ur7' (known: ur3, ur5, ur10)");
    expectError(robotWith("protocol: rtde", "protocol: modbus"), ErrorCode::kOutOfRange, 8,
                "unknown protocol 'modbus'");
}

TEST(CellFileErrors, OutOfRangeWords) {
    std::string t = kHead + "tools:\n" + tool("g", 1);
    expectError(t.replace(t.find("parallel-gripper"), 16, "magnetic-gripper"),
                ErrorCode::kOutOfRange, 5, "tools[0].kind: unknown tool kind 'magnetic-gripper'");
    const std::string object = kHead +
                               "objects:\n"
                               "  - name: cube\n"
                               "    shape: box\n"
                               "    size: [0.04, 0.04, 0.04]\n"
                               "    mass: 0.05\n"
                               "    color: '#00ff00'\n"
                               "    pose: {xyz: [0, 0, 0.02]}\n";
    EXPECT_TRUE(parseCellDescription(object, "t.yaml").ok());
    t = object;
    expectError(t.replace(t.find("#00ff00"), 7, "#00ff0g"), ErrorCode::kOutOfRange, 8,
                "objects[0].color: '#00ff0g' is not a colour");
    t = object;
    expectError(t.replace(t.find("box"), 3, "sphere"), ErrorCode::kOutOfRange, 5,
                "objects[0].shape: unknown shape 'sphere' (known: box)");
    expectError(kHead + "docks:\n  - name: 'a b'\n    pose: {xyz: [0, 0, 0]}\n",
                ErrorCode::kOutOfRange, 4, "docks[0].name: 'a b' is not a valid name");
    // Text quoted from the file is shortened in messages.
    std::string longModel = kHead + "robots:\n" + robot("r");
    longModel.replace(longModel.find("ur5"), 3, std::string(100000, 'u'));
    const Result<CellDescription> r = parseCellDescription(longModel, "t.yaml");
    ASSERT_FALSE(r.ok());
    EXPECT_LT(r.error().message.size(), 200u) << r.error().message;
    EXPECT_EQ(r.error().message.rfind("t.yaml:5: robots[0].model: unknown robot model 'uuu", 0), 0u)
        << r.error().message;
}

// --- names and references -------------------------------------------------------------------

TEST(CellFileErrors, DuplicateNamesAcrossKinds) {
    expectError(
        kHead + "tools:\n" + tool("g", 1) + "docks:\n  - name: g\n    pose: {xyz: [0, 0, 0]}\n",
        ErrorCode::kDuplicateName, 12,
        "docks[0].name: name 'g' already used by the tool at line 4");
    expectError(kHead + "tools:\n" + tool("g", 1) + tool("g", 2), ErrorCode::kDuplicateName, 11,
                "tools[1].name: name 'g' already used by the tool at line 4");
}

TEST(CellFileErrors, UnknownReferences) {
    expectError(kHead + "robots:\n" + robot("r", "    tool: nothing\n"), ErrorCode::kUnknownName, 9,
                "robots[0].tool: 'nothing' does not exist");
    expectError(kHead + "tools:\n" + tool("g", 1) + "robots:\n" + robot("r", "    tool: r\n"),
                ErrorCode::kUnknownName, 17, "robots[0].tool: 'r' is a robot, not a tool");
    expectError(kHead + "docks:\n  - name: d\n    pose: {xyz: [0, 0, 0]}\n    tool: d\n",
                ErrorCode::kUnknownName, 6, "docks[0].tool: 'd' is a dock, not a tool");
    expectError(kHead +
                    "objects:\n"
                    "  - name: cube\n"
                    "    shape: box\n"
                    "    size: [0.04, 0.04, 0.04]\n"
                    "    mass: 0.05\n"
                    "    color: green\n"
                    "    pose: {xyz: [0, 0, 0.02]}\n"
                    "    on: floor\n",
                ErrorCode::kUnknownName, 10, "objects[0].on: 'floor' does not exist");
}

TEST(CellFileErrors, ToolInTwoPlaces) {
    const std::string tools = "tools:\n" + tool("g", 1);  // lines 3-10
    expectError(kHead + tools + "robots:\n" + robot("r", "    tool: g\n") +
                    "docks:\n  - name: d\n    pose: {xyz: [0, 0, 0]}\n    tool: g\n",
                ErrorCode::kConflict, 21,
                "docks[0].tool: tool 'g' is already on the flange of robot 'r'");
    expectError(kHead + tools +
                    "docks:\n"
                    "  - name: d1\n"
                    "    pose: {xyz: [0, 0, 0]}\n"
                    "    tool: g\n"
                    "  - name: d2\n"
                    "    pose: {xyz: [1, 0, 0]}\n"
                    "    tool: g\n",
                ErrorCode::kConflict, 17, "docks[1].tool: tool 'g' is already parked in dock 'd1'");
    expectError(
        kHead + tools + "robots:\n" + robot("r", "    tool: g\n") + robot("s", "    tool: g\n"),
        ErrorCode::kConflict, 23, "robots[1].tool: tool 'g' is already on the flange");
}

TEST(CellFileErrors, OtherConflicts) {
    std::string twoRobots = kHead + "robots:\n" + robot("r") + robot("s");  // s: lines 9-13
    twoRobots.replace(twoRobots.find("port: 0"), 7, "port: 30004");
    EXPECT_TRUE(parseCellDescription(twoRobots, "t.yaml").ok());  // port 0 may repeat
    twoRobots.replace(twoRobots.find("port: 0"), 7, "port: 30004");
    expectError(twoRobots, ErrorCode::kConflict, 13,
                "robots[1].controller.port: port 30004 already used by robot 'r' at line 4");
    expectError(kHead + "tools:\n" + tool("g", 3) + tool("h", 3), ErrorCode::kConflict, 14,
                "tools[1].changer-id: changer-id 3 already used by tool 'g' at line 4");
    const std::string cube =
        "    shape: box\n"
        "    size: [0.04, 0.04, 0.04]\n"
        "    mass: 0.05\n"
        "    color: green\n"
        "    pose: {xyz: [0, 0, 0.02]}\n";
    expectError(kHead + "objects:\n  - name: a\n" + cube + "    on: b\n  - name: b\n" + cube +
                    "    on: a\n",
                ErrorCode::kConflict, 17,
                "objects[1].on: the objects under object 'b' go round in a loop (through 'a')");
    expectError(kHead + "objects:\n  - name: a\n" + cube + "    on: a\n", ErrorCode::kConflict, 10,
                "objects[0].on: the objects under object 'a' go round in a loop (through 'a')");
}

// --- bounds ---------------------------------------------------------------------------------

TEST(CellFileErrors, BoundedCounts) {
    std::string text = kHead + "robots:\n";
    for (std::size_t i = 0; i < kMaxRobots; ++i) text += robot("r" + std::to_string(i));
    EXPECT_TRUE(parseCellDescription(text, "t.yaml").ok());
    expectError(text + robot("one-more"), ErrorCode::kTooMany, 4, "robots: 17 entries, at most 16");

    text = kHead + "objects:\n";
    for (std::size_t i = 0; i <= kMaxObjects; ++i) {
        text += "  - {name: o" + std::to_string(i) +
                ", shape: box, size: [1, 1, 1], mass: 1, color: red, pose: {xyz: [0, 0, 0]}}\n";
    }
    expectError(text, ErrorCode::kTooMany, 4, "objects: 1025 entries, at most 1024");

    // The largest stack: 1024 objects each on the next, the last on a table.
    text = kHead + "tables:\n  - {name: tab, pose: {xyz: [0, 0, 0]}, size: [1, 1, 1]}\nobjects:\n";
    for (std::size_t i = 0; i < kMaxObjects; ++i) {
        const std::string under = i + 1 < kMaxObjects ? "o" + std::to_string(i + 1) : "tab";
        text += "  - {name: o" + std::to_string(i) +
                ", shape: box, size: [1, 1, 1], mass: 1, color: red, pose: {xyz: [0, 0, 0]}, on: " +
                under + "}\n";
    }
    const Result<CellDescription> stack = parseCellDescription(text, "t.yaml");
    ASSERT_TRUE(stack.ok()) << stack.error().message;
    EXPECT_EQ(stack->objects.size(), kMaxObjects);

    // A mapping of 10^5 keys (the size limit allows it) is checked without quadratic work.
    text = kHead;
    for (int i = 0; i < 100000; ++i) text += "k" + std::to_string(i) + ": 0\n";
    expectError(text, ErrorCode::kUnknownKey, 3, "unknown key 'k0'");
    text = "pnp-cell: 1\n";
    for (int i = 0; i < 100000; ++i) text += "name: t\n";
    expectError(text, ErrorCode::kUnknownKey, 3, "key 'name' repeated (first at line 2)");
}

}  // namespace
}  // namespace pnp::world
