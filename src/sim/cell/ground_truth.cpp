#include "sim/cell/ground_truth.hpp"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <thread>

#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"

namespace pnp::sim::cell {

namespace {

using ua::NodeId;
using ua::QualifiedName;
using ua::Variant;

std::vector<double> toVector(const world::Joints& q) { return {q.begin(), q.end()}; }

Variant frame(const Eigen::Isometry3d& pose) {
    return Variant(ua::toExtensionObject(ua::spatial::toFrame(pose)));
}

Variant vector3(const Eigen::Vector3d& v) {
    return Variant(ua::toExtensionObject(ua::spatial::toThreeDVector(v)));
}

Variant text(const std::string& s) { return Variant(ua::String(s)); }

Variant changer(world::ChangerLock lock) {
    switch (lock) {
        case world::ChangerLock::kOpen:
            return Variant(ua::String("Open"));
        case world::ChangerLock::kIntermediate:
            return Variant(ua::String("Intermediate"));
        case world::ChangerLock::kLocked:
            return Variant(ua::String("Locked"));
    }
    return Variant(ua::String(""));
}

}  // namespace

struct GroundTruth::Impl {
    ua::server::Server& server;
    Simulator& simulator;
    GroundTruthOptions options;
    ua::UInt16 ns = 0;

    std::mutex mutex;
    std::condition_variable wake;
    bool running = false;
    std::thread thread;

    // The last value written per node: a value is written only when it changed, so that
    // subscribers see changes, not the update rate.
    std::map<NodeId, Variant> last;

    Impl(ua::server::Server& s, Simulator& sim, GroundTruthOptions o)
        : server(s), simulator(sim), options(o) {}

    NodeId id(const std::string& path) const { return NodeId(ns, path); }

    NodeId variable(const NodeId& parent, const std::string& path, const std::string& name,
                    ua::UInt32 dataType, ua::Int32 valueRank, Variant initial) {
        ua::server::VariableAttributes a;
        a.dataType = NodeId(0, dataType);
        a.valueRank = valueRank;
        if (valueRank == 1) a.arrayDimensions = {0};
        a.value = ua::DataValue(std::move(initial));
        a.accessLevel = ua::server::access_level::CurrentRead;  // ground truth is read-only
        return server.addressSpace().addVariable(parent, id(path), QualifiedName{ns, name}, a);
    }

