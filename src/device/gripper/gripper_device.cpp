// GripperDevice: the skill controller with IGripperType and IVendorNameplateType, the status
// variables, and the gripper skills (each a bounded hardware call on the skill's worker).
#include "device/gripper/gripper_device.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <mutex>
#include <optional>
#include <stop_token>
#include <variant>

#include "skill/model/model.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::device::gripper {

using skill::server::Execution;
using skill::server::Outcome;
using skill::server::Param;
using ua::NodeId;
using ua::QualifiedName;
using ua::Variant;
namespace ns0 = ua::ns0;

namespace {

constexpr ua::UInt32 kDiIVendorNameplateType = 15035;

std::string number(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g", v);
    return buf;
}

// What the skills share: the hardware (serialised) and the device's settings.
struct Context {
    HardwareAccess& access;
    GripperDeviceOptions options;
    GripPoint gripPoint;
};

// A force parameter: finite and not negative (the hardware refuses what it cannot do).
std::optional<std::string> checkForce(double force) {
    if (!std::isfinite(force) || force < 0.0)
        return "Force must be a finite number >= 0 N, got " + number(force);
    return std::nullopt;
}

// Runs one skill's hardware work with the run's cancel flag (set by Halt) and a deadline.
// `what` prefixes failures: "Grasp failed: no object between the fingers".
class HardwareRun {
  public:
    HardwareRun(Execution& run, Context& context, std::string what)
        : context_(context),
          what_(std::move(what)),
          onStop_(run.stopToken(), [this] { cancel_ = true; }) {}

    bool cancelled() const { return cancel_.load(); }

    // Makes the device ready unless its last status says it is.
    std::optional<Outcome> activate() {
        const auto last = context_.access.lastStatus();
        if (last && last->ready) return std::nullopt;
        const auto deadline = Clock::now() + context_.options.activateTimeout;
        auto r = context_.access.with(
            [&](GripperHardware& h) { return h.activate(deadline, cancel_); }, deadline, &cancel_);
        if (!r) return busy();
        if (!r->ok()) return failure(r->error(), "activation: ");
        return std::nullopt;
    }

    // One call returning a Status; an Outcome when it did not succeed.
    template <class Call>
    std::variant<Status, Outcome> call(std::chrono::milliseconds timeout, Call&& fn) {
        if (cancel_) return Outcome::aborted("halted by a client");
        const auto deadline = Clock::now() + timeout;
        auto r = context_.access.with([&](GripperHardware& h) { return fn(h, deadline, cancel_); },
                                      deadline, &cancel_);
        if (!r) return busy();
        if (!r->ok()) return failure(r->error(), "");
        return r->value();
    }

    Outcome failed(const std::string& why) const {
        return Outcome::failed(what_ + " failed: " + why);
    }

  private:
    Outcome busy() {
        if (cancel_) return Outcome::aborted("halted by a client");
        return failed("the gripper stayed busy with another call until the deadline");
    }
    Outcome failure(const Error& e, const std::string& prefix) {
        if (e.kind == ErrorKind::kCancelled || cancel_) {
            // A run halted between two calls: make sure nothing keeps moving.
            if (e.kind != ErrorKind::kCancelled) stopDevice();
            return Outcome::aborted("halted by a client");
        }
        return failed(prefix + e.message);
    }
    void stopDevice() {
        const auto deadline = Clock::now() + context_.options.stopTimeout;
        context_.access.with(
            [&](GripperHardware& h) {
                h.stop(deadline);
                return 0;
            },
            deadline);
    }

    Context& context_;
    std::string what_;
    std::atomic<bool> cancel_{false};
    std::stop_callback<std::function<void()>> onStop_;
};

class GraspSkill : public skill::server::Skill {
  public:
    explicit GraspSkill(Context& c) : Skill(skill::types::GraspGripperSkillType), context_(c) {}
    Outcome execute(Execution& run) override {
        HardwareRun hw(run, context_, "Grasp");
        const double f = run.get(force_);
        if (auto bad = checkForce(f)) return hw.failed(*bad);
        if (auto o = hw.activate()) return *o;
        const GraspRequest request{.width = 0.0, .speed = context_.options.speed, .force = f};
        auto r = hw.call(context_.options.graspTimeout,
                         [&](GripperHardware& h, Deadline d, const std::atomic<bool>& cancel) {
                             return h.grasp(request, d, cancel);
                         });
        if (auto* o = std::get_if<Outcome>(&r)) return *o;
        // Only an object really held is a grasp (never a closed gripper on empty air).
        if (!std::get<Status>(r).holding) return hw.failed("the gripper reports no object held");
        return Outcome::completed();
    }

