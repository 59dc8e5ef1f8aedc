#include "ua/demo/demo.hpp"

#include <algorithm>
#include <array>
#include <atomic>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "ua/server/state_machine.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::demo {

using server::AddressSpace;
using server::MethodCompletion;
using Clock = std::chrono::steady_clock;

// ---- the Sleep worker ------------------------------------------------------------------
// One thread and a timer queue: every pending Sleep call waits here, none on the network
// thread. Completions run on the worker thread, without the lock held.
class SleepWorker {
  public:
    explicit SleepWorker(std::size_t maxPending) : maxPending_(maxPending) {}
    ~SleepWorker() { shutdown(); }
    SleepWorker(const SleepWorker&) = delete;
    SleepWorker& operator=(const SleepWorker&) = delete;

    // Good, or why the call was not queued (the caller completes it then).
    StatusCode schedule(Clock::time_point due, MethodCompletion done) {
        std::lock_guard lock(mutex_);
        if (stopped_) return status::BadShutdown;
        if (queue_.size() >= maxPending_) return status::BadTooManyOperations;
        if (!thread_.joinable()) thread_ = std::thread([this] { run(); });
        queue_.push_back({due, std::move(done)});
        std::push_heap(queue_.begin(), queue_.end(), Later{});
        cv_.notify_one();
        return status::Good;
    }

    // Completes every pending call with BadShutdown and joins the thread. Idempotent.
    void shutdown() {
        std::thread t;
        {
            std::lock_guard lock(mutex_);
            stopped_ = true;
            t = std::move(thread_);
        }
        cv_.notify_one();
        if (t.joinable()) {
            if (t.get_id() == std::this_thread::get_id())
                t.detach();  // the last owner let go inside a completion: run() returns next
            else
                t.join();
        }
        std::vector<Entry> rest;
        {
            std::lock_guard lock(mutex_);
            rest.swap(queue_);
        }
        for (auto& e : rest) e.done.fail(status::BadShutdown);
    }

    std::size_t pending() const {
        std::lock_guard lock(mutex_);
        return queue_.size();
    }

  private:
    struct Entry {
        Clock::time_point due;
        MethodCompletion done;
    };
    struct Later {
        bool operator()(const Entry& a, const Entry& b) const { return a.due > b.due; }
    };

    void run() {
        std::unique_lock lock(mutex_);
        while (!stopped_) {
            if (queue_.empty()) {
                cv_.wait(lock);
                continue;
            }
            Clock::time_point due = queue_.front().due;
            if (Clock::now() < due) {
                cv_.wait_until(lock, due);
                continue;
            }
            std::pop_heap(queue_.begin(), queue_.end(), Later{});
            MethodCompletion done = std::move(queue_.back().done);
            queue_.pop_back();
            lock.unlock();
            done.succeed({});
            lock.lock();
        }
    }

    const std::size_t maxPending_;
    mutable std::mutex mutex_;
    std::condition_variable cv_;
    std::vector<Entry> queue_;  // min-heap by due time
    std::thread thread_;
    bool stopped_ = false;
};

