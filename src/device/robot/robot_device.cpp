// RobotDevice: the OPC 40010-1 MotionDeviceSystem instance, the skill controller on its
// MotionDevice, WorldToRobotBase / SetTool / ClearTool, and the thread that copies the
// controller's latest sample into the Robotics nodes.
#include "device/robot/robot_device.hpp"

#include <array>
#include <atomic>
#include <condition_variable>
#include <mutex>
#include <thread>

#include "device/robot/motion_context.hpp"
#include "device/robot/move_skills.hpp"
#include "skill/model/model.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::device::robot {

using ua::NodeId;
using ua::QualifiedName;
using ua::Variant;
namespace ns0 = ua::ns0;
namespace status = ua::status;

DeviceIdentity identityOf(const rb::HardwareInterface& hardware) {
    return {hardware.manufacturer(), hardware.modelName(), hardware.serialNumber(), {}};
}

motion::Limits defaultLimits(const kinematics::RobotModel& model) {
    motion::Limits l;
    for (std::size_t i = 0; i < model.limits.size(); ++i) {
        l.joint.maxVelocity[i] = model.limits[i].maxVelocity;
        l.joint.maxAcceleration[i] = model.limits[i].maxAcceleration;
    }
    return l;
}

namespace {

// OPC 40010-1 (http://opcfoundation.org/UA/Robotics/) ids.
namespace rid {
constexpr ua::UInt32 MotionDeviceSystemType = 1002;
constexpr ua::UInt32 ControllerType = 1003;
constexpr ua::UInt32 SafetyStateType = 1013;
constexpr ua::UInt32 AxisType = 16601;
constexpr ua::UInt32 Controls = 4002;
constexpr ua::UInt32 HasSafetyStates = 18182;
constexpr ua::Int32 ArticulatedRobot = 1;      // MotionDeviceCategoryEnumeration
constexpr ua::Int32 Rotary = 1;                // AxisMotionProfileEnumeration
constexpr ua::Int32 OperationalModeOther = 0;  // OperationalModeEnumeration: not known here
}  // namespace rid
constexpr ua::UInt32 kDiDeviceSet = 5001;

// UNECE units (OPC 10000-8 §5.6.3: UnitId from the common code's characters).
ua::EUInformation unit(const char* code, const char* symbol, const char* description) {
    ua::Int32 id = 0;
    for (const char* c = code; *c; ++c) id = (id << 8) | static_cast<unsigned char>(*c);
    return {"http://www.opcfoundation.org/UA/units/un/cefact", id, ua::LocalizedText("", symbol),
            ua::LocalizedText("", description)};
}

Variant text(const std::string& s) { return Variant(ua::LocalizedText("", s)); }

}  // namespace

struct RobotDevice::Impl {
    ua::server::Server& server;
    rb::Controller& controller;
    RobotDeviceOptions options;
    // Shared with the network thread's callbacks (weakly): a call in flight while the
    // device goes away finishes on a live context.
    std::shared_ptr<detail::MotionContext> context;

    NodeId system, device, controllerNode, safety, worldToBase;
    std::array<NodeId, kinematics::kAxes> position{}, speed{}, acceleration{};
    NodeId emergencyStop, protectiveStop, inControl, streamTarget, setTool, clearTool;
    NodeId flangePose;  // ActualFlangePose (pnp extension)
    std::unique_ptr<skill::server::SkillController> skills;
    std::shared_ptr<detail::PositionStreamSkill> stream;

    // The latest sample (controller's loop thread -> publisher thread).
    struct Latest {
        std::mutex mutex;
        std::optional<rb::State> state;
        std::atomic<bool> closed{false};
    };
    std::shared_ptr<Latest> latest = std::make_shared<Latest>();
    std::mutex wakeMutex;
    std::condition_variable wake;
    bool stopping = false;  // under wakeMutex
    std::thread publisher;

    Impl(ua::server::Server& s, rb::Controller& c, rb::Planner& p, RobotDeviceOptions o)
        : server(s),
          controller(c),
          options(std::move(o)),
          context(std::make_shared<detail::MotionContext>(
              c, p, detail::Timing{options.waitSlice, options.restTimeout})) {}

