#include "ua/server/state_machine.hpp"

#include <algorithm>
#include <mutex>
#include <utility>

#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

namespace {

using Fields = std::vector<std::pair<std::vector<QualifiedName>, Variant>>;

QualifiedName ns0Name(const char* name) { return QualifiedName{0, name}; }

bool isA(const AddressSpace& as, const NodeId& type, UInt32 base) {
    return type == NodeId(0, base) || as.isSubtypeOf(type, NodeId(0, base));
}

// The references of `node` of type `refType` (and its subtypes) in one direction.
std::vector<ReferenceDescription> referencesOf(const AddressSpace& as, const NodeId& node,
                                               UInt32 refType,
                                               BrowseDirection dir = BrowseDirection::Forward) {
    ContinuationPointStore points(1);
    BrowseDescription d;
    d.nodeId = node;
    d.browseDirection = dir;
    d.referenceTypeId = NodeId(0, refType);
    d.includeSubtypes = true;
    d.resultMask = 63;  // everything
    BrowseResult r = as.browse(d, 0, points);
    if (r.statusCode.isBad()) return {};
    return std::move(r.references);
}

NodeId firstTarget(const AddressSpace& as, const NodeId& node, UInt32 refType,
                   BrowseDirection dir = BrowseDirection::Forward) {
    auto refs = referencesOf(as, node, refType, dir);
    return refs.empty() ? NodeId() : refs.front().nodeId.nodeId;
}

NodeId child(const AddressSpace& as, const NodeId& node, std::initializer_list<const char*> path) {
    std::vector<QualifiedName> names;
    for (const char* p : path) names.push_back(ns0Name(p));
    return as.resolvePath(node, names).value_or(NodeId());
}

// A UInt32 Property (StateNumber, TransitionNumber); 0 when absent.
UInt32 numberProperty(const AddressSpace& as, const NodeId& node, const char* name) {
    NodeId p = child(as, node, {name});
    if (p.isNull()) return 0;
    DataValue v = as.readValue(p);
    const UInt32* n = v.value ? v.value->scalar<UInt32>() : nullptr;
    return n ? *n : 0;
}

// Id of a node created below `parent`: "<parent>.<name>" below a string id, else fresh.
NodeId childId(const NodeId& parent, const std::string& name) {
    if (parent.idType() == IdType::String)
        return NodeId(parent.namespaceIndex(), parent.string() + "." + name);
    return NodeId(parent.namespaceIndex(), UInt32{0});
}

}  // namespace

struct FiniteStateMachine::Impl {
    Impl(Server& s, NodeId m, Options o)
        : server(s), as(s.addressSpace()), machine(std::move(m)), options(std::move(o)) {}

    Server& server;
    AddressSpace& as;
    NodeId machine;
    String machineName;
    Options options;
    std::vector<State> states;
    std::vector<Transition> transitions;

    // Children of the instance (null when absent).
    NodeId currentState, currentStateId, currentStateNumber;
    NodeId lastTransition, lastTransitionId, lastTransitionNumber, lastTransitionTime,
        lastTransitionEffective;
    NodeId availableStates, availableTransitions;
    // The ten above, in that order, then the methods' nodes (kMethods + index in `methods`),
    // for writing them as one change (bindInstance()).
    AddressSpace::VariableGroup stateVariables;
    enum StateVariable : std::size_t {
        kCurrentState,
        kCurrentStateId,
        kCurrentStateNumber,
        kLastTransition,
        kLastTransitionId,
        kLastTransitionNumber,
        kLastTransitionTime,
        kLastTransitionEffective,
        kAvailableStates,
        kAvailableTransitions,
        kMethods,
    };

    struct Method {
        QualifiedName name;
        NodeId node;
        std::vector<std::size_t> fromStates;
        MethodHook hook;
        int executable = -1;  // as last written (-1: not yet): unchanged flags are not rewritten
    };
    std::vector<Method> methods;