namespace {

constexpr std::array<BuiltinType, 25> kTypes = {
    BuiltinType::Boolean,         BuiltinType::SByte,         BuiltinType::Byte,
    BuiltinType::Int16,           BuiltinType::UInt16,        BuiltinType::Int32,
    BuiltinType::UInt32,          BuiltinType::Int64,         BuiltinType::UInt64,
    BuiltinType::Float,           BuiltinType::Double,        BuiltinType::String,
    BuiltinType::DateTime,        BuiltinType::Guid,          BuiltinType::ByteString,
    BuiltinType::XmlElement,      BuiltinType::NodeId,        BuiltinType::ExpandedNodeId,
    BuiltinType::StatusCode,      BuiltinType::QualifiedName, BuiltinType::LocalizedText,
    BuiltinType::ExtensionObject, BuiltinType::DataValue,     BuiltinType::Variant,
    BuiltinType::DiagnosticInfo,
};

// Calls f(T{}) with a default value of the C++ type that holds built-in type t.
template <class F>
decltype(auto) withType(BuiltinType t, F&& f) {
    switch (t) {
        case BuiltinType::Boolean:
            return f(Boolean{});
        case BuiltinType::SByte:
            return f(SByte{});
        case BuiltinType::Byte:
            return f(Byte{});
        case BuiltinType::Int16:
            return f(Int16{});
        case BuiltinType::UInt16:
            return f(UInt16{});
        case BuiltinType::Int32:
            return f(Int32{});
        case BuiltinType::UInt32:
            return f(UInt32{});
        case BuiltinType::Int64:
            return f(Int64{});
        case BuiltinType::UInt64:
            return f(UInt64{});
        case BuiltinType::Float:
            return f(Float{});
        case BuiltinType::Double:
            return f(Double{});
        case BuiltinType::String:
            return f(String{});
        case BuiltinType::DateTime:
            return f(DateTime{});
        case BuiltinType::Guid:
            return f(Guid{});
        case BuiltinType::ByteString:
            return f(ByteString{});
        case BuiltinType::XmlElement:
            return f(XmlElement{});
        case BuiltinType::NodeId:
            return f(NodeId{});
        case BuiltinType::ExpandedNodeId:
            return f(ExpandedNodeId{});
        case BuiltinType::StatusCode:
            return f(StatusCode{});
        case BuiltinType::QualifiedName:
            return f(QualifiedName{});
        case BuiltinType::LocalizedText:
            return f(LocalizedText{});
        case BuiltinType::ExtensionObject:
            return f(ExtensionObject{});
        case BuiltinType::DataValue:
            return f(DataValue{});
        case BuiltinType::Variant:
            return f(Variant{});
        case BuiltinType::DiagnosticInfo:
            return f(DiagnosticInfo{});
        case BuiltinType::Null:
            break;
    }
    throw server::AddressSpaceError(status::BadInvalidArgument, "no demo variable of type Null");
}

Argument argument(std::string name, UInt32 dataType, std::string description = {}) {
    Argument a;
    a.name = std::move(name);
    a.dataType = NodeId(0, dataType);
    a.valueRank = -1;
    a.description = LocalizedText("", std::move(description));
    return a;
}

void addNodes(AddressSpace& as, UInt16 ns, std::shared_ptr<SleepWorker> worker,
              const DemoOptions& options) {
    server::ObjectAttributes objAttr;
    objAttr.description = LocalizedText("en", "pnp demo: every built-in type, Echo, Add, Sleep");
    objAttr.eventNotifier = 1;  // SubscribeToEvents: the demo's events are fired at it
    const NodeId demo =
        as.addObject(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Demo"), QualifiedName{ns, "Demo"},
                     objAttr, NodeId(0, ns0::BaseObjectType), NodeId(0, ns0::Organizes));

    const Byte rw = server::access_level::CurrentRead | server::access_level::CurrentWrite;
    for (BuiltinType t : kTypes) {
        const std::string type(toString(t));
        for (bool array : {false, true}) {
            const std::string name = (array ? "Array." : "Scalar.") + type;
            server::VariableAttributes a;
            a.description =
                LocalizedText("en", std::string(array ? "array of " : "scalar ") + type);
            a.dataType = demoDataType(t);
            a.valueRank = array ? 1 : -1;
            if (array) a.arrayDimensions = {0};
            a.accessLevel = rw;
            a.value = DataValue(array ? demoInitialArray(t) : demoInitialScalar(t));
            as.addVariable(demo, NodeId(ns, name), QualifiedName{ns, name}, a,
                           NodeId(0, ns0::BaseDataVariableType), NodeId(0, ns0::HasComponent));
        }
    }

    server::MethodAttributes m;
    m.description = LocalizedText("en", "returns its input");
    as.addMethod(
        demo, NodeId(ns, "Demo.Echo"), QualifiedName{ns, "Echo"},
        {argument("Data", ns0::ByteString, "bytes to echo")},
        {argument("Data", ns0::ByteString, "the same bytes")},
        server::makeMethodHandler([](const server::MethodCallContext&, std::vector<Variant>& in,
                                     std::vector<Variant>& out) -> StatusCode {
            if (in.size() != 1) return status::BadArgumentsMissing;
            if (in[0].scalar<ByteString>() == nullptr) return status::BadTypeMismatch;
            out.push_back(std::move(in[0]));  // the input is ours: no copy
            return status::Good;
        }),
        m);

    m.description = LocalizedText("en", "a + b (Int32, wraps around)");
    as.addMethod(demo, NodeId(ns, "Demo.Add"), QualifiedName{ns, "Add"},
                 {argument("a", ns0::Int32), argument("b", ns0::Int32)},
                 {argument("sum", ns0::Int32)},
                 server::makeMethodHandler([](const server::MethodCallContext&,
                                              const std::vector<Variant>& in,
                                              std::vector<Variant>& out) -> StatusCode {
                     if (in.size() != 2) return status::BadArgumentsMissing;
                     const Int32* a = in[0].scalar<Int32>();
                     const Int32* b = in[1].scalar<Int32>();
                     if (a == nullptr || b == nullptr) return status::BadTypeMismatch;
                     // Two's complement wrap-around, like the reference server's (a + b) | 0.
                     auto sum = static_cast<UInt32>(*a) + static_cast<UInt32>(*b);
                     out = {static_cast<Int32>(sum)};
                     return status::Good;
                 }),
                 m);

    m.description =
        LocalizedText("en", "waits, off the network thread, then completes (asynchronous method)");
    const auto maxSleep = options.maxSleep;
    as.addMethod(
        demo, NodeId(ns, "Demo.Sleep"), QualifiedName{ns, "Sleep"},
        {argument("milliseconds", ns0::UInt32, "how long to wait")}, {},
        [worker = std::move(worker), maxSleep](const server::MethodCallContext&,
                                               std::vector<Variant> in, MethodCompletion done) {
            const UInt32* ms = in.size() == 1 ? in[0].scalar<UInt32>() : nullptr;
            if (ms == nullptr)
                return done.fail(in.empty() ? status::BadArgumentsMissing
                                            : status::BadTypeMismatch);
            const std::chrono::milliseconds d(*ms);
            if (d > maxSleep) return done.fail(status::BadOutOfRange);
            StatusCode st = worker->schedule(Clock::now() + d, done);
            if (st.isBad()) done.fail(st);
        },
        m);
}

UInt16 build(AddressSpace& as, const std::shared_ptr<SleepWorker>& worker,
             const DemoOptions& options) {
    const UInt16 ns = as.addNamespace(kNamespaceUri);
    addNodes(as, ns, worker, options);
    return ns;
}

// Fires a DemoEventType event at Demo; Sequence counts the demo's events.
void fireDemoEvent(server::Server& server, UInt16 ns, std::atomic<UInt32>& sequence, String message,
                   UInt16 severity) {
    server::Event e;
    e.eventType = NodeId(ns, "DemoEventType");
    e.sourceNode = NodeId(ns, "Demo");
    e.sourceName = "Demo";
    e.message = LocalizedText("en", std::move(message));
    e.severity = severity;
    e.set(QualifiedName{ns, "Sequence"}, Variant(UInt32{++sequence}));
    server.fireEvent(std::move(e));
}

// The event source and the live value (need the Server).
void addEventNodes(server::Server& server, UInt16 ns,
                   const std::shared_ptr<std::atomic<UInt32>>& sequence) {
    AddressSpace& as = server.addressSpace();
    const NodeId demo(ns, "Demo");
    as.addReference(NodeId(0, ns0::Server), NodeId(0, ns0::HasNotifier), demo);

    const NodeId type = as.addObjectType(NodeId(0, ns0::BaseEventType), NodeId(ns, "DemoEventType"),
                                         QualifiedName{ns, "DemoEventType"});
    server::VariableAttributes seq;
    seq.dataType = NodeId(0, ns0::UInt32);
    seq.value = DataValue(Variant(UInt32{0}));
    seq.description = LocalizedText("en", "counts the demo's events (a custom event field)");
    as.addProperty(type, NodeId(ns, "DemoEventType.Sequence"), QualifiedName{ns, "Sequence"}, seq);

    server::VariableAttributes counter;
    counter.dataType = NodeId(0, ns0::UInt32);
    counter.value = DataValue(Variant(UInt32{0}));
    counter.description = LocalizedText("en", "+1 every 100 ms");
    as.addVariable(demo, NodeId(ns, "Demo.Counter"), QualifiedName{ns, "Counter"}, counter,
                   NodeId(0, ns0::BaseDataVariableType), NodeId(0, ns0::HasComponent));

    server::MethodAttributes m;
    m.description = LocalizedText("en", "fires a DemoEventType event at Demo");
    as.addMethod(
        demo, NodeId(ns, "Demo.FireEvent"), QualifiedName{ns, "FireEvent"},
        {argument("message", ns0::String), argument("severity", ns0::UInt16)}, {},
        server::makeMethodHandler([&server, ns, sequence](const server::MethodCallContext&,
                                                          std::vector<Variant>& in,
                                                          std::vector<Variant>&) -> StatusCode {
            if (in.size() != 2) return status::BadArgumentsMissing;
            const String* text = in[0].scalar<String>();
            const UInt16* severity = in[1].scalar<UInt16>();
            if (text == nullptr || severity == nullptr) return status::BadTypeMismatch;
            if (*severity < 1 || *severity > 1000) return status::BadOutOfRange;
            fireDemoEvent(server, ns, *sequence, *text, *severity);
            return status::Good;
        }),
        m);
}

// Demo.Program: a ProgramStateMachineType instance (OPC 10000-10) whose Start / Suspend /
// Resume / Halt / Reset methods move it between Ready, Running, Suspended and Halted and fire
// a ProgramTransitionEventType event at Demo each time. The state machine belongs to the
// method handlers (so to the address space): each handler holds it and takes the transition
// the method causes.
void addProgram(server::Server& server, UInt16 ns) {
    AddressSpace& as = server.addressSpace();
    const NodeId demo(ns, "Demo");
    server::InstantiateOptions o;
    o.displayName = LocalizedText("en", "Program");
    o.optionalChildren = {QualifiedName{0, "AvailableStates"},
                          QualifiedName{0, "AvailableTransitions"}};
    const NodeId program =
        as.instantiate(demo, NodeId(0, ns0::ProgramStateMachineType), NodeId(ns, "Demo.Program"),
                       QualifiedName{ns, "Program"}, o);
    as.addReference(demo, NodeId(0, ns0::HasEventSource), program);
    // The program's Mandatory properties (OPC 10000-10 §5.2.1): not deletable, not recycled.
    auto set = [&](const char* property, Variant value) {
        if (auto p = as.resolvePath(program, std::vector<QualifiedName>{{0, property}}))
            as.setValue(*p, DataValue(std::move(value)));
    };
    set("Deletable", Variant(false));
    set("AutoDelete", Variant(false));
    set("RecycleCount", Variant(Int32{0}));
    auto machine = std::make_shared<server::FiniteStateMachine>(server, program);
    for (const char* method : {"Start", "Suspend", "Resume", "Halt", "Reset"}) {
        as.setMethodHandler(
            machine->method(method),
            server::makeMethodHandler(
                [machine, method](const server::MethodCallContext&, std::vector<Variant>&,
                                  std::vector<Variant>&) { return machine->fire(method); }));
    }
}

}  // namespace

