#include "component/toolchanger/robot_arm.hpp"

#include <stdexcept>

#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"

namespace pnp::component::toolchanger {

RobotArm::RobotArm(const skill::detector::DetectedSkill& moveSkill,
                   std::chrono::milliseconds timeout)
    : url_(moveSkill.endpointUrl), name_(moveSkill.controllerName), timeout_(timeout) {
    ua::client::ClientConfig cc;
    cc.applicationName = "pnp tool changer";
    cc.applicationUri = "urn:pnp:component:toolchanger:robot-client";
    cc.requestTimeout = timeout;
    cc.connectTimeout = timeout;
    client_ = std::make_shared<ua::client::Client>(cc);
    client_->connect(url_);
    move_ = std::make_unique<skill::client::CartesianLinearMoveSkillClient>(client_, moveSkill.node,
                                                                            timeout);
    controller_ = moveSkill.controller;
    const ua::UInt16 robotics = client_->namespaceIndex(skill::kRoboticsUri, timeout);
    for (const auto& r : client_->browse(controller_, {}, timeout)) {
        if (r.nodeId.serverIndex != 0 || r.browseName.namespaceIndex != robotics) continue;
        if (r.browseName.name == "SetTool") setTool_ = r.nodeId.nodeId;
        if (r.browseName.name == "ClearTool") clearTool_ = r.nodeId.nodeId;
        if (r.browseName.name == "ActualFlangePose") flangePose_ = r.nodeId.nodeId;
    }
    if (setTool_.isNull() || clearTool_.isNull())
        throw std::runtime_error("the robot " + name_ + " at " + url_ +
                                 " has no SetTool / ClearTool methods");
}

RobotArm::~RobotArm() {
    move_.reset();
    client_->stopBackgroundThread();
}

MoveOutcome RobotArm::moveLinear(const Eigen::Isometry3d& target,
                                 const std::vector<double>& maxVelocity,
                                 std::chrono::milliseconds timeout, std::stop_token cancel) {
    skill::client::CartesianMove m;
    m.target = ua::spatial::toFrame(target);
    m.maxVelocity = maxVelocity;
    MoveOutcome out;
    try {
        const auto r = move_->run(m, timeout, cancel);
        out.completed = r.run.result == skill::SkillResult::Completed;
        out.aborted = r.run.result == skill::SkillResult::Aborted || cancel.stop_requested();
        if (r.run.timedOut)
            out.message = "the robot's move did not end within " + std::to_string(timeout.count()) +
                          " ms (halted)";
        else if (!out.completed)
            out.message = "the robot's move " + std::string(skill::toString(r.run.result)) +
                          (r.run.message.empty() ? "" : ": " + r.run.message);
    } catch (const std::exception& e) {
        out.message = std::string("the robot's move: ") + e.what();
    }
    return out;
}

std::string RobotArm::setTool(const std::string& name, const Eigen::Isometry3d& flangeToTool) {
    try {
        const auto r =
            client_->call(controller_, setTool_,
                          {ua::Variant(ua::String(name)),
                           ua::Variant(ua::toExtensionObject(ua::spatial::toFrame(flangeToTool)))},
                          timeout_);
        if (!r.ok()) return "SetTool(" + name + "): " + r.status.toString();
    } catch (const std::exception& e) {
        return "SetTool(" + name + "): " + e.what();
    }
    return {};
}

std::string RobotArm::clearTool(const std::string& name) {
    try {
        const auto r =
            client_->call(controller_, clearTool_, {ua::Variant(ua::String(name))}, timeout_);
        if (!r.ok()) return "ClearTool(" + name + "): " + r.status.toString();
    } catch (const std::exception& e) {
        return "ClearTool(" + name + "): " + e.what();
    }
    return {};
}

std::optional<Eigen::Isometry3d> RobotArm::flangePose(std::string& error) {
    if (flangePose_.isNull()) {
        error = "the robot " + name_ + " offers no ActualFlangePose";
        return std::nullopt;
    }
    try {
        const ua::DataValue dv =
            client_->readAttribute(flangePose_, ua::AttributeId::Value, timeout_);
        if (!dv.statusOrGood().isGood()) {
            error = "ActualFlangePose of " + name_ + ": " + dv.statusOrGood().toString();
            return std::nullopt;
        }
        const auto* x = dv.value ? dv.value->scalar<ua::ExtensionObject>() : nullptr;
        auto f = x ? ua::fromExtensionObject<ua::ThreeDFrame>(*x) : std::nullopt;
        if (!f || !ua::spatial::finite(*f)) {
            error = "ActualFlangePose of " + name_ + " is not a finite ThreeDFrame";
            return std::nullopt;
        }
        return ua::spatial::toIsometry(*f);
    } catch (const std::exception& e) {
        error = "ActualFlangePose of " + name_ + ": " + e.what();
        return std::nullopt;
    }
}

}  // namespace pnp::component::toolchanger
