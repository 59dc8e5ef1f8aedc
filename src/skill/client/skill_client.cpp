#include "skill/client/skill_client.hpp"

#include <algorithm>
#include <map>
#include <thread>

#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::skill::client {

using namespace std::chrono_literals;
using ua::client::Clock;
namespace status = ua::status;

// The received transitions with absolute sequence numbers, so that run() and
// takeTransitions() each keep their own cursor. Shared with the event callback, which may
// outlive a call on the client's dispatching thread.
struct SkillClient::Queue {
    static constexpr std::size_t kKeep = 1000;
    std::mutex mutex;
    std::condition_variable_any changed;
    std::deque<Transition> items;
    std::uint64_t first = 0;  // sequence number of items.front()
    std::uint64_t taken = 0;  // cursor of takeTransitions() / nextTransition()
    // The server's time of the end of the last run(): its events that arrive later (held back
    // by the publishing interval after a polled end) are not taken for the next run's.
    ua::DateTime lastRunEnded{};
    bool earlier(const Transition& t) const {
        return t.time != ua::DateTime{} && lastRunEnded != ua::DateTime{} && t.time <= lastRunEnded;
    }
    // Replaced, never changed in place: an event takes the current set without copying it.
    using Callbacks = std::map<std::size_t, TransitionCallback>;
    std::shared_ptr<const Callbacks> callbacks = std::make_shared<const Callbacks>();
    std::size_t nextCallback = 1;

    std::uint64_t end() const { return first + items.size(); }
    void push(Transition t) {
        std::shared_ptr<const Callbacks> cbs;
        {
            std::lock_guard lock(mutex);
            items.push_back(t);
            while (items.size() > kKeep) items.pop_front(), ++first;
            cbs = callbacks;
        }
        changed.notify_all();
        // Outside the lock: a callback may call the client.
        for (const auto& [id, cb] : *cbs) cb(t);
    }
    // With mutex held.
    void changeCallbacks(const std::function<void(Callbacks&)>& change) {
        auto next = std::make_shared<Callbacks>(*callbacks);
        change(*next);
        callbacks = std::move(next);
    }
};

namespace {

Clock::time_point resolve(Deadline d) { return d.resolve(Clock::now(), 10s); }

std::string textOf(const ua::Variant& v) {
    if (const auto* s = v.scalar<ua::String>()) return *s;
    if (const auto* t = v.scalar<ua::LocalizedText>()) return t->text;
    return v.isEmpty() ? std::string() : v.toString();
}

template <class T>
std::optional<T> integerOf(const ua::Variant* v) {
    if (v == nullptr) return std::nullopt;
    if (const auto* x = v->scalar<ua::UInt32>()) return static_cast<T>(*x);
    if (const auto* x = v->scalar<ua::Int32>()) return static_cast<T>(*x);
    if (const auto* x = v->scalar<ua::UInt16>()) return static_cast<T>(*x);
    return std::nullopt;
}

ProgramState stateFromId(const ua::NodeId& id) {
    if (id.namespaceIndex() != 0 || !id.isNumeric()) return ProgramState::Unknown;
    switch (id.numeric()) {
        case ua::ns0::ProgramStateMachineType_Ready:
            return ProgramState::Ready;
        case ua::ns0::ProgramStateMachineType_Running:
            return ProgramState::Running;
        case ua::ns0::ProgramStateMachineType_Suspended:
            return ProgramState::Suspended;
        case ua::ns0::ProgramStateMachineType_Halted:
            return ProgramState::Halted;
        default:
            return ProgramState::Unknown;
    }
}

// The state from a /Number field, else from the /Id field.
ProgramState stateOf(const ua::Variant* number, const ua::Variant* id) {
    if (auto n = integerOf<ua::UInt32>(number)) return programStateFromNumber(*n);
    if (id != nullptr)
        if (const auto* node = id->scalar<ua::NodeId>()) return stateFromId(*node);
    return ProgramState::Unknown;
}

const std::vector<std::string> kEventSelect = {
    "Transition",     "Transition/Number", "FromState/Number",   "FromState/Id",
    "ToState/Number", "ToState/Id",        "IntermediateResult", "Time",
    "Message",        "Severity",          "SourceNode"};

}  // namespace

