// The MES's own use of the knowledge base on this backend: the repository's knowledge
// (models/kb/*.ttl and the skill types derived from the NodeSet2 models) loads and validates,
// the thesis process reads the same nine steps, a step's parameters resolve, the type
// hierarchy answers — the same query text as on the embedded engine, so `pnp mes --kb URL`
// behaves as the default.
#include <gtest/gtest.h>

#include <filesystem>

#include "kb_suite.hpp"
#include "mes/process.hpp"

namespace pnp::kb::test {

TEST(MesQueries, TheRepositorysKnowledgeAndTheThesisProcess) {
    mes::SharedKb kb(openBackend(PNP_KB_BACKEND));
    // The Virtuoso store is shared by the suite: leave none of our graphs behind.
    struct Clear {
        mes::SharedKb& kb;
        ~Clear() {
            try {
                kb.update("CLEAR GRAPH <urn:pnp:kb:skill-types>", soon());
                for (const auto& f : mes::defaultKnowledgeFiles())
                    kb.update("CLEAR GRAPH <file://" +
                                  std::filesystem::absolute(f).lexically_normal().string() + ">",
                              soon());
            } catch (const std::exception& e) {
                ADD_FAILURE() << "clearing the graphs: " << e.what();
            }
        }
    } clear{kb};
    mes::loadKnowledge(kb, mes::defaultKnowledgeFiles(), soon(std::chrono::seconds(60)));
    const auto p = mes::loadProcess(kb, "urn:pnp:kb:process#thesis", soon());
    ASSERT_EQ(p.steps.size(), 9u);
    EXPECT_EQ(p.steps.front().skillType, "urn:pnp:ua:skills:toolchanger#ChangeToolSkillType");
    EXPECT_EQ(p.steps.back().skillType, "urn:pnp:ua:skills:toolchanger#DropToolSkillType");
    for (const auto& b : p.steps[1].bindings) {
        const auto r = mes::resolveBinding(kb, b, soon());
        if (b.name == "ObjectId") {
            EXPECT_EQ(r.text, "cube-green");
        }
        if (b.name == "PlacePosition") {
            EXPECT_EQ(r.text, "-0.05,-0.10,0,0,0,0");
        }
    }
    const auto params =
        mes::typeParameters(kb, "urn:pnp:ua:skills:robotics#CartesianLinearMoveSkillType", soon());
    EXPECT_EQ(params.count("TargetPosition"), 1u);
    EXPECT_TRUE(kb.ask(std::string(mes::kPrefixes) +
                           "ASK { <urn:pnp:ua:skills:composite#PickAndPlaceSkillType> "
                           "rdfs:subClassOf* <urn:pnp:ua:skills#SkillType> }",
                       soon()));
}

}  // namespace pnp::kb::test