    mutable std::mutex mutex;
    std::size_t current = 0;
    std::optional<std::size_t> last;
    TransitionObserver observer;

    // What every event of a transition carries, built on its first use (each event copies it
    // instead of building names, texts and the message again).
    struct EventTemplate {
        NodeId eventType;
        LocalizedText message;
        // Transition, FromState, ToState with their Id and Number: shared by the events.
        std::shared_ptr<const Fields> fields;
    };
    std::vector<std::optional<EventTemplate>> eventTemplates;

    const EventTemplate& eventTemplate(std::size_t t) {
        if (eventTemplates.size() != transitions.size()) eventTemplates.resize(transitions.size());
        auto& slot = eventTemplates[t];
        if (slot) return *slot;
        const Transition& tr = transitions[t];
        const State& fs = states[tr.from];
        const State& ts = states[tr.to];
        EventTemplate e;
        e.eventType = !options.eventType.isNull() ? options.eventType
                      : !tr.eventType.isNull()    ? tr.eventType
                                                  : NodeId(0, ns0::TransitionEventType);
        e.message = LocalizedText("", machineName + ": " + fs.displayName.text + " -> " +
                                          ts.displayName.text + " (" + tr.displayName.text + ")");
        Fields fields;
        fields.reserve(9);
        auto add = [&](const char* var, const LocalizedText& text, const NodeId& id, UInt32 n) {
            fields.push_back({{ns0Name(var)}, Variant(text)});
            fields.push_back({{ns0Name(var), ns0Name("Id")}, Variant(id)});
            fields.push_back({{ns0Name(var), ns0Name("Number")}, Variant(n)});
        };
        add("Transition", tr.displayName, tr.node, tr.number);
        add("FromState", fs.displayName, fs.node, fs.number);
        add("ToState", ts.displayName, ts.node, ts.number);
        e.fields = std::make_shared<const Fields>(std::move(fields));
        slot = std::move(e);
        return *slot;
    }

    // ---- setup ----------------------------------------------------------------------------
    [[noreturn]] void fail(const std::string& what) const {
        throw StateMachineError("state machine " + machine.toString() + ": " + what);
    }

    NodeId checkMachine() {
        if (as.nodeClass(machine) != NodeClass::Object) fail("not an Object of this address space");
        const NodeId type = firstTarget(as, machine, ns0::HasTypeDefinition);
        if (type.isNull() || !isA(as, type, ns0::FiniteStateMachineType))
            fail("its type " + type.toString() + " is not a FiniteStateMachineType");
        if (!options.eventType.isNull() && !isA(as, options.eventType, ns0::TransitionEventType))
            fail("Options::eventType " + options.eventType.toString() +
                 " is not a TransitionEventType");
        DataValue name = as.readAttribute(machine, AttributeId::BrowseName);
        if (const auto* q = name.value ? name.value->scalar<QualifiedName>() : nullptr)
            machineName = q->name;
        return type;
    }

    std::optional<std::size_t> stateByNode(const NodeId& node) const {
        for (std::size_t i = 0; i < states.size(); ++i)
            if (states[i].node == node) return i;
        return std::nullopt;
    }
    std::optional<std::size_t> stateByName(std::string_view name) const {
        for (std::size_t i = 0; i < states.size(); ++i)
            if (states[i].browseName.name == name) return i;
        return std::nullopt;
    }