Transition transitionFromNumber(ua::UInt32 number) {
    static constexpr ProgramState H = ProgramState::Halted, R = ProgramState::Ready,
                                  U = ProgramState::Running, S = ProgramState::Suspended;
    static constexpr std::pair<ProgramState, ProgramState> kByNumber[] = {
        {H, R}, {R, U}, {U, H}, {U, R}, {U, S}, {S, U}, {S, H}, {S, R}, {R, H}};
    Transition t;
    t.number = number;
    if (number < 1 || number > 9) return t;
    t.from = kByNumber[number - 1].first;
    t.to = kByNumber[number - 1].second;
    t.name = std::string(toString(t.from)) + "To" + std::string(toString(t.to));
    return t;
}

namespace {

Transition transitionOf(ua::client::EventFields& e) {
    Transition t;
    if (const auto* v = e.get("Transition")) t.name = textOf(*v);
    t.number = integerOf<ua::UInt32>(e.get("Transition/Number")).value_or(0);
    t.from = stateOf(e.get("FromState/Number"), e.get("FromState/Id"));
    t.to = stateOf(e.get("ToState/Number"), e.get("ToState/Id"));
    // A server that sends only the transition's number: its states are fixed by Part 10.
    if (t.number >= 1 && t.number <= 9) {
        const Transition byNumber = transitionFromNumber(t.number);
        if (t.from == ProgramState::Unknown) t.from = byNumber.from;
        if (t.to == ProgramState::Unknown) t.to = byNumber.to;
        if (t.name.empty()) t.name = byNumber.name;
    }
    if (const auto* v = e.get("IntermediateResult")) t.intermediateResult = *v;
    if (const auto* v = e.get("Time"))
        if (const auto* d = v->scalar<ua::DateTime>()) t.time = *d;
    if (const auto* v = e.get("Message")) t.message = textOf(*v);
    t.severity = integerOf<ua::UInt16>(e.get("Severity")).value_or(0);
    if (const auto* v = e.get("SourceNode"))
        if (const auto* n = v->scalar<ua::NodeId>()) t.source = *n;
    return t;
}

ua::BrowseDescription browseOf(const ua::NodeId& node, ua::UInt32 referenceType,
                               ua::BrowseDirection direction = ua::BrowseDirection::Forward) {
    ua::BrowseDescription d;
    d.nodeId = node;
    d.browseDirection = direction;
    d.referenceTypeId = ua::NodeId(0, referenceType);
    d.includeSubtypes = true;
    d.resultMask = 0x3F;
    return d;
}

ua::ReadValueId readOf(const ua::NodeId& node, ua::UInt32 attribute = 13) {
    ua::ReadValueId r;
    r.nodeId = node;
    r.attributeId = attribute;
    return r;
}

}  // namespace

SkillClient::SkillClient(std::shared_ptr<Client> client, ua::NodeId skill, Deadline deadline,
                         SkillClientOptions options)
    : client_(std::move(client)),
      node_(std::move(skill)),
      options_(std::move(options)),
      lockTime_(options_.lockTime),
      queue_(std::make_shared<Queue>()) {
    if (!client_) throw Error(status::BadInvalidArgument, "SkillClient: no client");
    // Publish responses and event callbacks are dispatched by the background thread.
    if (!client_->backgroundThreadRunning()) client_->startBackgroundThread();
    discover(Deadline(resolve(deadline)));
}

SkillClient::~SkillClient() {
    // The item and subscription are deleted on the server (errors swallowed by their RAII).
    std::lock_guard lock(subscribeMutex_);
    events_ = {};
    subscription_ = {};
}

