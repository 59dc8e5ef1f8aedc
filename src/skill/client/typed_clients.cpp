#include "skill/client/typed_clients.hpp"

#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_model.hpp"

namespace pnp::skill::client {

TypedSkillClient::TypedSkillClient(const ModelNode& type, std::shared_ptr<Client> client,
                                   ua::NodeId skill, Deadline deadline, SkillClientOptions options)
    : SkillClient(std::move(client), std::move(skill), deadline, std::move(options)) {
    requireType(type);
}

#define PNP_TYPED_CLIENT_CTOR(Class, Type)                                             \
    Class::Class(std::shared_ptr<Client> client, ua::NodeId skill, Deadline deadline,  \
                 SkillClientOptions options)                                           \
        : TypedSkillClient(types::Type, std::move(client), std::move(skill), deadline, \
                           std::move(options)) {}
PNP_TYPED_CLIENT_CTOR(GraspGripperSkillClient, GraspGripperSkillType)
PNP_TYPED_CLIENT_CTOR(ReleaseGripperSkillClient, ReleaseGripperSkillType)
PNP_TYPED_CLIENT_CTOR(MoveGripperSkillClient, MoveGripperSkillType)
PNP_TYPED_CLIENT_CTOR(JointPtpMoveSkillClient, JointPtpMoveSkillType)
PNP_TYPED_CLIENT_CTOR(JointLinearMoveSkillClient, JointLinearMoveSkillType)
PNP_TYPED_CLIENT_CTOR(CartesianPtpMoveSkillClient, CartesianPtpMoveSkillType)
PNP_TYPED_CLIENT_CTOR(CartesianLinearMoveSkillClient, CartesianLinearMoveSkillType)
#undef PNP_TYPED_CLIENT_CTOR

namespace {
// Force is Optional in the gripper types: only written when the instance has it.
NamedValues optionalForce(const SkillClient& c, std::optional<double> force) {
    if (force && c.findParameter("Force") != nullptr) return {{"Force", *force}};
    return {};
}
}  // namespace

RunResult GraspGripperSkillClient::run(std::optional<double> force, Deadline deadline,
                                       std::stop_token cancel) {
    return SkillClient::run(optionalForce(*this, force), deadline, std::move(cancel));
}

RunResult ReleaseGripperSkillClient::run(std::optional<double> force, Deadline deadline,
                                         std::stop_token cancel) {
    return SkillClient::run(optionalForce(*this, force), deadline, std::move(cancel));
}

RunResult MoveGripperSkillClient::run(double width, double force, Deadline deadline,
                                      std::stop_token cancel) {
    return SkillClient::run({{"Width", width}, {"Force", force}}, deadline, std::move(cancel));
}

NamedValues parametersOf(const JointMove& m) {
    return {{"TargetJointPosition", ua::Variant(m.targetJoints)},
            {"MaxVelocity", ua::Variant(m.maxVelocity)},
            {"MaxAcceleration", ua::Variant(m.maxAcceleration)},
            {"ToolFrame", ua::Variant(m.toolFrame)}};
}

RunResult JointPtpMoveSkillClient::run(const JointMove& move, Deadline deadline,
                                       std::stop_token cancel) {
    return SkillClient::run(parametersOf(move), deadline, std::move(cancel));
}
RunResult JointPtpMoveSkillClient::run(std::vector<double> targetJoints,
                                       std::vector<double> maxVelocity,
                                       std::vector<double> maxAcceleration, std::string toolFrame,
                                       Deadline deadline, std::stop_token cancel) {
    return run(JointMove{std::move(targetJoints), std::move(maxVelocity),
                         std::move(maxAcceleration), std::move(toolFrame)},
               deadline, std::move(cancel));
}
RunResult JointLinearMoveSkillClient::run(const JointMove& move, Deadline deadline,
                                          std::stop_token cancel) {
    return SkillClient::run(parametersOf(move), deadline, std::move(cancel));
}
RunResult JointLinearMoveSkillClient::run(std::vector<double> targetJoints,
                                          std::vector<double> maxVelocity,
                                          std::vector<double> maxAcceleration,
                                          std::string toolFrame, Deadline deadline,
                                          std::stop_token cancel) {
    return run(JointMove{std::move(targetJoints), std::move(maxVelocity),
                         std::move(maxAcceleration), std::move(toolFrame)},
               deadline, std::move(cancel));
}

NamedValues parametersOf(const CartesianMove& m) {
    std::vector<ua::ExtensionObject> bounds;
    for (const auto& r : m.axisBounds) bounds.push_back(ua::toExtensionObject(r));
    return {{"TargetPosition", ua::Variant(ua::toExtensionObject(m.target))},
            {"AxisBounds", ua::Variant(std::move(bounds))},
            {"MaxVelocity", ua::Variant(m.maxVelocity)},
            {"MaxAcceleration", ua::Variant(m.maxAcceleration)},
            {"ToolFrame", ua::Variant(m.toolFrame)}};
}

CartesianMoveResult cartesianResultOf(RunResult r) {
    CartesianMoveResult out;
    for (const auto& [name, value] : r.finalResult.values) {
        if (name == "ForcesExceeded")
            if (const auto* b = value.scalar<bool>()) out.forcesExceeded = *b;
        if (name == "ForcesMax")
            if (const auto* x = value.scalar<ua::ExtensionObject>()) try {
                    out.forcesMax = ua::fromExtensionObject<ua::ThreeDVector>(*x);
                } catch (const std::exception&) {
                }
    }
    out.run = std::move(r);
    return out;
}

CartesianMoveResult CartesianPtpMoveSkillClient::run(const CartesianMove& move, Deadline deadline,
                                                     std::stop_token cancel) {
    return cartesianResultOf(SkillClient::run(parametersOf(move), deadline, std::move(cancel)));
}
CartesianMoveResult CartesianLinearMoveSkillClient::run(const CartesianMove& move,
                                                        Deadline deadline, std::stop_token cancel) {
    return cartesianResultOf(SkillClient::run(parametersOf(move), deadline, std::move(cancel)));
}

}  // namespace pnp::skill::client