    // The StateType / TransitionType components of the type and its supertypes (the most
    // derived declaration of a BrowseName wins).
    void deriveFromType(const NodeId& type, std::optional<std::size_t>& initial) {
        std::vector<NodeId> chain;
        for (NodeId t = type; !t.isNull() && chain.size() < 32;
             t = firstTarget(as, t, ns0::HasSubtype, BrowseDirection::Inverse)) {
            chain.push_back(t);
            if (t == NodeId(0, ns0::FiniteStateMachineType)) break;
        }
        std::vector<ReferenceDescription> transitionRefs;
        auto seen = [](const auto& list, const QualifiedName& n) {
            return std::any_of(list.begin(), list.end(),
                               [&](const auto& x) { return x.browseName == n; });
        };
        for (const NodeId& t : chain) {
            for (auto& r : referencesOf(as, t, ns0::HasComponent)) {
                if (r.nodeClass != NodeClass::Object || !r.nodeId.isLocal()) continue;
                const NodeId& td = r.typeDefinition.nodeId;
                if (isA(as, td, ns0::StateType)) {
                    if (seen(states, r.browseName)) continue;
                    if (isA(as, td, ns0::InitialStateType)) initial = states.size();
                    states.push_back({r.nodeId.nodeId, r.browseName, r.displayName,
                                      numberProperty(as, r.nodeId.nodeId, "StateNumber")});
                } else if (isA(as, td, ns0::TransitionType)) {
                    if (!seen(transitionRefs, r.browseName)) transitionRefs.push_back(r);
                }
            }
        }
        if (states.empty()) fail("its type " + type.toString() + " defines no states");
        for (const auto& r : transitionRefs) {
            Transition tr;
            tr.node = r.nodeId.nodeId;
            tr.browseName = r.browseName;
            tr.displayName = r.displayName;
            tr.number = numberProperty(as, tr.node, "TransitionNumber");
            tr.from = endpoint(tr, ns0::FromState);
            tr.to = endpoint(tr, ns0::ToState);
            for (const auto& c : referencesOf(as, tr.node, ns0::HasCause))
                if (c.nodeClass == NodeClass::Method) tr.causes.push_back(c.browseName);
            for (const auto& e : referencesOf(as, tr.node, ns0::HasEffect))
                if (e.nodeId.isLocal() && isA(as, e.nodeId.nodeId, ns0::TransitionEventType)) {
                    tr.eventType = e.nodeId.nodeId;
                    break;
                }
            transitions.push_back(std::move(tr));
        }
    }

    std::size_t endpoint(const Transition& tr, UInt32 refType) const {
        auto refs = referencesOf(as, tr.node, refType);
        const char* what = refType == ns0::FromState ? "FromState" : "ToState";
        if (refs.size() != 1)
            fail("transition " + tr.browseName.name + " has " + std::to_string(refs.size()) + " " +
                 what + " references (1 expected)");
        if (auto i = stateByNode(refs.front().nodeId.nodeId)) return *i;
        // A subtype may override a state of its supertype: match the BrowseName.
        if (auto i = stateByName(refs.front().browseName.name)) return *i;
        fail("transition " + tr.browseName.name + ": " + what + " " +
             refs.front().nodeId.nodeId.toString() + " is not a state of the machine");
    }