// Round trips: NamespaceArray (cached by the client), Browse of the skill, one batched Browse
// of its members and the type's supertype, one Browse per further supertype, one Read.
void SkillClient::discover(Deadline deadline) {
    const std::vector<std::string> uris = client_->namespaceArray(deadline);
    auto uriOf = [&](ua::UInt16 ns) { return ns < uris.size() ? uris[ns] : std::string(); };
    auto local = [&](const ua::ExpandedNodeId& x) {
        return x.namespaceUri.empty() ? x.nodeId : client_->toNodeId(x, deadline);
    };
    const std::string what = "skill " + node_.toString();

    auto top = client_->browse({browseOf(node_, ua::ns0::HasTypeDefinition),
                                browseOf(node_, ua::ns0::HierarchicalReferences)},
                               0, deadline);
    for (const auto& r : top)
        if (r.statusCode.isBad()) throw Error(r.statusCode, "browse of " + what);
    if (top[0].references.empty()) throw Error(status::BadTypeMismatch, what + " has no type");
    TypeInfo type;
    type.node = local(top[0].references[0].nodeId);
    type.name = top[0].references[0].browseName.name;

    ua::NodeId parameterSet, lock, finalData, currentState, lastTransition;
    for (const auto& ref : top[1].references) {
        const std::string& n = ref.browseName.name;
        const ua::NodeId id = local(ref.nodeId);
        if (ref.nodeClass == ua::NodeClass::Method) {
            if (n == "Start") start_ = id;
            if (n == "Suspend") suspend_ = id;
            if (n == "Resume") resume_ = id;
            if (n == "Halt") halt_ = id;
            if (n == "Reset") reset_ = id;
        } else if (n == names::ParameterSet) {
            parameterSet = id;
        } else if (n == names::Lock) {
            lock = id;
        } else if (n == names::FinalResultData) {
            finalData = id;
        } else if (n == "CurrentState") {
            currentState = id;
        } else if (n == "LastTransition") {
            lastTransition = id;
        }
    }
    lockNode_ = lock;

    // Members and the first supertype in one request; absent members are browsed as the
    // skill itself (harmless) to keep the indices fixed.
    auto orSelf = [&](const ua::NodeId& id) { return id.isNull() ? node_ : id; };
    auto second =
        client_->browse({browseOf(orSelf(parameterSet), ua::ns0::HierarchicalReferences),
                         browseOf(orSelf(finalData), ua::ns0::HierarchicalReferences),
                         browseOf(orSelf(lock), ua::ns0::HierarchicalReferences),
                         browseOf(orSelf(currentState), ua::ns0::HasProperty),
                         browseOf(type.node, ua::ns0::HasSubtype, ua::BrowseDirection::Inverse),
                         browseOf(orSelf(lastTransition), ua::ns0::HasProperty)},
                        0, deadline);
    if (!parameterSet.isNull())
        for (const auto& ref : second[0].references)
            if (ref.nodeClass == ua::NodeClass::Variable)
                parameters_.push_back({ref.browseName.name, local(ref.nodeId), {}, -1, false});
    if (!finalData.isNull())
        for (const auto& ref : second[1].references) {
            if (ref.nodeClass != ua::NodeClass::Variable) continue;
            const std::string& n = ref.browseName.name;
            if (n == names::Result)
                resultNode_ = local(ref.nodeId);
            else if (n == names::Message)
                messageNode_ = local(ref.nodeId);
            else
                resultValues_.emplace_back(n, local(ref.nodeId));
        }
    if (!lock.isNull())
        for (const auto& ref : second[2].references) {
            const std::string& n = ref.browseName.name;
            const ua::NodeId id = local(ref.nodeId);
            if (n == "InitLock") initLock_ = id;
            if (n == "RenewLock") renewLock_ = id;
            if (n == "ExitLock") exitLock_ = id;
            if (n == "BreakLock") breakLock_ = id;
            if (n == "RemainingLockTime") remainingLockTime_ = id;
        }
    if (!currentState.isNull())
        for (const auto& ref : second[3].references) {
            if (ref.browseName.name == "Number") stateNumber_ = local(ref.nodeId);
            if (ref.browseName.name == "Id") stateId_ = local(ref.nodeId);
        }

    if (!lastTransition.isNull() && second.size() > 5)
        for (const auto& ref : second[5].references) {
            if (ref.browseName.name == "Number") lastTransitionNumber_ = local(ref.nodeId);
            if (ref.browseName.name == "TransitionTime") lastTransitionTime_ = local(ref.nodeId);
        }

    // The supertype chain up to SkillType (usually 1 to 4 levels).
    auto fill = [&](TypeInfo& t) {
        t.uri = uriOf(t.node.namespaceIndex());
        t.id = t.node.isNumeric() ? t.node.numeric() : 0;
    };
    fill(type);
    types_.push_back(type);
    std::vector<ua::ReferenceDescription> supers = second[4].references;
    for (int depth = 0; depth < 32 && !types_.back().is(types::SkillType); ++depth) {
        if (supers.empty() || types_.back().node == ua::NodeId(0, ua::ns0::BaseObjectType))
            throw Error(status::BadTypeMismatch, what + " (" + type.name + ") is not a SkillType");
        TypeInfo super;
        super.node = local(supers[0].nodeId);
        super.name = supers[0].browseName.name;
        fill(super);
        types_.push_back(super);
        if (super.is(types::SkillType)) break;
        supers =
            client_
                ->browse(browseOf(super.node, ua::ns0::HasSubtype, ua::BrowseDirection::Inverse), 0,
                         deadline)
                .references;
    }
    if (!types_.back().is(types::SkillType))
        throw Error(status::BadTypeMismatch, what + " is not a SkillType");

    // The skill's BrowseName and each parameter's DataType, ValueRank, AccessLevel.
    std::vector<ua::ReadValueId> reads{readOf(node_, 3)};
    for (const auto& p : parameters_) {
        reads.push_back(readOf(p.node, 14));
        reads.push_back(readOf(p.node, 15));
        reads.push_back(readOf(p.node, 17));
    }
    auto values = client_->read(std::move(reads), deadline);
    if (values.size() != 1 + 3 * parameters_.size())
        throw Error(status::BadUnexpectedError, "read of " + what + ": wrong result count");
    if (values[0].value)
        if (const auto* q = values[0].value->scalar<ua::QualifiedName>()) browseName_ = q->name;
    for (std::size_t i = 0; i < parameters_.size(); ++i) {
        auto& p = parameters_[i];
        const auto& dt = values[1 + 3 * i].value;
        const auto& vr = values[2 + 3 * i].value;
        const auto& al = values[3 + 3 * i].value;
        if (dt)
            if (const auto* n = dt->scalar<ua::NodeId>()) p.dataType = *n;
        if (vr)
            if (const auto* n = vr->scalar<ua::Int32>()) p.valueRank = *n;
        if (al)
            if (const auto* n = al->scalar<ua::Byte>()) p.writable = (*n & 0x2) != 0;
    }
}

