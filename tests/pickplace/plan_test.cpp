// The pick-and-place geometry (plan.hpp) and the knowledge-base lookup (knowledge.hpp) against
// a small test-local knowledge base: no processes, no network.
#include "component/pickplace/plan.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "component/pickplace/knowledge.hpp"
#include "ua/spatial/spatial.hpp"

namespace {

using namespace pnp::component::pickplace;
using Eigen::Isometry3d;
using Eigen::Vector3d;

Isometry3d at(double x, double y, double z, double yaw = 0) {
    Isometry3d p = Isometry3d::Identity();
    p.translation() = Vector3d(x, y, z);
    p.linear() = Eigen::AngleAxisd(yaw, Vector3d::UnitZ()).toRotationMatrix();
    return p;
}

ObjectInfo cube() {
    ObjectInfo o;
    o.id = "cube-green";
    o.pose = at(0.05, 0.10, 0.02);
    o.size = Vector3d(0.04, 0.04, 0.04);
    return o;
}

GripPoint vacuum() {
    GripPoint g;
    g.kind = GripKind::Vacuum;
    g.offset.translation() = Vector3d(0, 0, 0.1868);
    return g;
}

GripPoint robotiq() {
    GripPoint g;
    g.kind = GripKind::Parallel;
    g.offset.translation() = Vector3d(0, 0, 0.2028);
    g.spanLow = 0.0;
    g.spanHigh = 0.085;
    return g;
}

TEST(PickPlacePlan, VacuumCupOnTheTopFaceFromAboveAndTheCentreEndsHalfTheHeightAbovePlace) {
    std::string error;
    auto p = planPickAndPlace(cube(), vacuum(), at(-0.05, -0.10, 0), {}, error);
    ASSERT_TRUE(p) << error;
    EXPECT_TRUE(p->pick.translation().isApprox(Vector3d(0.05, 0.10, 0.04), 1e-12));
    EXPECT_TRUE(p->pickApproach.translation().isApprox(Vector3d(0.05, 0.10, 0.09), 1e-12));
    EXPECT_TRUE(p->objectAtPlace.translation().isApprox(Vector3d(-0.05, -0.10, 0.02), 1e-12));
    EXPECT_TRUE(p->place.translation().isApprox(Vector3d(-0.05, -0.10, 0.04), 1e-12));
    EXPECT_TRUE(p->placeApproach.translation().isApprox(Vector3d(-0.05, -0.10, 0.09), 1e-12));
    // Tool z down.
    EXPECT_NEAR(p->pick.linear().col(2).z(), -1.0, 1e-12);
    EXPECT_NEAR(p->place.linear().col(2).z(), -1.0, 1e-12);
    EXPECT_EQ(p->gripWidth, 0.0);
}

TEST(PickPlacePlan, ParallelFingersAroundTheCentreKeepTheObjectsYaw) {
    ObjectInfo o = cube();
    o.pose = at(0.05, 0.10, 0.02, 0.3);
    std::string error;
    auto p =
        planPickAndPlace(o, robotiq(), at(-0.05, -0.10, 0, 0.3), {.approachHeight = 0.08}, error);
    ASSERT_TRUE(p) << error;
    EXPECT_TRUE(p->pick.translation().isApprox(Vector3d(0.05, 0.10, 0.02), 1e-12));
    EXPECT_NEAR(p->pickApproach.translation().z(), 0.10, 1e-12);
    EXPECT_NEAR(p->gripWidth, 0.04, 1e-12);
    // The fingers' axis (grip x) lies along the object's x axis.
    const Vector3d fingers = p->pick.linear().col(0);
    EXPECT_NEAR(std::abs(fingers.dot(o.pose.linear().col(0))), 1.0, 1e-12);
    EXPECT_NEAR(p->pick.linear().col(2).z(), -1.0, 1e-12);
}

TEST(PickPlacePlan, AnObjectWiderThanTheSpanIsRefusedWithTheNumbers) {
    ObjectInfo o = cube();
    o.id = "box-wide";
    o.size = Vector3d(0.12, 0.10, 0.04);
    std::string error;
    EXPECT_FALSE(planPickAndPlace(o, robotiq(), at(0, 0, 0), {}, error));
    EXPECT_NE(error.find("box-wide is 0.100 m wide"), std::string::npos) << error;
    EXPECT_NE(error.find("opens to 0.085 m"), std::string::npos) << error;
}

TEST(PickPlacePlan, OnlyTheNarrowSideFitsTheFingersAreTurned) {
    ObjectInfo o = cube();
    o.size = Vector3d(0.12, 0.05, 0.04);
    std::string error;
    auto p = planPickAndPlace(o, robotiq(), at(0, 0, 0), {}, error);
    ASSERT_TRUE(p) << error;
    EXPECT_NEAR(p->gripWidth, 0.05, 1e-12);
    EXPECT_NEAR(std::abs(p->pick.linear().col(0).dot(Vector3d::UnitY())), 1.0, 1e-12);
}

TEST(PickPlacePlan, BadInputIsRefused) {
    std::string error;
    ObjectInfo o = cube();
    o.size = Vector3d(0, 0.04, 0.04);
    EXPECT_FALSE(planPickAndPlace(o, vacuum(), at(0, 0, 0), {}, error));
    o = cube();
    o.pose.linear() = Eigen::AngleAxisd(0.5, Vector3d::UnitX()).toRotationMatrix();
    EXPECT_FALSE(planPickAndPlace(o, vacuum(), at(0, 0, 0), {}, error));
    EXPECT_NE(error.find("not upright"), std::string::npos);
    Isometry3d nan = at(0, 0, 0);
    nan.translation().x() = std::nan("");
    EXPECT_FALSE(planPickAndPlace(cube(), vacuum(), nan, {}, error));
}

TEST(PickPlaceKnowledge, PosesAndSizesParseStrictly) {
    auto p = parsePose("0.05, 0.10,0.02,0,0,1.5");
    ASSERT_TRUE(p);
    EXPECT_TRUE(p->translation().isApprox(Vector3d(0.05, 0.10, 0.02)));
    EXPECT_FALSE(parsePose("0.05,0.10,0.02,0,0"));
    EXPECT_FALSE(parsePose("0.05,0.10,0.02,0,0,1,2"));
    EXPECT_FALSE(parsePose("0.05,0.10,x,0,0,1"));
    EXPECT_FALSE(parsePose("0.05,0.10,nan,0,0,1"));
    EXPECT_FALSE(parsePose(""));
    EXPECT_TRUE(parseSize("0.04,0.04,0.04"));
    EXPECT_FALSE(parseSize("0.04,0.04,"));
    auto back = parsePose(poseText(*p));
    ASSERT_TRUE(back);
    EXPECT_TRUE(back->isApprox(*p, 1e-6));
    EXPECT_TRUE(validObjectId("cube-green"));
    EXPECT_FALSE(validObjectId("cube\" } DROP"));
    EXPECT_FALSE(validObjectId(""));
    EXPECT_FALSE(validObjectId(std::string(129, 'a')));
}

// A knowledge base that answers the lookup from a map and records the updates.
class FakeKnowledge : public pnp::kb::KnowledgeBase {
  public:
    std::map<std::string, std::pair<std::string, std::string>> objects;  // id -> pose, size
    std::vector<std::string> queries, updates;
    pnp::kb::Results select(std::string_view query, pnp::kb::Deadline) override {
        queries.emplace_back(query);
        pnp::kb::Results r;
        r.variables = {"pose", "size"};
        for (const auto& [id, ps] : objects)
            if (query.find("pnp:id \"" + id + "\"") != std::string_view::npos)
                r.rows.push_back({pnp::kb::Term{pnp::kb::Term::Kind::Literal, ps.first, "", ""},
                                  pnp::kb::Term{pnp::kb::Term::Kind::Literal, ps.second, "", ""}});
        return r;
    }
    bool ask(std::string_view, pnp::kb::Deadline) override { return false; }
    void update(std::string_view u, pnp::kb::Deadline) override { updates.emplace_back(u); }
    std::size_t loadTurtle(const std::filesystem::path&, const std::string&,
                           pnp::kb::Deadline) override {
        return 0;
    }
    std::string describe() const override { return "fake"; }
};

TEST(PickPlaceKnowledge, LookupAndUpdateSendTheVocabularysQueries) {
    FakeKnowledge kb;
    kb.objects["cube-green"] = {"0.05,0.10,0.02,0,0,0", "0.04,0.04,0.04"};
    kb.objects["broken"] = {"here", "0.04,0.04,0.04"};
    std::string error;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(1);
    auto o = lookupObject(kb, "cube-green", deadline, error);
    ASSERT_TRUE(o) << error;
    EXPECT_TRUE(o->pose.translation().isApprox(Vector3d(0.05, 0.10, 0.02)));
    EXPECT_TRUE(o->size.isApprox(Vector3d(0.04, 0.04, 0.04)));
    ASSERT_EQ(kb.queries.size(), 1u);
    EXPECT_NE(kb.queries[0].find("a/rdfs:subClassOf* pnp:Object"), std::string::npos);
    EXPECT_NE(kb.queries[0].find("PREFIX pnp: <urn:pnp:kb#>"), std::string::npos);

    EXPECT_FALSE(lookupObject(kb, "cube-red", deadline, error));
    EXPECT_NE(error.find("no object with pnp:id \"cube-red\""), std::string::npos) << error;
    EXPECT_FALSE(lookupObject(kb, "broken", deadline, error));
    EXPECT_NE(error.find("pnp:pose of \"broken\""), std::string::npos) << error;
    EXPECT_FALSE(lookupObject(kb, "a\"b", deadline, error));
    EXPECT_EQ(kb.queries.size(), 3u);  // the bad id never reached the knowledge base

    storeObjectPose(kb, "cube-green", at(-0.05, -0.10, 0.02), deadline);
    ASSERT_EQ(kb.updates.size(), 1u);
    EXPECT_NE(kb.updates[0].find("DELETE { GRAPH ?g { ?o pnp:pose ?old } }"), std::string::npos);
    EXPECT_NE(kb.updates[0].find("\"-0.050000,-0.100000,0.020000,"), std::string::npos)
        << kb.updates[0];
}

}  // namespace