    void build() {
        auto& space = server.addressSpace();
        ns = space.addNamespace(kWorldNamespaceUri);
        const auto snap = simulator.snapshot();
        const auto& cell = simulator.description();
        const NodeId root = space.addObject(NodeId(0, ua::ns0::ObjectsFolder), id("World"),
                                            QualifiedName{ns, "World"});
        variable(root, "World.Time", "Time", ua::ns0::Double, -1, Variant(0.0));
        variable(root, "World.Step", "Step", ua::ns0::UInt64, -1, Variant(ua::UInt64{0}));
        variable(root, "World.CellName", "CellName", ua::ns0::String, -1,
                 Variant(ua::String(cell.name)));

        const NodeId robots = space.addFolder(root, id("Robots"), QualifiedName{ns, "Robots"});
        for (const auto& r : snap->robots) {
            const std::string p = "Robots." + r.name;
            const NodeId o = space.addObject(robots, id(p), QualifiedName{ns, r.name});
            variable(o, p + ".Joints", "Joints", ua::ns0::Double, 1, Variant(toVector(r.q)));
            variable(o, p + ".JointVelocities", "JointVelocities", ua::ns0::Double, 1,
                     Variant(toVector(r.qd)));
            variable(o, p + ".FlangePose", "FlangePose", ua::ns0::ThreeDFrame, -1, frame(r.flange));
            variable(o, p + ".TcpPose", "TcpPose", ua::ns0::ThreeDFrame, -1, frame(r.tcp));
            variable(o, p + ".TcpForce", "TcpForce", ua::ns0::ThreeDVector, -1,
                     vector3(r.tcpForce));
            variable(o, p + ".Tool", "Tool", ua::ns0::String, -1,
                     Variant(ua::String(r.tool.value_or(""))));
            variable(o, p + ".Changer", "Changer", ua::ns0::String, -1, changer(r.changer));
            variable(o, p + ".ChangerVoltage", "ChangerVoltage", ua::ns0::Double, -1,
                     Variant(r.changerVoltage));
            variable(o, p + ".Dock", "Dock", ua::ns0::String, -1,
                     Variant(ua::String(r.dock.value_or(""))));
            if (const auto* d = cell.findRobot(r.name)) {
                variable(o, p + ".Model", "Model", ua::ns0::String, -1, text(d->modelName));
                variable(o, p + ".Base", "Base", ua::ns0::ThreeDFrame, -1, frame(d->base));
            }
        }
        const NodeId tables = space.addFolder(root, id("Tables"), QualifiedName{ns, "Tables"});
        for (const auto& t : cell.tables) {
            const std::string p = "Tables." + t.name;
            const NodeId o = space.addObject(tables, id(p), QualifiedName{ns, t.name});
            variable(o, p + ".Pose", "Pose", ua::ns0::ThreeDFrame, -1, frame(t.pose));
            variable(o, p + ".Size", "Size", ua::ns0::ThreeDVector, -1, vector3(t.size));
        }
        const NodeId docks = space.addFolder(root, id("Docks"), QualifiedName{ns, "Docks"});
        for (const auto& d : cell.docks) {
            const std::string p = "Docks." + d.name;
            const NodeId o = space.addObject(docks, id(p), QualifiedName{ns, d.name});
            variable(o, p + ".Pose", "Pose", ua::ns0::ThreeDFrame, -1, frame(d.pose));
        }
        const NodeId objects = space.addFolder(root, id("Objects"), QualifiedName{ns, "Objects"});
        for (const auto& x : snap->objects) {
            const std::string p = "Objects." + x.name;
            const NodeId o = space.addObject(objects, id(p), QualifiedName{ns, x.name});
            variable(o, p + ".Pose", "Pose", ua::ns0::ThreeDFrame, -1, frame(x.pose));
            variable(o, p + ".Holder", "Holder", ua::ns0::String, -1,
                     Variant(ua::String(x.holder)));
            if (const auto* d = cell.findObject(x.name)) {
                variable(o, p + ".Size", "Size", ua::ns0::ThreeDVector, -1, vector3(d->size));
                if (!d->color.empty())
                    variable(o, p + ".Color", "Color", ua::ns0::String, -1, text(d->color));
            }
        }
        const NodeId tools = space.addFolder(root, id("Tools"), QualifiedName{ns, "Tools"});
        for (const auto& t : snap->tools) {
            const std::string p = "Tools." + t.name;
            const NodeId o = space.addObject(tools, id(p), QualifiedName{ns, t.name});
            variable(o, p + ".Dock", "Dock", ua::ns0::String, -1,
                     Variant(ua::String(t.dock.value_or(""))));
            variable(o, p + ".Robot", "Robot", ua::ns0::String, -1,
                     Variant(ua::String(t.robot.value_or(""))));
            variable(o, p + ".Powered", "Powered", ua::ns0::Boolean, -1, Variant(t.powered));
            variable(o, p + ".Held", "Held", ua::ns0::String, -1,
                     Variant(ua::String(t.held.value_or(""))));
            if (const auto* d = cell.findTool(t.name))
                variable(o, p + ".Tcp", "Tcp", ua::ns0::ThreeDFrame, -1, frame(d->tcp));
        }
        addOperatorMethods(root);
    }

    // The operator's hands: each call runs on the simulator's stepping thread (the world is
    // that thread's) and completes from there, never blocking the network thread.
    void operatorMethod(const NodeId& parent, const std::string& name,
                        std::vector<ua::Argument> inputs,
                        std::function<std::string(world::World&, std::vector<Variant>&)> act) {
        ua::Argument error;
        error.name = "Error";
        error.dataType = NodeId(0, ua::ns0::String);
        error.valueRank = -1;
        error.description = ua::LocalizedText("", "why it was not done; empty: done");
        Simulator* sim = &simulator;
        server.addressSpace().addMethod(
            parent, id("World." + name), QualifiedName{ns, name}, inputs, {error},
            [sim, act](const ua::server::MethodCallContext&, std::vector<Variant> in,
                       ua::server::MethodCompletion done) {
                sim->post([act, in = std::move(in), done](world::World& w) mutable {
                    done.succeed({Variant(ua::String(act(w, in)))});
                });
            });
    }

    static ua::Argument stringArgument(const std::string& name, const std::string& what) {
        ua::Argument a;
        a.name = name;
        a.dataType = NodeId(0, ua::ns0::String);
        a.valueRank = -1;
        a.description = ua::LocalizedText("", what);
        return a;
    }

    static std::string textOf(const Variant& v) {
        const auto* s = v.scalar<ua::String>();
        return s != nullptr ? std::string(*s) : std::string();
    }