bool SkillClient::isA(const ModelNode& type) const {
    return std::any_of(types_.begin(), types_.end(), [&](const TypeInfo& t) { return t.is(type); });
}

void SkillClient::requireType(const ModelNode& type) const {
    if (!isA(type))
        throw Error(status::BadTypeMismatch, "skill " + browseName_ + " is a " + types_[0].name +
                                                 ", not a " + std::string(type.name));
}

// ---- state and parameters ------------------------------------------------------------------

ProgramState SkillClient::state(Deadline deadline) {
    const ua::NodeId& node = !stateNumber_.isNull() ? stateNumber_ : stateId_;
    if (node.isNull()) throw Error(status::BadNotFound, browseName_ + " has no CurrentState");
    ua::Variant v = client_->readValue(node, deadline);
    return stateNumber_.isNull() ? stateOf(nullptr, &v) : stateOf(&v, nullptr);
}

const ParameterInfo* SkillClient::findParameter(std::string_view name) const {
    for (const auto& p : parameters_)
        if (p.name == name) return &p;
    return nullptr;
}

namespace {
const ParameterInfo& need(const SkillClient& c, std::string_view name) {
    const ParameterInfo* p = c.findParameter(name);
    if (p == nullptr)
        throw Error(status::BadNotFound,
                    "skill " + c.browseName() + " has no parameter " + std::string(name));
    return *p;
}
}  // namespace

ua::Variant SkillClient::parameter(std::string_view name, Deadline deadline) {
    const ParameterInfo& p = need(*this, name);
    auto dv = client_->readAttribute(p.node, ua::AttributeId::Value, deadline);
    if (dv.statusOrGood().isBad()) throw Error(dv.statusOrGood(), "read of parameter " + p.name);
    return dv.value.value_or(ua::Variant());
}

NamedValues SkillClient::parameterValues(Deadline deadline) {
    std::vector<ua::ReadValueId> reads;
    for (const auto& p : parameters_) reads.push_back(readOf(p.node));
    auto values = client_->read(std::move(reads), deadline);
    NamedValues out;
    for (std::size_t i = 0; i < parameters_.size() && i < values.size(); ++i)
        out.emplace_back(parameters_[i].name, values[i].value.value_or(ua::Variant()));
    return out;
}

void SkillClient::setParameter(std::string_view name, ua::Variant value, Deadline deadline) {
    setParameters({{std::string(name), std::move(value)}}, deadline);
}