    ua::UInt16 ns(std::string_view uri) const {
        auto i = server.addressSpace().namespaceIndex(uri);
        if (!i) throw RobotDeviceError("the model " + std::string(uri) + " is not loaded");
        return *i;
    }
    NodeId child(const NodeId& parent, std::initializer_list<QualifiedName> path) const {
        std::vector<QualifiedName> p(path);
        auto n = server.addressSpace().resolvePath(parent, p);
        if (!n) {
            std::string text;
            for (const auto& q : p) text += "/" + q.name;
            throw RobotDeviceError("robot device: " + parent.toString() + " has no " + text);
        }
        return *n;
    }
    void set(const NodeId& node, Variant value) {
        auto st = server.addressSpace().setValue(node, ua::DataValue(std::move(value)));
        if (st.isBad())
            throw RobotDeviceError("robot device: cannot set " + node.toString() + ": " +
                                   st.toString());
    }

    void build();
    void buildAxes(const NodeId& axes, ua::UInt16 rob, ua::UInt16 di);
    void bindWorldToBase(ua::UInt16 skillsRobotics);
    void bindTools(ua::UInt16 skillsRobotics);
    void addSkills();
    void publish();
    void unbind();
    void stop();
};

void RobotDevice::Impl::build() {
    auto& space = server.addressSpace();
    skill::server::loadSkillModels(space, {skill::kBaseUri, skill::kRoboticsUri});
    const ua::UInt16 di = ns(skill::kDiUri);
    const ua::UInt16 rob = ns(skill::kRoboticsCsUri);
    const ua::UInt16 skr = ns(skill::kRoboticsUri);
    const ua::UInt16 own = options.namespaceIndex;
    const std::string& name = options.name;
    if (name.empty()) throw RobotDeviceError("robot device: a name is needed");
    DeviceIdentity id = options.identity;
    if (id.productCode.empty()) id.productCode = id.model;

    ua::server::InstantiateOptions component;
    component.referenceType = NodeId(0, ns0::HasComponent);
    system = space.instantiate(NodeId(di, kDiDeviceSet), NodeId(rob, rid::MotionDeviceSystemType),
                               NodeId(own, name + "System"), QualifiedName(own, name + "System"),
                               component);
    const NodeId motionDevices = child(system, {{rob, "MotionDevices"}});
    const NodeId controllers = child(system, {{rob, "Controllers"}});
    const NodeId safetyStates = child(system, {{rob, "SafetyStates"}});

    // The MotionDevice is the skill controller (SkillMotionDeviceType implements
    // ISkillControllerType); MotionDevices holds it by HasComponent, as the type's placeholder.
    skills = std::make_unique<skill::server::SkillController>(
        server, skill::server::SkillControllerOptions{.name = name,
                                                      .type = skill::types::SkillMotionDeviceType,
                                                      .parent = motionDevices,
                                                      .namespaceIndex = own});
    device = skills->node();
    if (space.deleteReference(motionDevices, NodeId(0, ns0::Organizes), device))
        space.addReference(motionDevices, NodeId(0, ns0::HasComponent), device);

    auto identify = [&](const NodeId& n) {
        set(child(n, {{di, "Manufacturer"}}), text(id.manufacturer));
        set(child(n, {{di, "Model"}}), text(id.model));
        set(child(n, {{di, "SerialNumber"}}), Variant(ua::String(id.serialNumber)));
        set(child(n, {{di, "ProductCode"}}), Variant(ua::String(id.productCode)));
    };
    identify(device);
    set(child(device, {{rob, "MotionDeviceCategory"}}), Variant(rid::ArticulatedRobot));
    const NodeId parameters = child(device, {{di, "ParameterSet"}});
    set(child(parameters, {{rob, "SpeedOverride"}}), Variant(1.0));
    {
        // Optional in MotionDeviceType: whether the controller follows our commands.
        ua::server::VariableAttributes a;
        a.dataType = NodeId(0, ns0::Boolean);
        a.value = ua::DataValue(Variant(false));
        inControl = space.addVariable(parameters, NodeId(own, ua::UInt32{0}),
                                      QualifiedName(rob, "InControl"), a);
    }
    buildAxes(child(device, {{rob, "Axes"}}), rob, di);
    {
        // Not in OPC 40010 (it has no pose of the arm): the flange's pose in the world frame
        // from the actual joints, so that a client can plan its way from where the arm is.
        const std::string base =
            device.idType() == ua::IdType::String ? device.string() : options.name;
        ua::server::VariableAttributes a;
        a.dataType = NodeId(0, ns0::ThreeDFrame);
        a.value = ua::DataValue(Variant(ua::toExtensionObject(ua::ThreeDFrame{})));
        a.value.status = status::UncertainInitialValue;
        a.description = ua::LocalizedText(
            "",
            "The flange's actual pose in the world frame (x, y, z in m; a, b, c in rad about "
            "fixed X, Y, Z), from the actual joint positions and WorldToRobotBase.");
        flangePose = space.addVariable(device, NodeId(own, base + ".ActualFlangePose"),
                                       QualifiedName(skr, "ActualFlangePose"), a);
    }

    controllerNode = space.instantiate(controllers, NodeId(rob, rid::ControllerType),
                                       NodeId(own, name + "Controller"),
                                       QualifiedName(own, name + "Controller"), component);
    identify(controllerNode);
    set(child(controllerNode, {{rob, "CurrentUser"}, {rob, "Level"}}),
        Variant(ua::String("Operator")));
    safety = space.instantiate(safetyStates, NodeId(rob, rid::SafetyStateType),
                               NodeId(own, name + "SafetyState"),
                               QualifiedName(own, name + "SafetyState"), component);
    const NodeId safetyParameters = child(safety, {{di, "ParameterSet"}});
    emergencyStop = child(safetyParameters, {{rob, "EmergencyStop"}});
    protectiveStop = child(safetyParameters, {{rob, "ProtectiveStop"}});
    set(emergencyStop, Variant(false));
    set(protectiveStop, Variant(false));
    set(child(safetyParameters, {{rob, "OperationalMode"}}), Variant(rid::OperationalModeOther));
    space.addReference(controllerNode, NodeId(rob, rid::Controls), device);
    space.addReference(controllerNode, NodeId(rob, rid::HasSafetyStates), safety);

    bindWorldToBase(skr);
    bindTools(skr);
    addSkills();
}

