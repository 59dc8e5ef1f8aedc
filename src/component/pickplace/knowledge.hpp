// What the pick-and-place component asks the knowledge base (pnp::kb, docs/kb-vocabulary.md):
// an object's pose and size by its pnp:id, and the object's new pose after it was placed —
// the knowledge base is the component's world model, never the simulator.
//
//   auto object = lookupObject(kb, "cube-green", deadline, error);   // nullopt: error says why
//   storeObjectPose(kb, "cube-green", placedPose, deadline);         // throws kb::KbError
#pragma once

#include <Eigen/Geometry>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "component/pickplace/plan.hpp"
#include "kb/knowledge_base.hpp"

namespace pnp::component::pickplace {

// An ObjectId is an IRI local name: 1..128 of [A-Za-z0-9._-] (so it goes into a query as a
// plain literal without escaping).
bool validObjectId(std::string_view id);

// The ThreeDFrame text "x,y,z,a,b,c" (m, rad; pnp's orientation convention, ua/spatial) of
// pnp:pose, and "x,y,z" of pnp:size. nullopt for anything else.
std::optional<Eigen::Isometry3d> parsePose(std::string_view text);
std::optional<Eigen::Vector3d> parseSize(std::string_view text);
std::string poseText(const Eigen::Isometry3d& pose);

// The object with pnp:id `id` (an instance of pnp:Object or a subclass) and its pnp:pose /
// pnp:size. nullopt with the reason: unknown id, several different poses, a value that does
// not parse, the knowledge base's error.
std::optional<ObjectInfo> lookupObject(kb::KnowledgeBase& kb, const std::string& id,
                                       kb::Deadline deadline, std::string& error);

// Replaces the object's pnp:pose (in whichever graph holds it). Throws kb::KbError.
void storeObjectPose(kb::KnowledgeBase& kb, const std::string& id, const Eigen::Isometry3d& pose,
                     kb::Deadline deadline);

// The Turtle files a component loads by default: every models/kb/*.ttl of the source tree
// (skill::modelsDirectory(), i.e. $PNP_SKILL_MODELS or the build's source tree), sorted.
std::vector<std::filesystem::path> defaultKnowledgeFiles();

}  // namespace pnp::component::pickplace
