// The skill detector against the real server runtime: loadSkillModels + SkillController +
// skills (skill/server), on 127.0.0.1.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "skill/demo/demo_skills.hpp"
#include "skill/detector/skill_detector.hpp"
#include "skill/server/controller.hpp"
#include "support/loopback_server.hpp"
#include "ua/server/server.hpp"
#include "ua/types/ns0_enums.hpp"

using namespace pnp;
using namespace pnp::skill;
using namespace std::chrono_literals;
using detector::DetectedSkill;
using detector::ServerState;
using detector::SkillDetector;

namespace {

std::shared_ptr<server::Skill> delaySkill() {
    return server::makeSkill(
        types::DelaySkillType, {server::declareParameter<double>("DurationMs", 1.0)},
        {.execute = [](server::Execution&) { return server::Outcome::completed(); }});
}

detector::DetectorConfig config() {
    detector::DetectorConfig c;
    c.useDiscovery = false;
    c.healthInterval = 50ms;
    c.requestTimeout = 500ms;
    return c;
}

}  // namespace

TEST(SkillDetectorRuntime, SkillControllerSkillsAreFoundByTypeDefinition) {
    auto cfg = pnp::testing::loopbackConfig();
    cfg.applicationUri = "urn:pnp:test:runtime";
    cfg.applicationName = "runtime component";
    ua::server::Server srv(cfg);
    server::loadSkillModels(srv.addressSpace(), {kDemoUri, kBaseUri});
    auto controller = std::make_unique<server::SkillController>(
        srv, server::SkillControllerOptions{.name = "Gripper"});
    controller->add("Wait", delaySkill());
    controller->add("GraspGripperSkill", delaySkill());  // the name lies, the type does not
    // The demo component: Delay, Grasp, Release, MoveGripper.
    auto demo = demo::addDemoSkills(srv, "DemoGripper");
    srv.start();

    SkillDetector d(nullptr, config());
    int added = 0, removed = 0;
    std::mutex m;
    d.onChange([&](const DetectedSkill&, bool a) {
        std::lock_guard l(m);
        (a ? added : removed)++;
    });
    d.start();
    d.addServer(pnp::testing::url(srv));
    ASSERT_TRUE(d.waitUntil([](const SkillDetector& x) { return x.all().size() == 6; }, 3s));
    auto delay = d.find(types::DelaySkillType);
    EXPECT_EQ(delay.size(), 3u);
    EXPECT_EQ(d.find(types::SkillType).size(), 6u);
    EXPECT_EQ(d.find(types::GripperSkillType).size(), 3u);
    auto grasp = d.find(types::GraspGripperSkillType);
    ASSERT_EQ(grasp.size(), 1u);  // the demo's, not the lying Delay
    EXPECT_EQ(grasp[0].controller, demo->node());
    EXPECT_EQ(grasp[0].typeChain.size(), 3u);
    for (const auto& s : delay) {
        if (s.controller != controller->node()) continue;
        EXPECT_EQ(s.componentUri, "urn:pnp:test:runtime");
        EXPECT_EQ(s.controller, controller->node());
        EXPECT_EQ(s.controllerName, "Gripper");
        EXPECT_EQ(s.type.name, "DelaySkillType");
        EXPECT_TRUE(s.typeChain.back().matches(types::SkillType));
    }
    auto st = d.servers().at(0);
    std::printf("runtime server: examination %.2f ms, %zu requests after connect\n", st.examineMs,
                st.roundTrips);

    srv.stop();
    ASSERT_TRUE(d.waitUntil([](const SkillDetector& x) { return x.all().empty(); }, 3s));
    std::lock_guard l(m);
    EXPECT_EQ(added, 6);
    EXPECT_EQ(removed, 6);
    d.stop();
    demo.reset();
    controller.reset();
}
