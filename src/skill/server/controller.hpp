// The skill controller of a component (docs/skills.md): in one call, the device node below
// DI DeviceSet (or Objects), its HasInterface reference to ISkillControllerType with the
// interface's Name and Skills folder, and one skill instance per add() — instantiated from
// the skill's type, with its parameters checked, its program state machine, DI lock and
// worker thread bound.
//
//   Server server(config);
//   loadSkillModels(server.addressSpace(), {kRoboticsUri});
//   SkillController gripper(server, {.name = "Gripper"});
//   gripper.add("Grasp", std::make_shared<GraspSkill>());
//   server.start();
//
// Build the controller and add its skills before Server::start() (or inside post()): they
// change the address space structurally. The destructor halts running skills, joins their
// workers and removes the handlers; destroy it before the Server.
#pragma once

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "skill/model/model.hpp"
#include "skill/server/skill.hpp"
#include "ua/server/server.hpp"

namespace pnp::skill::server {

// Loads the NodeSet2 files of the skill models with these URIs (and the models they require:
// the base model, DI, Robotics) unless present. Throws ua::server::NodeSetError.
void loadSkillModels(ua::server::AddressSpace& space,
                     const std::vector<std::string_view>& uris = {kBaseUri});
// The NodeId of a model node in this address space; throws SkillError when the model is not
// loaded.
ua::NodeId resolve(const ua::server::AddressSpace& space, const ModelNode& node);

struct SkillControllerOptions {
    std::string name;        // BrowseName (in `namespaceIndex`) and the interface's Name
    ua::NodeId id = {};      // null: string id <name> in `namespaceIndex`
    ModelNode type = {};     // ObjectType of the device node; empty: BaseObjectType
    ua::NodeId parent = {};  // null: DI DeviceSet when DI is loaded, else Objects
    ua::UInt16 namespaceIndex = 1;
    std::chrono::milliseconds maxInactiveLockTime{10000};
};

// The live view of one skill instance (thread-safe).
class SkillHandle {
  public:
    const ua::NodeId& node() const;
    ProgramState state() const;
    bool locked() const;
    // Runs completed / failed / aborted since start-up.
    std::uint64_t runs() const;

    explicit SkillHandle(std::shared_ptr<SkillRuntime> runtime) : runtime_(std::move(runtime)) {}

  private:
    std::shared_ptr<SkillRuntime> runtime_;
};

class SkillController {
  public:
    SkillController(ua::server::Server& server, SkillControllerOptions options);
    ~SkillController();
    SkillController(const SkillController&) = delete;
    SkillController& operator=(const SkillController&) = delete;

    const ua::NodeId& node() const { return node_; }
    const ua::NodeId& skillsFolder() const { return skills_; }

    // Instantiates skill->type() as `name` below Skills and binds it. Throws SkillError
    // (abstract or unknown type, missing / mistyped parameter: the message names it).
    SkillHandle add(const std::string& name, std::shared_ptr<Skill> skill);
    std::vector<SkillHandle> skills() const;

  private:
    ua::server::Server& server_;
    SkillControllerOptions options_;
    ua::NodeId node_;
    ua::NodeId skills_;
    std::vector<std::shared_ptr<SkillRuntime>> runtimes_;
};

}  // namespace pnp::skill::server