    void addOperatorMethods(const NodeId& root) {
        operatorMethod(root, "PutToolInDock",
                       {stringArgument("Tool", "a tool of the cell (on the shelf or in a dock)"),
                        stringArgument("Dock", "an empty dock")},
                       [](world::World& w, std::vector<Variant>& in) {
                           return w.putToolInDock(textOf(in[0]), textOf(in[1]));
                       });
        operatorMethod(
            root, "TakeToolOut", {stringArgument("Tool", "a tool in a dock; it goes to the shelf")},
            [](world::World& w, std::vector<Variant>& in) { return w.takeToolOut(textOf(in[0])); });
        operatorMethod(root, "AttachToolByHand",
                       {stringArgument("Robot", "a robot whose changer is open and empty"),
                        stringArgument("Tool", "a tool in a dock or on the shelf")},
                       [](world::World& w, std::vector<Variant>& in) {
                           return w.attachToolByHand(textOf(in[0]), textOf(in[1]));
                       });
        operatorMethod(root, "DetachToolByHand",
                       {stringArgument("Robot", "a robot with a tool; the tool goes to the shelf")},
                       [](world::World& w, std::vector<Variant>& in) {
                           return w.detachToolByHand(textOf(in[0]));
                       });
        ua::Argument pose;
        pose.name = "Pose";
        pose.dataType = NodeId(0, ua::ns0::ThreeDFrame);
        pose.valueRank = -1;
        pose.description = ua::LocalizedText("",
                                             "its centre, world frame; it then rests on what "
                                             "is below it");
        operatorMethod(root, "PlaceObject",
                       {stringArgument("Object", "an object of the cell"), pose},
                       [](world::World& w, std::vector<Variant>& in) {
                           const auto* x = in[1].scalar<ua::ExtensionObject>();
                           std::optional<ua::ThreeDFrame> frame;
                           try {
                               if (x != nullptr)
                                   frame = ua::fromExtensionObject<ua::ThreeDFrame>(*x);
                           } catch (const ua::DecodeError&) {
                               frame.reset();
                           }
                           if (!frame || !ua::spatial::finite(*frame))
                               return std::string("Pose is not a finite ThreeDFrame");
                           return w.placeObject(textOf(in[0]), ua::spatial::toIsometry(*frame));
                       });
        operatorMethod(root, "RemoveObject",
                       {stringArgument("Object", "an object of the cell; it leaves the cell")},
                       [](world::World& w, std::vector<Variant>& in) {
                           return w.removeObject(textOf(in[0]));
                       });
    }

    void set(const std::string& path, Variant value) {
        const NodeId node = id(path);
        auto it = last.find(node);
        if (it != last.end() && it->second == value) return;
        server.addressSpace().setValue(node, ua::DataValue(value));
        last.insert_or_assign(node, std::move(value));
    }

    void update(const world::Snapshot& s) {
        set("World.Time", Variant(s.time));
        set("World.Step", Variant(ua::UInt64{s.step}));
        for (const auto& r : s.robots) {
            const std::string p = "Robots." + r.name;
            set(p + ".Joints", Variant(toVector(r.q)));
            set(p + ".JointVelocities", Variant(toVector(r.qd)));
            set(p + ".FlangePose", frame(r.flange));
            set(p + ".TcpPose", frame(r.tcp));
            set(p + ".TcpForce", vector3(r.tcpForce));
            set(p + ".Tool", Variant(ua::String(r.tool.value_or(""))));
            set(p + ".Changer", changer(r.changer));
            set(p + ".ChangerVoltage", Variant(r.changerVoltage));
            set(p + ".Dock", Variant(ua::String(r.dock.value_or(""))));
        }
        for (const auto& x : s.objects) {
            const std::string p = "Objects." + x.name;
            set(p + ".Pose", frame(x.pose));
            set(p + ".Holder", Variant(ua::String(x.holder)));
        }
        for (const auto& t : s.tools) {
            const std::string p = "Tools." + t.name;
            set(p + ".Dock", Variant(ua::String(t.dock.value_or(""))));
            set(p + ".Robot", Variant(ua::String(t.robot.value_or(""))));
            set(p + ".Powered", Variant(t.powered));
            set(p + ".Held", Variant(ua::String(t.held.value_or(""))));
        }
    }

    void loop() {
        const auto period = std::chrono::nanoseconds(static_cast<long long>(1e9 / options.rate));
        auto next = std::chrono::steady_clock::now();
        std::uint64_t lastStep = ~std::uint64_t{0};
        std::unique_lock lock(mutex);
        while (running) {
            lock.unlock();
            if (auto s = simulator.snapshot(); s && s->step != lastStep) {
                lastStep = s->step;
                update(*s);
            }
            lock.lock();
            next += period;
            wake.wait_until(lock, next, [this] { return !running; });
        }
    }
};

GroundTruth::GroundTruth(ua::server::Server& server, Simulator& simulator,
                         GroundTruthOptions options)
    : impl_(std::make_unique<Impl>(server, simulator, options)) {
    if (!(options.rate > 0.0 && options.rate <= 1000.0))
        throw std::invalid_argument("ground truth rate must be within (0, 1000] Hz");
    impl_->build();
}

GroundTruth::~GroundTruth() { stop(); }

void GroundTruth::start() {
    std::lock_guard lock(impl_->mutex);
    if (impl_->running) return;
    impl_->running = true;
    impl_->thread = std::thread([this] { impl_->loop(); });
}

void GroundTruth::stop() {
    {
        std::lock_guard lock(impl_->mutex);
        if (!impl_->running) return;
        impl_->running = false;
    }
    impl_->wake.notify_all();
    impl_->thread.join();
}

ua::UInt16 GroundTruth::namespaceIndex() const { return impl_->ns; }

}  // namespace pnp::sim::cell