void SkillClient::setParameters(const NamedValues& values, Deadline deadline) {
    if (values.empty()) return;
    std::vector<ua::WriteValue> writes;
    for (const auto& [name, value] : values) {
        ua::WriteValue w;
        w.nodeId = need(*this, name).node;
        w.attributeId = 13;
        w.value = ua::DataValue(value);
        writes.push_back(std::move(w));
    }
    auto results = client_->write(std::move(writes), deadline);
    for (std::size_t i = 0; i < values.size() && i < results.size(); ++i)
        if (results[i].isBad())
            throw Error(results[i],
                        "write of parameter " + values[i].first + " of skill " + browseName_);
}

// ---- methods -------------------------------------------------------------------------------

ua::client::CallResult SkillClient::callMethod(const ua::NodeId& object, const ua::NodeId& method,
                                               std::vector<ua::Variant> inputs,
                                               std::string_view what, Deadline deadline) {
    if (method.isNull())
        throw Error(status::BadMethodInvalid,
                    "skill " + browseName_ + " has no method " + std::string(what));
    auto r = client_->call(object, method, std::move(inputs), deadline);
    if (r.status.isBad()) throw Error(r.status, std::string(what) + " of skill " + browseName_);
    return r;
}

void SkillClient::callProgram(const ua::NodeId& method, std::string_view what, Deadline deadline) {
    callMethod(node_, method, {}, what, deadline);
}

void SkillClient::start(Deadline d) { callProgram(start_, "Start", d); }
void SkillClient::suspend(Deadline d) { callProgram(suspend_, "Suspend", d); }
void SkillClient::resume(Deadline d) { callProgram(resume_, "Resume", d); }
void SkillClient::halt(Deadline d) { callProgram(halt_, "Halt", d); }
void SkillClient::reset(Deadline d) { callProgram(reset_, "Reset", d); }

ua::Int32 SkillClient::callLock(const ua::NodeId& method, std::vector<ua::Variant> inputs,
                                std::string_view what, Deadline deadline) {
    auto r = callMethod(lockNode_, method, std::move(inputs), what, deadline);
    if (r.outputs.empty())
        throw Error(status::BadUnexpectedError, std::string(what) + ": no result");
    auto n = integerOf<ua::Int32>(&r.outputs[0]);
    if (!n) throw Error(status::BadTypeMismatch, std::string(what) + ": result is not an Int32");
    return *n;
}

bool SkillClient::lock(std::string_view context, Deadline deadline) {
    const Clock::time_point end = resolve(deadline);
    ua::Int32 r = callLock(initLock_, {ua::Variant(ua::String(context))}, "InitLock", end);
    if (r != lock_status::Ok) return false;
    // The server's lock time (once), so that run() renews in time.
    if (!remainingLockTime_.isNull() && !lockTimeKnown_.exchange(true)) {
        try {
            ua::Variant v = client_->readValue(remainingLockTime_, end);
            if (const auto* ms = v.scalar<ua::Double>(); ms != nullptr && *ms > 0)
                lockTime_ = std::chrono::milliseconds(static_cast<std::int64_t>(*ms));
        } catch (const Error&) {
            // keep options().lockTime
        }
    }
    return true;
}

bool SkillClient::renewLock(Deadline d) {
    return callLock(renewLock_, {}, "RenewLock", d) == lock_status::Ok;
}
bool SkillClient::unlock(Deadline d) {
    return callLock(exitLock_, {}, "ExitLock", d) == lock_status::Ok;
}
bool SkillClient::breakLock(Deadline d) {
    return callLock(breakLock_, {}, "BreakLock", d) == lock_status::Ok;
}

// ---- results and transitions ---------------------------------------------------------------

FinalResult SkillClient::finalResult(Deadline deadline) {
    return stateAndResult(false, deadline).result;
}