  private:
    Context& context_;
    Param<double> force_ = optionalParameter<double>("Force", 20.0);
};

class ReleaseSkill : public skill::server::Skill {
  public:
    explicit ReleaseSkill(Context& c) : Skill(skill::types::ReleaseGripperSkillType), context_(c) {}
    Outcome execute(Execution& run) override {
        HardwareRun hw(run, context_, "Release");
        if (auto bad = checkForce(run.get(force_))) return hw.failed(*bad);
        if (auto o = hw.activate()) return *o;
        auto r = hw.call(context_.options.releaseTimeout,
                         [](GripperHardware& h, Deadline d, const std::atomic<bool>& cancel) {
                             return h.release(d, cancel);
                         });
        if (auto* o = std::get_if<Outcome>(&r)) return *o;
        return Outcome::completed();
    }

  private:
    Context& context_;
    Param<double> force_ = optionalParameter<double>("Force", 20.0);
};

class MoveGripperSkill : public skill::server::Skill {
  public:
    explicit MoveGripperSkill(Context& c)
        : Skill(skill::types::MoveGripperSkillType), context_(c) {}
    Outcome execute(Execution& run) override {
        HardwareRun hw(run, context_, "MoveGripper");
        const double width = run.get(width_);
        const double f = run.get(force_);
        const GripPoint& gp = context_.gripPoint;
        constexpr double kTolerance = 1e-9;  // m: a span bound given as text rounds
        if (!std::isfinite(width) || width < gp.spanMin - kTolerance ||
            width > gp.spanMax + kTolerance)
            return hw.failed("Width " + number(width) + " m is outside the gripper's span " +
                             number(gp.spanMin) + " .. " + number(gp.spanMax) + " m");
        if (auto bad = checkForce(f)) return hw.failed(*bad);
        if (auto o = hw.activate()) return *o;
        const MoveRequest request{.width = std::clamp(width, gp.spanMin, gp.spanMax),
                                  .speed = context_.options.speed,
                                  .force = f};
        auto r = hw.call(context_.options.moveTimeout,
                         [&](GripperHardware& h, Deadline d, const std::atomic<bool>& cancel) {
                             return h.move(request, d, cancel);
                         });
        if (auto* o = std::get_if<Outcome>(&r)) return *o;
        run.progress(Variant(std::get<Status>(r).width));
        return Outcome::completed();
    }

  private:
    Context& context_;
    Param<double> width_ = parameter<double>("Width", 0.085);
    Param<double> force_ = parameter<double>("Force", 20.0);
};

Variant text(const std::string& s) { return Variant(ua::LocalizedText("", s)); }

}  // namespace

struct GripperDevice::Impl {
    ua::server::Server& server;
    Context context;
    NodeId device, gripPointNode;
    ua::UInt16 di = 0;
    NodeId manufacturer, model, serialNumber;
    std::map<std::string, NodeId> status;
    std::unique_ptr<skill::server::SkillController> skills;

    // The values published last (the observer writes changes only).
    std::mutex publishedMutex;
    std::optional<Status> published;
    bool closed = false;  // under publishedMutex: the device is going away

    Impl(ua::server::Server& s, HardwareAccess& a, GripperDeviceOptions o)
        : server(s), context{a, std::move(o), a.hardware().gripPoint()} {}

    ua::UInt16 ns(std::string_view uri) const {
        auto i = server.addressSpace().namespaceIndex(uri);
        if (!i) throw GripperDeviceError("the model " + std::string(uri) + " is not loaded");
        return *i;
    }
    NodeId child(const NodeId& parent, std::initializer_list<QualifiedName> path) const {
        std::vector<QualifiedName> p(path);
        auto n = server.addressSpace().resolvePath(parent, p);
        if (!n) {
            std::string names;
            for (const auto& q : p) names += "/" + q.name;
            throw GripperDeviceError("gripper device: " + parent.toString() + " has no " + names);
        }
        return *n;
    }
    void set(const NodeId& node, Variant value) {
        auto st = server.addressSpace().setValue(node, ua::DataValue(std::move(value)));
        if (st.isBad())
            throw GripperDeviceError("gripper device: cannot set " + node.toString() + ": " +
                                     st.toString());
    }
    std::string idOf(const std::string& path) const {
        return (device.idType() == ua::IdType::String ? device.string() : context.options.name) +
               "." + path;
    }