    // Creates the state and transition nodes of an explicit description below the machine.
    void createFromDescription(const StateMachineDescription& d,
                               std::optional<std::size_t>& initial) {
        const UInt16 ns = machine.namespaceIndex();
        if (d.states.empty()) fail("the description has no states");
        for (const auto& s : d.states) {
            if (s.name.empty()) fail("a state without a name");
            if (stateByName(s.name)) fail("state " + s.name + " is described twice");
            if (s.initial) {
                if (initial) fail("more than one initial state");
                initial = states.size();
            }
            ObjectAttributes a;
            a.displayName = s.displayName.text.empty() ? LocalizedText("", s.name) : s.displayName;
            NodeId node =
                as.addObject(machine, childId(machine, s.name), QualifiedName{ns, s.name}, a,
                             NodeId(0, s.initial ? ns0::InitialStateType : ns0::StateType),
                             NodeId(0, ns0::HasComponent));
            setNumber(node, "StateNumber", s.number);
            states.push_back({node, QualifiedName{ns, s.name}, a.displayName, s.number});
        }
        for (const auto& t : d.transitions) {
            if (t.name.empty()) fail("a transition without a name");
            auto from = stateByName(t.from), to = stateByName(t.to);
            if (!from) fail("transition " + t.name + ": unknown FromState " + t.from);
            if (!to) fail("transition " + t.name + ": unknown ToState " + t.to);
            for (const auto& o : transitions)
                if (o.browseName.name == t.name)
                    fail("transition " + t.name + " is described twice");
            if (!t.eventType.isNull() && !isA(as, t.eventType, ns0::TransitionEventType))
                fail("transition " + t.name + ": " + t.eventType.toString() +
                     " is not a TransitionEventType");
            ObjectAttributes a;
            a.displayName = t.displayName.text.empty() ? LocalizedText("", t.name) : t.displayName;
            NodeId node =
                as.addObject(machine, childId(machine, t.name), QualifiedName{ns, t.name}, a,
                             NodeId(0, ns0::TransitionType), NodeId(0, ns0::HasComponent));
            setNumber(node, "TransitionNumber", t.number);
            as.addReference(node, NodeId(0, ns0::FromState), states[*from].node);
            as.addReference(node, NodeId(0, ns0::ToState), states[*to].node);
            if (!t.eventType.isNull())
                as.addReference(node, NodeId(0, ns0::HasEffect), t.eventType);
            Transition tr{
                node,       QualifiedName{ns, t.name}, a.displayName, t.number, *from, *to, {},
                t.eventType};
            for (const auto& c : t.causes) tr.causes.push_back(QualifiedName{ns, c});
            transitions.push_back(std::move(tr));
        }
    }

    void setNumber(const NodeId& node, const char* name, UInt32 number) {
        NodeId p = child(as, node, {name});
        if (p.isNull()) {
            VariableAttributes a;
            a.dataType = NodeId(0, ns0::UInt32);
            a.value = DataValue(Variant(number));
            as.addProperty(node, childId(node, name), ns0Name(name), a);
        } else if (StatusCode st = as.setValue(p, DataValue(Variant(number))); st.isBad()) {
            fail(std::string("cannot set ") + name + ": " + st.toString());
        }
    }

    // The instance's Variables and methods.
    void bindInstance(bool linkCauses) {
        currentState = child(as, machine, {"CurrentState"});
        if (currentState.isNull()) fail("it has no CurrentState");
        currentStateId = child(as, currentState, {"Id"});
        currentStateNumber = child(as, currentState, {"Number"});
        lastTransition = child(as, machine, {"LastTransition"});
        if (!lastTransition.isNull()) {
            lastTransitionId = child(as, lastTransition, {"Id"});
            lastTransitionNumber = child(as, lastTransition, {"Number"});
            lastTransitionTime = child(as, lastTransition, {"TransitionTime"});
            lastTransitionEffective = child(as, lastTransition, {"EffectiveTransitionTime"});
        }
        availableStates = child(as, machine, {"AvailableStates"});
        availableTransitions = child(as, machine, {"AvailableTransitions"});
        for (std::size_t t = 0; t < transitions.size(); ++t) {
            for (const QualifiedName& cause : transitions[t].causes) {
                auto m = std::find_if(methods.begin(), methods.end(),
                                      [&](const Method& x) { return x.name == cause; });
                if (m == methods.end())
                    m = methods.insert(methods.end(), Method{cause, {}, {}, {}});
                if (std::find(m->fromStates.begin(), m->fromStates.end(), transitions[t].from) ==
                    m->fromStates.end())
                    m->fromStates.push_back(transitions[t].from);
            }
        }
        for (Method& m : methods) {
            auto found = as.resolvePath(machine, std::vector<QualifiedName>{m.name});
            if (found) {
                if (as.nodeClass(*found) != NodeClass::Method)
                    fail("its component " + m.name.name + " is not a Method");
                m.node = *found;
            } else if (options.createMethods) {
                MethodAttributes a;
                a.displayName = LocalizedText("", m.name.name);
                m.node =
                    as.addMethod(machine, childId(machine, m.name.name), m.name, {}, {}, {}, a);
            } else {
                continue;  // not callable on this instance
            }
            if (linkCauses)
                for (const Transition& tr : transitions)
                    if (std::find(tr.causes.begin(), tr.causes.end(), m.name) != tr.causes.end())
                        as.addReference(tr.node, NodeId(0, ns0::HasCause), m.node);
        }
        std::vector<NodeId> group{
            currentState,     currentStateId,       currentStateNumber, lastTransition,
            lastTransitionId, lastTransitionNumber, lastTransitionTime, lastTransitionEffective,
            availableStates,  availableTransitions};
        for (const Method& m : methods) group.push_back(m.node);
        stateVariables = AddressSpace::VariableGroup(std::move(group));
    }