SkillClient::Polled SkillClient::stateAndResult(bool withState, Deadline deadline) {
    std::vector<ua::ReadValueId> reads{readOf(resultNode_.isNull() ? node_ : resultNode_),
                                       readOf(messageNode_.isNull() ? node_ : messageNode_)};
    for (const auto& [name, node] : resultValues_) reads.push_back(readOf(node));
    const ua::NodeId& stateNode = !stateNumber_.isNull() ? stateNumber_ : stateId_;
    const std::size_t results = reads.size();
    if (withState) {
        reads.push_back(readOf(stateNode.isNull() ? node_ : stateNode));
        reads.push_back(readOf(lastTransitionNumber_.isNull() ? node_ : lastTransitionNumber_));
        reads.push_back(readOf(lastTransitionTime_.isNull() ? node_ : lastTransitionTime_));
    }
    auto values = client_->read(std::move(reads), deadline);
    Polled polled;
    if (withState && values.size() == results + 3) {
        ua::Variant v = values[results].value.value_or(ua::Variant());
        if (!stateNode.isNull())
            polled.state = stateNumber_.isNull() ? stateOf(nullptr, &v) : stateOf(&v, nullptr);
        if (!lastTransitionNumber_.isNull() && values[results + 1].value)
            polled.lastTransition = integerOf<ua::UInt32>(&*values[results + 1].value).value_or(0);
        if (!lastTransitionTime_.isNull() && values[results + 2].value)
            if (const auto* t = values[results + 2].value->scalar<ua::DateTime>())
                polled.lastTransitionTime = *t;
        values.resize(results);
    }
    Polled& both = polled;
    FinalResult& out = both.result;
    if (!resultNode_.isNull() && values.size() > 0 && values[0].value)
        if (auto n = integerOf<ua::Int32>(&*values[0].value))
            out.result = static_cast<SkillResult>(*n);
    if (!messageNode_.isNull() && values.size() > 1 && values[1].value)
        out.message = textOf(*values[1].value);
    for (std::size_t i = 0; i < resultValues_.size() && i + 2 < values.size(); ++i)
        out.values.emplace_back(resultValues_[i].first,
                                values[i + 2].value.value_or(ua::Variant()));
    return both;
}

void SkillClient::subscribeTransitions(Deadline deadline) {
    std::lock_guard lock(subscribeMutex_);
    if (events_.valid()) return;
    const Clock::time_point end = resolve(deadline);
    ua::client::Subscription& subscription =
        options_.subscription ? *options_.subscription : subscription_;
    if (!subscription.valid()) {
        ua::client::SubscriptionSettings s;
        // Small interval: a waiting Publish is answered as soon as the interval allows, so
        // an event reaches us about one round trip after the transition.
        s.publishingInterval = options_.publishingInterval;
        s.maxKeepAliveCount = 100;
        s.lifetimeCount = 6000;
        subscription = ua::client::Subscription(*client_, s, {}, end);
    }
    ua::client::EventOptions o;
    o.select = kEventSelect;
    o.eventType = ua::NodeId(0, ua::ns0::ProgramTransitionEventType);
    o.where = ua::client::whereOfType(
        ua::NodeId(client_->namespaceIndex(kBaseUri, end), types::SkillTransitionEventType.id));
    o.queueSize = 1000;
    events_ = subscription.monitorEvents(
        node_, std::move(o),
        [queue = queue_, source = node_](ua::client::EventFields& e) {
            Transition t = transitionOf(e);
            if (!t.source.isNull() && t.source != source) return;  // a child's event
            queue->push(std::move(t));
        },
        end);
}

std::size_t SkillClient::onTransition(TransitionCallback callback, Deadline deadline) {
    subscribeTransitions(deadline);
    std::lock_guard lock(queue_->mutex);
    std::size_t id = queue_->nextCallback++;
    queue_->changeCallbacks([&](Queue::Callbacks& c) { c.emplace(id, std::move(callback)); });
    return id;
}

void SkillClient::removeTransitionCallback(std::size_t id) {
    std::lock_guard lock(queue_->mutex);
    queue_->changeCallbacks([&](Queue::Callbacks& c) { c.erase(id); });
}

std::vector<Transition> SkillClient::takeTransitions() {
    std::lock_guard lock(queue_->mutex);
    auto& q = *queue_;
    std::vector<Transition> out;
    for (std::uint64_t s = std::max(q.taken, q.first); s < q.end(); ++s)
        out.push_back(q.items[s - q.first]);
    q.taken = q.end();
    return out;
}

std::optional<Transition> SkillClient::nextTransition(Deadline deadline, std::stop_token cancel) {
    const Clock::time_point end = resolve(deadline);
    std::unique_lock lock(queue_->mutex);
    auto& q = *queue_;
    if (!q.changed.wait_until(lock, cancel, end, [&] { return q.taken < q.end(); }))
        return std::nullopt;
    const std::uint64_t s = std::max(q.taken, q.first);
    q.taken = s + 1;
    return q.items[s - q.first];
}