void RobotDevice::Impl::buildAxes(const NodeId& axes, ua::UInt16 rob, ua::UInt16 di) {
    auto& space = server.addressSpace();
    const ua::UInt16 own = options.namespaceIndex;
    ua::server::InstantiateOptions o;
    o.referenceType = NodeId(0, ns0::HasComponent);
    o.optionalChildren = {QualifiedName(rob, "ActualSpeed"),
                          QualifiedName(rob, "ActualAcceleration")};
    const auto rad = unit("C81", "rad", "radian");
    const auto radPerS = unit("2A", "rad/s", "radian per second");
    const auto radPerS2 = unit("2B", "rad/s²", "radian per second squared");
    const std::string base = device.idType() == ua::IdType::String ? device.string() : options.name;
    for (int i = 0; i < kinematics::kAxes; ++i) {
        const std::string axisName = "Axis" + std::to_string(i + 1);
        const NodeId axis = space.instantiate(axes, NodeId(rob, rid::AxisType),
                                              NodeId(own, base + ".Axes." + axisName),
                                              QualifiedName(own, axisName), o);
        set(child(axis, {{rob, "MotionProfile"}}), Variant(rid::Rotary));
        const NodeId p = child(axis, {{di, "ParameterSet"}});
        const auto k = static_cast<std::size_t>(i);
        position[k] = child(p, {{rob, "ActualPosition"}});
        speed[k] = child(p, {{rob, "ActualSpeed"}});
        acceleration[k] = child(p, {{rob, "ActualAcceleration"}});
        const QualifiedName eu(0, "EngineeringUnits");
        set(child(position[k], {eu}), Variant(ua::toExtensionObject(rad)));
        set(child(speed[k], {eu}), Variant(ua::toExtensionObject(radPerS)));
        set(child(acceleration[k], {eu}), Variant(ua::toExtensionObject(radPerS2)));
        set(position[k], Variant(0.0));
        set(speed[k], Variant(0.0));
        set(acceleration[k], Variant(0.0));
    }
}

