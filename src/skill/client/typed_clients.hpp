// Typed clients of the skill model's skill types: each checks in its constructor that the
// skill is of its type (subtypes accepted; else Error BadTypeMismatch) and offers a run()
// with the type's parameters as C++ arguments. The untyped SkillClient::run stays available.
//
//   MoveGripperSkillClient gripper(ua, node);
//   RunResult r = gripper.run(/*width*/ 0.04, /*force*/ 20.0, 2s);
#pragma once

#include <optional>
#include <stop_token>
#include <string>
#include <vector>

#include "skill/client/skill_client.hpp"
#include "ua/types/ns0_types_model.hpp"

namespace pnp::skill::client {

// A SkillClient whose skill must be of type `type` (or a subtype).
class TypedSkillClient : public SkillClient {
  public:
    TypedSkillClient(const ModelNode& type, std::shared_ptr<Client> client, ua::NodeId skill,
                     Deadline deadline = {}, SkillClientOptions options = {});
    using SkillClient::run;
};

class GraspGripperSkillClient : public TypedSkillClient {
  public:
    GraspGripperSkillClient(std::shared_ptr<Client> client, ua::NodeId skill,
                            Deadline deadline = {}, SkillClientOptions options = {});
    using SkillClient::run;
    // Force (N) is optional in the type: written only when the skill has it.
    RunResult run(std::optional<double> force, Deadline deadline, std::stop_token cancel = {});
};

class ReleaseGripperSkillClient : public TypedSkillClient {
  public:
    ReleaseGripperSkillClient(std::shared_ptr<Client> client, ua::NodeId skill,
                              Deadline deadline = {}, SkillClientOptions options = {});
    using SkillClient::run;
    RunResult run(std::optional<double> force, Deadline deadline, std::stop_token cancel = {});
};

class MoveGripperSkillClient : public TypedSkillClient {
  public:
    MoveGripperSkillClient(std::shared_ptr<Client> client, ua::NodeId skill, Deadline deadline = {},
                           SkillClientOptions options = {});
    using SkillClient::run;
    RunResult run(double width, double force, Deadline deadline, std::stop_token cancel = {});
};

// Joint moves: TargetJointPosition, MaxVelocity, MaxAcceleration (per axis), ToolFrame.
struct JointMove {
    std::vector<double> targetJoints;
    std::vector<double> maxVelocity;
    std::vector<double> maxAcceleration;
    std::string toolFrame;
};
NamedValues parametersOf(const JointMove& move);

class JointPtpMoveSkillClient : public TypedSkillClient {
  public:
    JointPtpMoveSkillClient(std::shared_ptr<Client> client, ua::NodeId skill,
                            Deadline deadline = {}, SkillClientOptions options = {});
    using SkillClient::run;
    RunResult run(const JointMove& move, Deadline deadline, std::stop_token cancel = {});
    RunResult run(std::vector<double> targetJoints, std::vector<double> maxVelocity,
                  std::vector<double> maxAcceleration, std::string toolFrame, Deadline deadline,
                  std::stop_token cancel = {});
};

class JointLinearMoveSkillClient : public TypedSkillClient {
  public:
    JointLinearMoveSkillClient(std::shared_ptr<Client> client, ua::NodeId skill,
                               Deadline deadline = {}, SkillClientOptions options = {});
    using SkillClient::run;
    RunResult run(const JointMove& move, Deadline deadline, std::stop_token cancel = {});
    RunResult run(std::vector<double> targetJoints, std::vector<double> maxVelocity,
                  std::vector<double> maxAcceleration, std::string toolFrame, Deadline deadline,
                  std::stop_token cancel = {});
};

// Cartesian moves: TargetPosition, AxisBounds, MaxVelocity, MaxAcceleration, ToolFrame.
// FinalResultData adds ForcesExceeded (Boolean) and ForcesMax (ThreeDVector).
struct CartesianMove {
    ua::ThreeDFrame target;
    std::vector<ua::Range> axisBounds;
    std::vector<double> maxVelocity;
    std::vector<double> maxAcceleration;
    std::string toolFrame;
};
NamedValues parametersOf(const CartesianMove& move);

struct CartesianMoveResult {
    RunResult run;
    bool forcesExceeded = false;
    std::optional<ua::ThreeDVector> forcesMax;
};
CartesianMoveResult cartesianResultOf(RunResult r);

class CartesianPtpMoveSkillClient : public TypedSkillClient {
  public:
    CartesianPtpMoveSkillClient(std::shared_ptr<Client> client, ua::NodeId skill,
                                Deadline deadline = {}, SkillClientOptions options = {});
    using SkillClient::run;
    CartesianMoveResult run(const CartesianMove& move, Deadline deadline,
                            std::stop_token cancel = {});
};

class CartesianLinearMoveSkillClient : public TypedSkillClient {
  public:
    CartesianLinearMoveSkillClient(std::shared_ptr<Client> client, ua::NodeId skill,
                                   Deadline deadline = {}, SkillClientOptions options = {});
    using SkillClient::run;
    CartesianMoveResult run(const CartesianMove& move, Deadline deadline,
                            std::stop_token cancel = {});
};

}  // namespace pnp::skill::client
