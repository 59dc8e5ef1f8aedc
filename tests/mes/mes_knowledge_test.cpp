// Loading the knowledge: the skill types derived from the NodeSet2 models, the repository's
// Turtle files, the thesis process; what is refused at load (file, line, what is wrong).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <string>

#include "mes/process.hpp"
#include "mes/skill_type_graph.hpp"

using namespace pnp;
using namespace std::chrono_literals;

namespace {

kb::Deadline soon() { return std::chrono::steady_clock::now() + 10s; }

std::string tmpFile(const std::string& name, const std::string& text) {
    const std::string path =
        ::testing::TempDir() + "pnp_mes_" + std::to_string(::getpid()) + "_" + name;
    std::ofstream(path) << text;
    return path;
}

const char* kHeader =
    "@prefix pnp: <urn:pnp:kb#> .\n"
    "@prefix proc: <urn:pnp:kb:process#> .\n"
    "@prefix demo: <urn:pnp:ua:skills:demo#> .\n";

std::vector<std::filesystem::path> withDefaults(const std::string& extra) {
    auto files = mes::defaultKnowledgeFiles();
    files.emplace_back(extra);
    return files;
}

}  // namespace

TEST(MesKnowledge, SkillTypesComeFromTheModelsWithHierarchyAndParameters) {
    mes::SharedKb kb(kb::open(""));
    mes::loadKnowledge(kb, mes::defaultKnowledgeFiles(), soon());
    // A subtype chain: CartesianLinearMove -> LinearMove -> MoveSkill -> SkillType.
    EXPECT_TRUE(kb.ask(std::string(mes::kPrefixes) +
                           "ASK { <urn:pnp:ua:skills:robotics#CartesianLinearMoveSkillType> "
                           "rdfs:subClassOf+ <urn:pnp:ua:skills#SkillType> }",
                       soon()));
    // Parameters of the type itself, of its supertypes and of its interfaces.
    auto params =
        mes::typeParameters(kb, "urn:pnp:ua:skills:robotics#CartesianLinearMoveSkillType", soon());
    EXPECT_EQ(params.count("TargetPosition"), 1u);
    EXPECT_EQ(params["TargetPosition"], "ThreeDFrame");
    EXPECT_EQ(params.count("MaxVelocity"), 1u);
    auto pick =
        mes::typeParameters(kb, "urn:pnp:ua:skills:composite#PickAndPlaceSkillType", soon());
    for (const char* p : {"ObjectId", "ToolSkillControllerEndpoint", "MoveSkillControllerEndpoint",
                          "PlacePosition"})
        EXPECT_EQ(pick.count(p), 1u) << p;
}

TEST(MesKnowledge, TheThesisProcessHasItsNineStepsInOrder) {
    mes::SharedKb kb(kb::open(""));
    mes::loadKnowledge(kb, mes::defaultKnowledgeFiles(), soon());
    const auto p = mes::loadProcess(kb, "urn:pnp:kb:process#thesis", soon());
    ASSERT_EQ(p.steps.size(), 9u);
    const char* change = "urn:pnp:ua:skills:toolchanger#ChangeToolSkillType";
    const char* pick = "urn:pnp:ua:skills:composite#PickAndPlaceSkillType";
    const char* expected[] = {change, pick,   change,
                              pick,   change, pick,
                              change, pick,   "urn:pnp:ua:skills:toolchanger#DropToolSkillType"};
    for (std::size_t i = 0; i < 9; ++i) {
        EXPECT_EQ(p.steps[i].index, static_cast<int>(i + 1));
        EXPECT_EQ(p.steps[i].skillType, expected[i]) << i;
    }
    // Step 1's ToolPosition is dock 1's pose, looked up in the cell's resources.
    const auto& b = p.steps[0].bindings;
    auto it =
        std::find_if(b.begin(), b.end(), [](const auto& x) { return x.name == "ToolPosition"; });
    ASSERT_NE(it, b.end());
    const auto r = mes::resolveBinding(kb, *it, soon());
    EXPECT_EQ(r.text, "-0.125,0.513,-0.036,0,3.14159265358979,0");
    EXPECT_EQ(r.source, "urn:pnp:kb:cell#dock-1");
    // No vendor and no device in the process: every ApplicationUri / endpoint is empty.
    for (const auto& s : p.steps)
        for (const auto& x : s.bindings)
            if (x.name.ends_with("Endpoint") || x.name == "ToolAppUri") {
                EXPECT_EQ(x.value, "");
            }
}

TEST(MesKnowledge, AnInvalidTurtleFileIsRefusedWithFileLineAndColumn) {
    const auto f =
        tmpFile("bad.ttl", std::string(kHeader) + "proc:x a pnp:Process .\nproc:y a ;\n");
    mes::SharedKb kb(kb::open(""));
    try {
        mes::loadKnowledge(kb, withDefaults(f), soon());
        FAIL() << "accepted";
    } catch (const mes::ProcessError& e) {
        const std::string what = e.what();
        EXPECT_NE(what.find(f + ":5:"), std::string::npos) << what;
    }
}

TEST(MesKnowledge, AnUnknownSkillTypeOrParameterIsRefusedNamingFileAndLine) {
    const auto f =
        tmpFile("unknown.ttl", std::string(kHeader) +
                                   "proc:p a pnp:Process .\n"
                                   "proc:p-1 a pnp:Step ; pnp:process proc:p ; pnp:index 1 ;\n"
                                   "    pnp:skillType demo:DelaySkillTyp .\n"
                                   "proc:p-2 a pnp:Step ; pnp:process proc:p ; pnp:index 2 ;\n"
                                   "    pnp:skillType demo:DelaySkillType ;\n"
                                   "    pnp:binding [ pnp:name \"Duration\" ; pnp:value \"5\" ] .\n"
                                   "proc:p-3 a pnp:Step ; pnp:process proc:p ; pnp:index 3 ;\n"
                                   "    pnp:skillType demo:DelaySkillType ;\n"
                                   "    pnp:binding [ pnp:name \"FailWith\" ] .\n");
    mes::SharedKb kb(kb::open(""));
    try {
        mes::loadKnowledge(kb, withDefaults(f), soon());
        FAIL() << "accepted";
    } catch (const mes::ProcessError& e) {
        const std::string what = e.what();
        EXPECT_NE(
            what.find(f + ":6: step p-1: unknown skill type urn:pnp:ua:skills:demo#DelaySkillTyp"),
            std::string::npos)
            << what;
        EXPECT_NE(
            what.find(f + ":9: step p-2: DelaySkillType has no parameter \"Duration\" (it has: "
                          "DurationMs, FailWith)"),
            std::string::npos)
            << what;
        EXPECT_NE(what.find(f + ":12: step p-3: parameter FailWith needs exactly one of"),
                  std::string::npos)
            << what;
    }
}