void RobotDevice::Impl::bindWorldToBase(ua::UInt16 skr) {
    auto& space = server.addressSpace();
    // The model declares WorldToRobotBase read-only (no AccessLevel): the instance's copy
    // is replaced by a writable variable of the same id and BrowseName.
    const NodeId declared = child(device, {{skr, "WorldToRobotBase"}});
    space.deleteNode(declared);
    ua::server::VariableAttributes a;
    a.dataType = NodeId(0, ns0::ThreeDFrame);
    a.accessLevel = ua::server::access_level::CurrentRead | ua::server::access_level::CurrentWrite;
    a.value =
        ua::DataValue(Variant(ua::toExtensionObject(ua::spatial::toFrame(context->worldToBase()))));
    a.description = ua::LocalizedText(
        "",
        "The robot base in the world frame (x, y, z in m; a, b, c in rad about fixed X, Y, "
        "Z). Move targets are world poses.");
    worldToBase = space.addVariable(device, declared, QualifiedName(skr, "WorldToRobotBase"), a);
    // Checked, stored, and applied by the planner before its next plan (no wait here).
    std::weak_ptr<detail::MotionContext> weak = context;
    space.setValueCallback(worldToBase,
                           {.read = {}, .write = [weak](const NodeId&, const ua::DataValue& dv) {
                                auto ctx = weak.lock();
                                if (!ctx) return ua::StatusCode(status::BadInvalidState);
                                if (!dv.value) return ua::StatusCode(status::BadTypeMismatch);
                                const auto* x = dv.value->scalar<ua::ExtensionObject>();
                                if (x == nullptr) return ua::StatusCode(status::BadTypeMismatch);
                                std::optional<ua::ThreeDFrame> f;
                                try {
                                    f = ua::fromExtensionObject<ua::ThreeDFrame>(*x);
                                } catch (const ua::DecodeError&) {
                                    return ua::StatusCode(status::BadDecodingError);
                                }
                                if (!f) return ua::StatusCode(status::BadTypeMismatch);
                                if (!ua::spatial::finite(*f))
                                    return ua::StatusCode(status::BadOutOfRange);
                                ctx->setWorldToBase(ua::spatial::toIsometry(*f));
                                return ua::StatusCode{};
                            }});
}

void RobotDevice::Impl::bindTools(ua::UInt16 skr) {
    auto& space = server.addressSpace();
    std::weak_ptr<detail::MotionContext> weak = context;
    // Optional in SkillMotionDeviceType, so not instantiated: added with the model's
    // arguments. Both are quick and run on the network thread.
    const std::string base = device.idType() == ua::IdType::String ? device.string() : options.name;
    const ua::Argument nameArg{
        "Name", NodeId(0, ns0::String), -1, {}, ua::LocalizedText("", "Tool frame name.")};
    const ua::Argument frameArg{"Frame",
                                NodeId(0, ns0::ThreeDFrame),
                                -1,
                                {},
                                ua::LocalizedText("", "Flange to tool frame.")};
    // SetTool(Name, Frame): registers and activates; Frame null = activate a registered Name.
    setTool = space.addMethod(
        device, NodeId(options.namespaceIndex, base + ".SetTool"), QualifiedName(skr, "SetTool"),
        {nameArg, frameArg}, {},
        ua::server::makeMethodHandler([weak](const ua::server::MethodCallContext&,
                                             std::vector<Variant>& in, std::vector<Variant>&) {
            auto ctx = weak.lock();
            if (!ctx) return ua::StatusCode(status::BadInvalidState);
            if (in.size() != 2) return ua::StatusCode(status::BadArgumentsMissing);
            const auto* name = in[0].scalar<ua::String>();
            if (name == nullptr) return ua::StatusCode(status::BadInvalidArgument);
            std::optional<Eigen::Isometry3d> frame;
            if (!in[1].isEmpty()) {
                const auto* x = in[1].scalar<ua::ExtensionObject>();
                if (x == nullptr) return ua::StatusCode(status::BadInvalidArgument);
                try {
                    auto f = ua::fromExtensionObject<ua::ThreeDFrame>(*x);
                    if (!f || !ua::spatial::finite(*f))
                        return ua::StatusCode(status::BadInvalidArgument);
                    frame = ua::spatial::toIsometry(*f);
                } catch (const ua::DecodeError&) {
                    return ua::StatusCode(status::BadInvalidArgument);
                }
            }
            return ctx->setTool(*name, frame);
        }));
    clearTool = space.addMethod(
        device, NodeId(options.namespaceIndex, base + ".ClearTool"),
        QualifiedName(skr, "ClearTool"), {nameArg}, {},
        ua::server::makeMethodHandler([weak](const ua::server::MethodCallContext&,
                                             std::vector<Variant>& in, std::vector<Variant>&) {
            auto ctx = weak.lock();
            if (!ctx) return ua::StatusCode(status::BadInvalidState);
            if (in.size() != 1) return ua::StatusCode(status::BadArgumentsMissing);
            const auto* name = in[0].scalar<ua::String>();
            if (name == nullptr) return ua::StatusCode(status::BadInvalidArgument);
            return ctx->clearTool(*name);
        }));
}