    void build();
    void buildIdentity();
    void buildGripPoint(ua::UInt16 skillsNs);
    void buildStatus();
    void publish(const Status& s);
};

void GripperDevice::Impl::build() {
    auto& space = server.addressSpace();
    skill::server::loadSkillModels(space, {skill::kBaseUri});
    if (context.options.name.empty()) throw GripperDeviceError("gripper device: a name is needed");
    const GripPoint& gp = context.gripPoint;
    if (gp.kind == GripKind::kParallel && !(gp.spanMin >= 0.0 && gp.spanMax > gp.spanMin))
        throw GripperDeviceError("gripper device: a parallel grip point needs 0 <= span min < max");
    if (!gp.offset.matrix().allFinite())
        throw GripperDeviceError("gripper device: the grip point's offset is not finite");
    di = ns(skill::kDiUri);
    const ua::UInt16 skillsNs = ns(skill::kBaseUri);

    skills = std::make_unique<skill::server::SkillController>(
        server,
        skill::server::SkillControllerOptions{.name = context.options.name,
                                              .namespaceIndex = context.options.namespaceIndex});
    device = skills->node();
    space.addReference(device, NodeId(0, ns0::HasInterface),
                       skill::server::resolve(space, skill::types::IGripperType));
    buildIdentity();
    buildGripPoint(skillsNs);
    buildStatus();

    skills->add(skill_names::Grasp, std::make_shared<GraspSkill>(context));
    skills->add(skill_names::Release, std::make_shared<ReleaseSkill>(context));
    if (gp.kind == GripKind::kParallel)
        skills->add(skill_names::MoveGripper, std::make_shared<MoveGripperSkill>(context));
}

// DI IVendorNameplateType: who made the gripper (from the hardware).
void GripperDevice::Impl::buildIdentity() {
    auto& space = server.addressSpace();
    space.addReference(device, NodeId(0, ns0::HasInterface), NodeId(di, kDiIVendorNameplateType));
    auto property = [&](const char* name, ua::UInt32 dataType) {
        ua::server::VariableAttributes a;
        a.dataType = NodeId(0, dataType);
        return space.addProperty(device, NodeId(context.options.namespaceIndex, idOf(name)),
                                 QualifiedName(di, name), a);
    };
    manufacturer = property("Manufacturer", ns0::LocalizedText);
    model = property("Model", ns0::LocalizedText);
    serialNumber = property("SerialNumber", ns0::String);
    const GripperHardware& h = context.access.hardware();
    set(manufacturer, text(h.manufacturer()));
    set(model, text(h.modelName()));
    set(serialNumber, Variant(ua::String(h.serialNumber())));
}

// IGripperType: GripPoints/GripPoint_1 (GripPointType, ParallelGripPointType with Span).
void GripperDevice::Impl::buildGripPoint(ua::UInt16 skillsNs) {
    auto& space = server.addressSpace();
    const GripPoint& gp = context.gripPoint;
    const ua::UInt16 own = context.options.namespaceIndex;
    const NodeId folder = space.addObject(device, NodeId(own, idOf("GripPoints")),
                                          QualifiedName(skillsNs, "GripPoints"), {},
                                          NodeId(0, ns0::FolderType), NodeId(0, ns0::HasComponent));
    const bool parallel = gp.kind == GripKind::kParallel;
    ua::server::InstantiateOptions o;
    o.referenceType = NodeId(0, ns0::HasComponent);
    o.displayName = ua::LocalizedText("", gp.name.empty() ? "GripPoint_1" : gp.name);
    gripPointNode = space.instantiate(
        folder,
        skill::server::resolve(
            space, parallel ? skill::types::ParallelGripPointType : skill::types::GripPointType),
        NodeId(own, idOf("GripPoints.GripPoint_1")), QualifiedName(skillsNs, "GripPoint_1"), o);
    set(child(gripPointNode, {{skillsNs, "Type"}}), Variant(static_cast<ua::Int32>(gp.kind)));
    set(child(gripPointNode, {{skillsNs, "Offset"}}),
        Variant(ua::toExtensionObject(ua::spatial::toFrame(gp.offset))));
    if (parallel)
        set(child(gripPointNode, {{skillsNs, "Span"}}),
            Variant(ua::toExtensionObject(ua::Range{gp.spanMin, gp.spanMax})));
}

