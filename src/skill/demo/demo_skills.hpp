// Demo skills of the base model, simulated in software:
//   Delay        DelaySkillType: waits DurationMs of Running time (Suspend pauses it, Halt
//                stops it); fails with FailWith when that is not empty. DurationMs 0 = a
//                no-op skill (benchmarks).
//   Grasp        GraspGripperSkillType: closes a simulated gripper (40 ms), Force optional.
//   Release      ReleaseGripperSkillType: opens it (40 ms).
//   MoveGripper  MoveGripperSkillType: moves the jaws to Width (m) at 0.5 m/s, Force; fails
//                for a width outside 0..0.1 m; reports progress (the width reached).
#pragma once

#include <memory>
#include <string>

#include "skill/server/controller.hpp"

namespace pnp::skill::demo {

// Loads the models the demo needs (base, demo) into the server's address space.
void loadDemoModels(ua::server::Server& server);

// A controller "name" with the four skills above (call before Server::start()).
std::unique_ptr<server::SkillController> addDemoSkills(ua::server::Server& server,
                                                       const std::string& name = "DemoGripper");

}  // namespace pnp::skill::demo