// ---- run -----------------------------------------------------------------------------------

RunResult SkillClient::run(const NamedValues& params, Deadline deadline, std::stop_token cancel) {
    const Clock::time_point end = resolve(deadline);
    auto cleanup = [&] { return Deadline(std::max(end, Clock::now() + options_.cleanupTime)); };
    RunResult out;
    subscribeTransitions(end);

    // Lock, retrying with a short back-off while another session holds it.
    for (auto backoff = 5ms;; backoff = std::min(backoff * 2, 200ms)) {
        if (cancel.stop_requested()) {
            out.result = SkillResult::Aborted;
            out.message = "cancelled before the skill was locked";
            return out;
        }
        if (lock(options_.lockContext, end)) break;
        if (Clock::now() + backoff >= end)
            throw Error(status::BadLocked,
                        "skill " + browseName_ + " still locked by another session");
        std::unique_lock l(queue_->mutex);
        queue_->changed.wait_for(l, cancel, backoff, [] { return false; });
    }
    // ExitLock whatever happens from here on.
    struct Unlock {
        SkillClient& c;
        std::function<Deadline()> when;
        ~Unlock() {
            try {
                c.unlock(when());
            } catch (const Error&) {
                // the lock expires on its own after the server's lock time
            }
        }
    } unlock{*this, cleanup};

    setParameters(params, end);
    std::uint64_t cursor = 0;
    // Start; a Halted skill (a failed or halted run before) is Reset first and started again.
    for (int attempt = 0;; ++attempt) {
        {
            std::lock_guard l(queue_->mutex);
            cursor = queue_->end();
        }
        try {
            start(end);
            break;
        } catch (const Error& e) {
            // The Start may have been executed without our seeing the response.
            if (e.status() == status::BadTimeout) try {
                    halt(cleanup());
                } catch (const Error&) {
                }
            const bool refused =
                e.status() == status::BadNotExecutable || e.status() == status::BadInvalidState;
            if (attempt > 0 || !refused || state(end) != ProgramState::Halted) throw;
            reset(end);
        }
    }

    // Wait for Running and then Ready / Halted. The last event of a run that ends within
    // the subscription's publishing interval after the Running one may only be delivered at
    // the next interval (the server publishes once per interval), so meanwhile the end is
    // also polled: one Read of the state and the final result right after Start, then at
    // doubling gaps until the publishing interval has passed (a handful of Reads at most),
    // then once a second in case an event was lost. (Start's Good means Ready -> Running
    // happened and the final result was reset to None; we hold the lock, so no other run
    // came between: Ready / Halted with a result means this run ended.)
    // The lock is renewed every third of its time.
    const auto renewEvery = std::max<std::chrono::milliseconds>(lockTime() / 3, 10ms);
    const auto started = Clock::now();
    const ua::DateTime startedAt = ua::DateTime::now();
    const auto fastPollUntil =
        started + std::chrono::microseconds(static_cast<long>(options_.publishingInterval * 1000));
    auto pollGap = std::chrono::microseconds(50);
    auto nextRenew = started + renewEvery;
    auto nextPoll = started;
    bool running = false, ended = false, aborted = false, polledEnd = false;
    Polled last;
    auto poll = [&] {
        Polled p = stateAndResult(true, end);
        if ((p.state == ProgramState::Ready || p.state == ProgramState::Halted) &&
            p.result.result != SkillResult::None) {
            polledEnd = ended = true;
            out.finalResult = p.result;
            last = std::move(p);
        }
        const auto now = Clock::now();
        if (now < fastPollUntil) {
            nextPoll = now + pollGap;
            pollGap *= 2;
        } else {
            nextPoll = now + 1s;
        }
    };
    // After a polled end: the events of this run that have arrived (the Running one, usually),
    // and the last transition as LastTransition says when its event is still on its way.
    auto collectArrived = [&] {
        {
            std::lock_guard l(queue_->mutex);
            auto& q = *queue_;
            for (cursor = std::max(cursor, q.first); cursor < q.end(); ++cursor) {
                const Transition& t = q.items[cursor - q.first];
                if (q.earlier(t)) continue;  // a late event of the run before
                if (t.to == ProgramState::Running && t.from == ProgramState::Ready) running = true;
                if (running) out.transitions.push_back(t);  // not the late event of a Reset
            }
        }
        if (!running) {  // held back by the publishing interval too (e.g. after a Reset)
            Transition t = transitionFromNumber(2);
            t.time = startedAt;  // our clock: when Start returned
            t.source = node_;
            t.polled = true;
            out.transitions.push_back(std::move(t));
            running = true;
        }
        const bool endSeen =
            !out.transitions.empty() && (out.transitions.back().to == ProgramState::Ready ||
                                         out.transitions.back().to == ProgramState::Halted);
        if (!endSeen && last.lastTransition != 0) {
            Transition t = transitionFromNumber(last.lastTransition);
            t.time = last.lastTransitionTime;
            t.source = node_;
            if (t.to == ProgramState::Halted) t.message = out.finalResult.message;
            t.polled = true;
            out.transitions.push_back(std::move(t));
        }
    };
    poll();
    if (polledEnd) collectArrived();
    while (!ended) {
        std::vector<Transition> fresh;
        {
            std::unique_lock l(queue_->mutex);
            auto& q = *queue_;
            q.changed.wait_until(l, cancel, std::min({end, nextRenew, nextPoll}),
                                 [&] { return cursor < q.end(); });
            for (cursor = std::max(cursor, q.first); cursor < q.end(); ++cursor)
                if (!q.earlier(q.items[cursor - q.first]))  // a late event of the run before
                    fresh.push_back(q.items[cursor - q.first]);
        }
        for (auto& t : fresh) {
            if (t.to == ProgramState::Running && t.from == ProgramState::Ready) running = true;
            if (!running) continue;  // e.g. the late event of our Reset
            out.transitions.push_back(t);
            if (t.to == ProgramState::Ready || t.to == ProgramState::Halted) {
                ended = true;
                break;
            }
        }
        if (ended) break;
        const auto now = Clock::now();
        if (!fresh.empty() && now >= fastPollUntil) nextPoll = now + 1s;
        if (cancel.stop_requested() || now >= end) {
            aborted = true;
            break;
        }
        if (now >= nextRenew) {
            renewLock(end);
            nextRenew = now + renewEvery;
        }
        if (now >= nextPoll) {
            poll();
            if (polledEnd) collectArrived();
        }
    }

    if (aborted) {
        out.timedOut = !cancel.stop_requested();
        try {
            halt(cleanup());
        } catch (const Error&) {
            // BadInvalidState: it ended meanwhile; the final result says how
        }
        // Collect the Halted event (briefly; it normally arrives within a round trip).
        const auto until = std::min(Clock::now() + 500ms, Clock::now() + options_.cleanupTime);
        std::unique_lock l(queue_->mutex);
        auto& q = *queue_;
        for (bool done = false; !done;) {
            if (!q.changed.wait_until(l, until, [&] { return cursor < q.end(); })) break;
            for (cursor = std::max(cursor, q.first); cursor < q.end(); ++cursor) {
                const Transition& t = q.items[cursor - q.first];
                if (q.earlier(t)) continue;
                if (t.to == ProgramState::Running && t.from == ProgramState::Ready) running = true;
                if (!running) continue;
                out.transitions.push_back(t);
                if (t.to == ProgramState::Ready || t.to == ProgramState::Halted) done = true;
            }
        }
    }
    if (!polledEnd) out.finalResult = finalResult(cleanup());
    // When this run ended, by the server's clock: LastTransition's time when polled, else its
    // last event's (transitions synthesized from polls carry our clock and do not count).
    ua::DateTime endedAt = polledEnd ? last.lastTransitionTime : ua::DateTime{};
    for (const Transition& t : out.transitions)
        if (!t.polled && t.time > endedAt) endedAt = t.time;
    {
        std::lock_guard l(queue_->mutex);
        if (endedAt > queue_->lastRunEnded) queue_->lastRunEnded = endedAt;
    }
    out.result = out.finalResult.result;
    out.message = out.finalResult.message;
    if (aborted && out.result != SkillResult::Completed && out.result != SkillResult::Failed) {
        out.result = SkillResult::Aborted;
        if (out.message.empty())
            out.message = out.timedOut ? "deadline passed: halted" : "cancelled: halted";
    }
    return out;
}

}  // namespace pnp::skill::client