// Ready, Holding, Width (m) or Vacuum (mbar), Fault: what the device reported last.
void GripperDevice::Impl::buildStatus() {
    auto& space = server.addressSpace();
    const ua::UInt16 own = context.options.namespaceIndex;
    auto variable = [&](const std::string& name, ua::UInt32 dataType, Variant initial,
                        const char* description) {
        ua::server::VariableAttributes a;
        a.dataType = NodeId(0, dataType);
        a.value = ua::DataValue(std::move(initial));
        a.value.status = ua::status::UncertainInitialValue;
        a.description = ua::LocalizedText("", description);
        status[name] =
            space.addVariable(device, NodeId(own, idOf(name)), QualifiedName(own, name), a);
    };
    variable("Ready", ns0::Boolean, Variant(false),
             "The gripper is activated / homed / operating.");
    variable("Holding", ns0::Boolean, Variant(false), "The gripper reports an object held.");
    if (context.gripPoint.kind == GripKind::kParallel)
        variable("Width", ns0::Double, Variant(0.0), "The jaws' opening, m.");
    else
        variable("Vacuum", ns0::Double, Variant(0.0), "Vacuum below ambient, mbar.");
    variable("Fault", ns0::String, Variant(ua::String()), "The device's fault; empty: none.");
}

void GripperDevice::Impl::publish(const Status& s) {
    std::lock_guard l(publishedMutex);
    if (closed) return;
    auto& space = server.addressSpace();
    const bool first = !published;
    auto put = [&](const char* name, Variant v, bool changed) {
        auto it = status.find(name);
        if (it != status.end() && (first || changed))
            space.setValue(it->second, ua::DataValue(std::move(v)));
    };
    put("Ready", Variant(s.ready), !first && published->ready != s.ready);
    put("Holding", Variant(s.holding), !first && published->holding != s.holding);
    put("Width", Variant(s.width), !first && published->width != s.width);
    put("Vacuum", Variant(s.vacuum), !first && published->vacuum != s.vacuum);
    put("Fault", Variant(ua::String(s.fault)), !first && published->fault != s.fault);
    published = s;
}

GripperDevice::GripperDevice(ua::server::Server& server, HardwareAccess& access,
                             GripperDeviceOptions options)
    : impl_(std::make_shared<Impl>(server, access, std::move(options))) {
    impl_->build();
    // Held weakly: a Status reported while the device goes away is dropped.
    std::weak_ptr<Impl> weak = impl_;
    access.onStatus([weak](const Status& s) {
        if (auto impl = weak.lock()) impl->publish(s);
    });
    if (auto s = access.lastStatus()) impl_->publish(*s);
}

GripperDevice::~GripperDevice() {
    impl_->context.access.onStatus({});
    {
        // Waits for a publish in flight; later ones see `closed`.
        std::lock_guard l(impl_->publishedMutex);
        impl_->closed = true;
    }
    // Halts running skills (their hardware calls see cancel) and joins the workers.
    impl_->skills.reset();
}

const NodeId& GripperDevice::node() const { return impl_->device; }
const NodeId& GripperDevice::gripPoint() const { return impl_->gripPointNode; }

NodeId GripperDevice::skillNode(const std::string& name) const {
    auto n = impl_->server.addressSpace().resolvePath(
        impl_->skills->skillsFolder(),
        std::vector<QualifiedName>{QualifiedName(impl_->context.options.namespaceIndex, name)});
    return n ? *n : NodeId();
}

std::vector<skill::server::SkillHandle> GripperDevice::skills() const {
    return impl_->skills->skills();
}

NodeId GripperDevice::statusNode(const std::string& name) const {
    auto it = impl_->status.find(name);
    return it == impl_->status.end() ? NodeId() : it->second;
}

void GripperDevice::refreshIdentity() {
    const GripperHardware& h = impl_->context.access.hardware();
    auto& space = impl_->server.addressSpace();
    space.setValue(impl_->manufacturer, ua::DataValue(text(h.manufacturer())));
    space.setValue(impl_->model, ua::DataValue(text(h.modelName())));
    space.setValue(impl_->serialNumber, ua::DataValue(Variant(ua::String(h.serialNumber()))));
}

}  // namespace pnp::device::gripper