// Demo.Counter +1 every 100 ms, a "tick" event every second (a live source for `pnp ua
// serve`; one thread, joined by the destructor).
class DemoTicker {
  public:
    DemoTicker(server::Server& server, UInt16 ns, std::shared_ptr<std::atomic<UInt32>> sequence)
        : thread_([this, &server, ns, sequence] { run(server, ns, *sequence); }) {}
    ~DemoTicker() {
        {
            std::lock_guard lock(mutex_);
            stop_ = true;
        }
        wake_.notify_all();
        thread_.join();
    }

  private:
    void run(server::Server& server, UInt16 ns, std::atomic<UInt32>& sequence) {
        const NodeId counter(ns, "Demo.Counter");
        UInt32 ticks = 0;
        std::unique_lock lock(mutex_);
        while (!wake_.wait_for(lock, std::chrono::milliseconds(100), [this] { return stop_; })) {
            lock.unlock();
            server.addressSpace().setValue(counter, DataValue(Variant(++ticks)));
            if (ticks % 10 == 0) fireDemoEvent(server, ns, sequence, "tick", 100);
            lock.lock();
        }
    }

    std::mutex mutex_;
    std::condition_variable wake_;
    bool stop_ = false;
    std::thread thread_;  // last: starts after the members it uses
};