    // ---- run time (mutex held) ------------------------------------------------------------

    // Writes the current state (and, after a transition, the last transition) into the
    // address space.
    void publish(const DateTime& now) {
        // One change of the address space: a Read never sees the new state with the old
        // last transition, and a client that reads the new CurrentState and calls a method
        // at once finds it executable (the handlers check the machine's own state, which
        // changed before any of this).
        std::vector<std::pair<std::size_t, bool>> executable;
        if (options.trackExecutable)
            for (std::size_t k = 0; k < methods.size(); ++k) {
                Method& m = methods[k];
                if (m.node.isNull()) continue;
                const bool on = std::find(m.fromStates.begin(), m.fromStates.end(), current) !=
                                m.fromStates.end();
                if (m.executable == static_cast<int>(on)) continue;
                executable.emplace_back(kMethods + k, on);
                m.executable = on;
            }
        std::vector<std::pair<std::size_t, DataValue>> values;
        values.reserve(10);
        auto set = [&](std::size_t k, Variant v) {
            if (!stateVariables.variables()[k].isNull())
                values.emplace_back(k, DataValue(std::move(v)));
        };
        const State& s = states[current];
        set(kCurrentStateId, Variant(s.node));
        set(kCurrentStateNumber, Variant(s.number));
        set(kCurrentState, Variant(s.displayName));
        if (last) {
            const Transition& tr = transitions[*last];
            set(kLastTransitionId, Variant(tr.node));
            set(kLastTransitionNumber, Variant(tr.number));
            set(kLastTransitionTime, Variant(now));
            set(kLastTransitionEffective, Variant(now));
            set(kLastTransition, Variant(tr.displayName));
        }
        std::vector<NodeId> toStates, possible;
        for (const Transition& tr : transitions) {
            if (tr.from != current) continue;
            possible.push_back(tr.node);
            if (std::find(toStates.begin(), toStates.end(), states[tr.to].node) == toStates.end())
                toStates.push_back(states[tr.to].node);
        }
        set(kAvailableStates, Variant(std::move(toStates)));
        set(kAvailableTransitions, Variant(std::move(possible)));
        as.setValues(stateVariables, std::move(values), executable);
    }

    // The transition named `name` (byCause: caused by method `name`) from the current state.
    // When several transitions from the state have the same cause, the one with the fewest
    // causes wins (namespace 0 lists Reset as a cause of both SuspendedToReady and
    // SuspendedToHalted; Part 10 means the former), then the first declared.
    std::optional<std::size_t> transitionFromCurrent(std::string_view name, bool byCause) const {
        std::optional<std::size_t> best;
        for (std::size_t t = 0; t < transitions.size(); ++t) {
            const Transition& tr = transitions[t];
            if (tr.from != current) continue;
            if (!byCause && tr.browseName.name == name) return t;
            if (byCause &&
                std::any_of(tr.causes.begin(), tr.causes.end(),
                            [&](const QualifiedName& c) { return c.name == name; }) &&
                (!best || tr.causes.size() < transitions[*best].causes.size()))
                best = t;
        }
        return best;
    }