void RobotDevice::Impl::addSkills() {
    using detail::MoveKind;
    namespace n = skill_names;
    detail::MotionContext& c = *context;
    skills->add(n::CartesianPtpMove, detail::makeMoveSkill(MoveKind::CartesianPtp, c));
    skills->add(n::CartesianLinearMove, detail::makeMoveSkill(MoveKind::CartesianLinear, c));
    skills->add(n::JointPtpMove, detail::makeMoveSkill(MoveKind::JointPtp, c));
    skills->add(n::JointLinearMove, detail::makeMoveSkill(MoveKind::JointLinear, c));
    skills->add(n::CartesianLinearForceMove,
                detail::makeMoveSkill(MoveKind::CartesianLinearForce, c));
    stream = std::make_shared<detail::PositionStreamSkill>(c);
    const NodeId node = skills->add(n::PositionStream, stream).node();
    auto& space = server.addressSpace();
    const ua::UInt16 di = ns(skill::kDiUri);
    const ua::UInt16 skr = ns(skill::kRoboticsUri);
    streamTarget = child(node, {{di, "ParameterSet"}, {skr, "TargetJointPosition"}});
    // Writes while Running steer the stream (checked first; a refused one changes nothing).
    std::weak_ptr<detail::PositionStreamSkill> weak = stream;
    space.setValueCallback(streamTarget,
                           {.read = {}, .write = [weak](const NodeId&, const ua::DataValue& dv) {
                                auto s = weak.lock();
                                if (!s) return ua::StatusCode(status::BadInvalidState);
                                return s->offer(dv.value ? *dv.value : Variant());
                            }});
}

// The publisher thread: the latest sample into the Robotics nodes, at most every
// publishPeriod and only when a new one came (one atomic group write).
void RobotDevice::Impl::publish() {
    std::vector<NodeId> nodes;
    for (int i = 0; i < kinematics::kAxes; ++i) {
        const auto k = static_cast<std::size_t>(i);
        nodes.insert(nodes.end(), {position[k], speed[k], acceleration[k]});
    }
    nodes.insert(nodes.end(), {emergencyStop, protectiveStop, inControl, flangePose});
    ua::server::AddressSpace::VariableGroup group(nodes);
    auto& space = server.addressSpace();
    std::uint64_t lastSequence = 0;
    double lastTime = 0.0;
    std::optional<rb::Joints> lastQd;
    bool lastConnected = true;
    for (;;) {
        {
            std::unique_lock l(wakeMutex);
            if (wake.wait_for(l, options.publishPeriod, [&] { return stopping; })) return;
        }
        std::optional<rb::State> s;
        {
            std::lock_guard l(latest->mutex);
            s = latest->state;
        }
        const bool connected = controller.connected();
        if (!s || (s->sequence == lastSequence && connected == lastConnected &&
                   s->controllerTime == lastTime))
            continue;
        // Mean acceleration since the last write (the sample has none of its own).
        rb::Joints qdd{};
        const double dt = s->controllerTime - lastTime;
        if (lastQd && dt > 1e-6 && dt < 1.0)
            for (std::size_t k = 0; k < qdd.size(); ++k) qdd[k] = (s->qd[k] - (*lastQd)[k]) / dt;
        lastQd = s->qd;
        lastTime = s->controllerTime;
        lastSequence = s->sequence;
        lastConnected = connected;
        // Without a link the values are the last ones known.
        auto dv = [&](Variant v) {
            ua::DataValue d(std::move(v));
            if (!connected) d.status = status::UncertainLastUsableValue;
            return d;
        };
        std::vector<std::pair<std::size_t, ua::DataValue>> values;
        values.reserve(nodes.size());
        for (std::size_t k = 0; k < static_cast<std::size_t>(kinematics::kAxes); ++k) {
            values.emplace_back(3 * k, dv(Variant(s->q[k])));
            values.emplace_back(3 * k + 1, dv(Variant(s->qd[k])));
            values.emplace_back(3 * k + 2, dv(Variant(qdd[k])));
        }
        const std::size_t n = 3 * static_cast<std::size_t>(kinematics::kAxes);
        values.emplace_back(n, dv(Variant(s->safety == rb::SafetyState::kEmergencyStop)));
        values.emplace_back(n + 1, dv(Variant(s->safety == rb::SafetyState::kProtectiveStop)));
        values.emplace_back(n + 2, dv(Variant(connected && s->following)));
        const Eigen::Isometry3d flange = context->plan(
            [&](const rb::Planner& p) { return p.toolPose(s->q, Eigen::Isometry3d::Identity()); });
        values.emplace_back(n + 3,
                            dv(Variant(ua::toExtensionObject(ua::spatial::toFrame(flange)))));
        space.setValues(group, std::move(values));
    }
}