std::span<const BuiltinType> demoTypes() { return kTypes; }

NodeId demoDataType(BuiltinType t) {
    switch (t) {
        case BuiltinType::ExtensionObject:
            return NodeId(0, ns0::Structure);
        case BuiltinType::Variant:
            return NodeId(0, ns0::BaseDataType);
        default:
            return NodeId(0, static_cast<UInt32>(t));
    }
}

Variant demoInitialScalar(BuiltinType t) {
    switch (t) {
        case BuiltinType::ExtensionObject:
            return toExtensionObject(Range{});  // Range{0, 0}
        case BuiltinType::Variant:
            return Int32{0};  // a scalar Variant holds a concrete type
        default:
            return withType(t, [](auto v) { return Variant(std::move(v)); });
    }
}

Variant demoInitialArray(BuiltinType t) {
    return withType(t, [](auto v) {
        Variant out;
        out.setArray(std::vector<decltype(v)>{});
        return out;
    });
}

// ---- DemoNamespace -----------------------------------------------------------------------
DemoNamespace::DemoNamespace(server::Server& server, DemoOptions options)
    : DemoNamespace(server.addressSpace(), options) {
    auto sequence = std::make_shared<std::atomic<UInt32>>(0);
    addEventNodes(server, ns_, sequence);
    addProgram(server, ns_);
    ticker_ = std::make_unique<DemoTicker>(server, ns_, sequence);
}

DemoNamespace::DemoNamespace(AddressSpace& as, DemoOptions options)
    : worker_(std::make_shared<SleepWorker>(options.maxPendingSleeps)) {
    ns_ = build(as, worker_, options);
}

DemoNamespace::~DemoNamespace() {
    ticker_.reset();
    worker_->shutdown();
}

NodeId DemoNamespace::nodeId(std::string_view stringId) const {
    return NodeId(ns_, std::string(stringId));
}

std::size_t DemoNamespace::pendingSleeps() const { return worker_->pending(); }

UInt16 addDemoNamespace(server::Server& server, const DemoOptions& options) {
    UInt16 ns = addDemoNamespace(server.addressSpace(), options);
    addEventNodes(server, ns, std::make_shared<std::atomic<UInt32>>(0));
    addProgram(server, ns);
    return ns;
}

UInt16 addDemoNamespace(AddressSpace& as, const DemoOptions& options) {
    return build(as, std::make_shared<SleepWorker>(options.maxPendingSleeps), options);
}

}  // namespace pnp::ua::demo