    // Takes transition t (valid from the current state), releases the lock and tells the
    // observer.
    StatusCode take(std::unique_lock<std::mutex>& lock, std::size_t t, Fields extra) {
        const Transition& tr = transitions[t];
        const std::size_t from = current;
        current = tr.to;
        last = t;
        // In a method handler (under the network lock) no other request is served before it
        // returns: the event, which clients wait for, is written first, and the variables
        // follow before anyone can read them. Elsewhere (a worker thread) the variables come
        // first: a client that has the event may read them at once.
        const DateTime now = DateTime::now();
        const bool eventFirst = server.isNetworkThread();
        if (!eventFirst) publish(now);

        const State& fs = states[from];
        const State& ts = states[tr.to];
        const EventTemplate& tmpl = eventTemplate(t);
        Event e;
        e.time = now;
        e.eventType = tmpl.eventType;
        e.sourceNode = machine;
        e.sourceName = machineName;
        e.severity = options.eventSeverity;
        e.message = tmpl.message;
        e.sharedFields = tmpl.fields;
        e.fields.reserve(extra.size());
        for (auto& f : extra) {
            // Message and Severity given by the caller replace the defaults.
            if (f.first.size() == 1 && f.first[0].namespaceIndex == 0) {
                if (f.first[0].name == "Message") {
                    if (const auto* m = f.second.scalar<LocalizedText>()) e.message = *m;
                    if (const auto* m = f.second.scalar<String>())
                        e.message = LocalizedText("", *m);
                    continue;
                }
                if (f.first[0].name == "Severity") {
                    if (const auto* v = f.second.scalar<UInt16>()) e.severity = *v;
                    continue;
                }
            }
            e.fields.push_back(std::move(f));
        }
        server.fireEvent(std::move(e));
        if (eventFirst) publish(now);

        if (!observer) {
            lock.unlock();
            return status::Good;
        }
        TransitionObserver tell = observer;
        State a = fs, b = ts;
        Transition via = tr;
        lock.unlock();
        tell(a, via, b);
        return status::Good;
    }

    // The handler of cause method m on the instance.
    static MethodHandler handlerFor(const std::weak_ptr<Impl>& weak, std::size_t m) {
        return [weak, m](const MethodCallContext& context, std::vector<Variant> inputs,
                         MethodCompletion done) {
            auto self = weak.lock();
            if (!self) return done.fail(status::BadInvalidState);
            std::unique_lock lock(self->mutex);
            auto t = self->transitionFromCurrent(self->methods[m].name.name, true);
            if (!t) return done.fail(status::BadInvalidState);
            MethodHook hook = self->methods[m].hook;
            if (hook) {
                const std::size_t from = self->current;
                Transition tr = self->transitions[*t];
                lock.unlock();
                StatusCode st = hook(context, tr, inputs);
                if (st.isBad()) return done.fail(st);
                lock.lock();
                if (self->current != from) return done.fail(status::BadInvalidState);
            }
            StatusCode st = self->take(lock, *t, {});
            done(st);
        };
    }

    void start(std::optional<std::size_t> initial, const NodeId& type,
               const std::weak_ptr<Impl>& weak) {
        if (!options.initialState.empty()) {
            initial = stateByName(options.initialState);
            if (!initial) fail("unknown initial state " + options.initialState);
        } else if (!initial && !type.isNull() && isA(as, type, ns0::ProgramStateMachineType)) {
            initial = stateByName("Ready");
        }
        if (!initial)
            fail("no initial state (no InitialStateType state; set Options::initialState)");
        current = *initial;
        for (std::size_t m = 0; m < methods.size(); ++m)
            if (!methods[m].node.isNull())
                as.setMethodHandler(methods[m].node, handlerFor(weak, m));
        std::lock_guard lock(mutex);
        publish(DateTime::now());
    }
};