// The callbacks this device installed, gone before it is (a failed build() included).
void RobotDevice::Impl::unbind() {
    auto& space = server.addressSpace();
    for (const NodeId& n : {worldToBase, streamTarget})
        if (!n.isNull() && space.contains(n)) space.setValueCallback(n, {});
    for (const NodeId& m : {setTool, clearTool})
        if (!m.isNull() && space.contains(m)) space.setMethodHandler(m, {});
}

void RobotDevice::Impl::stop() {
    latest->closed = true;
    // The controller keeps the callback: make it a no-op that holds nothing of ours.
    controller.onState([](const rb::State&) {});
    {
        std::lock_guard l(wakeMutex);
        stopping = true;
    }
    wake.notify_all();
    if (publisher.joinable()) publisher.join();
    unbind();
    // Halts running skills (each brakes and waits until the arm is at rest) and joins them.
    skills.reset();
}

RobotDevice::RobotDevice(ua::server::Server& server, rb::Controller& controller,
                         rb::Planner& planner, RobotDeviceOptions options)
    : impl_(std::make_unique<Impl>(server, controller, planner, std::move(options))) {
    try {
        impl_->build();
    } catch (...) {
        impl_->unbind();
        throw;
    }
    // Keep it short on the loop thread: copy and return.
    std::weak_ptr<Impl::Latest> weak = impl_->latest;
    controller.onState([weak](const rb::State& s) {
        auto l = weak.lock();
        if (!l || l->closed) return;
        std::lock_guard g(l->mutex);
        l->state = s;
    });
    impl_->publisher = std::thread([impl = impl_.get()] { impl->publish(); });
}

RobotDevice::~RobotDevice() { impl_->stop(); }

const NodeId& RobotDevice::systemNode() const { return impl_->system; }
const NodeId& RobotDevice::motionDeviceNode() const { return impl_->device; }
const NodeId& RobotDevice::controllerNode() const { return impl_->controllerNode; }
const NodeId& RobotDevice::safetyStateNode() const { return impl_->safety; }
const NodeId& RobotDevice::actualPositionNode(int axis) const {
    return impl_->position.at(static_cast<std::size_t>(axis));
}

NodeId RobotDevice::skillNode(const std::string& name) const {
    auto n = impl_->server.addressSpace().resolvePath(
        impl_->skills->skillsFolder(),
        std::vector<QualifiedName>{QualifiedName(impl_->options.namespaceIndex, name)});
    return n ? *n : NodeId();
}

std::vector<skill::server::SkillHandle> RobotDevice::skills() const {
    return impl_->skills->skills();
}

Eigen::Isometry3d RobotDevice::worldToBase() const { return impl_->context->worldToBase(); }
std::string RobotDevice::activeTool() const { return impl_->context->activeTool(); }

}  // namespace pnp::device::robot