// ---- FiniteStateMachine ----------------------------------------------------------------------
FiniteStateMachine::FiniteStateMachine(Server& server, const NodeId& machine, Options options)
    : impl_(std::make_shared<Impl>(server, machine, std::move(options))) {
    try {
        const NodeId type = impl_->checkMachine();
        std::optional<std::size_t> initial;
        impl_->deriveFromType(type, initial);
        impl_->bindInstance(false);
        impl_->start(initial, type, impl_);
    } catch (const AddressSpaceError& e) {
        throw StateMachineError("state machine " + machine.toString() + ": " + e.what());
    }
}

FiniteStateMachine::FiniteStateMachine(Server& server, const NodeId& machine,
                                       const StateMachineDescription& description, Options options)
    : impl_(std::make_shared<Impl>(server, machine, std::move(options))) {
    try {
        impl_->checkMachine();
        std::optional<std::size_t> initial;
        impl_->createFromDescription(description, initial);
        impl_->bindInstance(true);
        impl_->start(initial, NodeId(), impl_);
    } catch (const AddressSpaceError& e) {
        throw StateMachineError("state machine " + machine.toString() + ": " + e.what());
    }
}

FiniteStateMachine::~FiniteStateMachine() = default;  // handlers hold a weak_ptr

const NodeId& FiniteStateMachine::node() const { return impl_->machine; }
const std::vector<FiniteStateMachine::State>& FiniteStateMachine::states() const {
    return impl_->states;
}
const std::vector<FiniteStateMachine::Transition>& FiniteStateMachine::transitions() const {
    return impl_->transitions;
}

FiniteStateMachine::State FiniteStateMachine::currentState() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->states[impl_->current];
}

std::size_t FiniteStateMachine::currentStateIndex() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->current;
}

std::optional<FiniteStateMachine::Transition> FiniteStateMachine::lastTransition() const {
    std::lock_guard lock(impl_->mutex);
    if (!impl_->last) return std::nullopt;
    return impl_->transitions[*impl_->last];
}

NodeId FiniteStateMachine::method(std::string_view name) const {
    for (const auto& m : impl_->methods)
        if (m.name.name == name) return m.node;
    return {};
}

StatusCode FiniteStateMachine::transitionTo(std::string_view to, Fields extraFields) {
    Impl& s = *impl_;
    auto target = s.stateByName(to);
    if (!target) return status::BadNotFound;
    std::unique_lock lock(s.mutex);
    for (std::size_t t = 0; t < s.transitions.size(); ++t)
        if (s.transitions[t].from == s.current && s.transitions[t].to == *target)
            return s.take(lock, t, std::move(extraFields));
    return status::BadInvalidState;
}

StatusCode FiniteStateMachine::fire(std::string_view name, Fields extraFields) {
    Impl& s = *impl_;
    const bool known =
        std::any_of(s.transitions.begin(), s.transitions.end(), [&](const Transition& t) {
            return t.browseName.name == name ||
                   std::any_of(t.causes.begin(), t.causes.end(),
                               [&](const QualifiedName& c) { return c.name == name; });
        });
    if (!known) return status::BadNotFound;
    std::unique_lock lock(s.mutex);
    auto t = s.transitionFromCurrent(name, false);
    if (!t) t = s.transitionFromCurrent(name, true);
    if (!t) return status::BadInvalidState;
    return s.take(lock, *t, std::move(extraFields));
}

StatusCode FiniteStateMachine::onMethod(std::string_view name, MethodHook hook) {
    std::lock_guard lock(impl_->mutex);
    for (auto& m : impl_->methods)
        if (m.name.name == name) {
            m.hook = std::move(hook);
            return status::Good;
        }
    return status::BadNotFound;
}

void FiniteStateMachine::onTransition(TransitionObserver observer) {
    std::lock_guard lock(impl_->mutex);
    impl_->observer = std::move(observer);
}

}  // namespace pnp::ua::server
