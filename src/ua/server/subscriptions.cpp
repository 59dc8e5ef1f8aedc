#include "ua/server/subscriptions.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <deque>
#include <memory>
#include <mutex>
#include <random>
#include <unordered_map>
#include <variant>

#include "ua/types/attribute_id.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

namespace {
using Clock = std::chrono::steady_clock;
using TimePoint = Clock::time_point;
using Millis = std::chrono::duration<double, std::milli>;

constexpr std::uint32_t kOverflowBits = 0x0480;  // InfoType DataValue + Overflow (§7.39)
constexpr UInt32 kAttrNodeId = 1;
constexpr UInt32 kAttrEventNotifier = 12;
constexpr UInt32 kAttrValue = 13;

Clock::duration toDuration(double ms) {
    return std::chrono::duration_cast<Clock::duration>(Millis(ms));
}

ByteString randomEventId() {
    thread_local std::mt19937_64 rng{std::random_device{}()};
    std::string s(16, '\0');
    for (std::size_t i = 0; i < 16; i += 8) {
        UInt64 r = rng();
        for (std::size_t k = 0; k < 8; ++k) s[i + k] = static_cast<char>(r >> (8 * k));
    }
    return ByteString(std::move(s));
}

template <class Resp>
void sendResponse(transport::ServerConnection& conn, UInt32 requestId, UInt32 requestHandle,
                  Resp& resp) {
    resp.responseHeader.requestHandle = requestHandle;
    resp.responseHeader.timestamp = DateTime::nowCoarse();
    Buffer b = transport::ServerConnection::newMessageBuffer();
    BinaryEncoder e(b);
    encode(e, NodeId(0, DataTypeInfo<Resp>::binaryEncodingId));
    encode(e, resp);
    conn.send(requestId, std::move(b));
}

// A numeric scalar as double (deadbands, comparisons); nullopt for other types.
std::optional<double> numericValue(const Variant& v) {
    return std::visit(
        [](const auto& x) -> std::optional<double> {
            using T = std::decay_t<decltype(x)>;
            if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool>)
                return static_cast<double>(x);
            else
                return std::nullopt;
        },
        v.storage());
}

// Element i of a numeric array as double.
std::optional<std::vector<double>> numericArray(const Variant& v) {
    return std::visit(
        [](const auto& x) -> std::optional<std::vector<double>> {
            using T = std::decay_t<decltype(x)>;
            if constexpr (requires {
                              typename T::value_type;
                              x.size();
                          }) {
                using E = typename T::value_type;
                if constexpr (std::is_arithmetic_v<E> && !std::is_same_v<E, bool>) {
                    std::vector<double> out(x.begin(), x.end());
                    return out;
                }
            }
            return std::nullopt;
        },
        v.storage());
}

// Values differ by more than `deadband` (absolute; OPC 10000-4 §7.22.2). Non-numeric values
// and changed shapes count as changes.
bool exceedsDeadband(const Variant& a, const Variant& b, double deadband) {
    if (auto x = numericValue(a)) {
        auto y = numericValue(b);
        return !y || std::fabs(*x - *y) > deadband;
    }
    auto xs = numericArray(a);
    auto ys = numericArray(b);
    if (!xs || !ys || xs->size() != ys->size()) return !(a == b);
    for (std::size_t i = 0; i < xs->size(); ++i)
        if (std::fabs((*xs)[i] - (*ys)[i]) > deadband) return true;
    return false;
}

bool variantsEqual(const Variant& a, const Variant& b) {
    auto x = numericValue(a);
    auto y = numericValue(b);
    if (x && y) return *x == *y;
    return a == b;
}

// ---- compiled event filters -----------------------------------------------------------------
struct FieldRef {
    // A BaseEventType field that Event holds as a member (resolved once, when compiled).
    enum class Member : std::uint8_t {
        None,
        EventId,
        EventType,
        SourceNode,
        SourceName,
        Time,
        ReceiveTime,
        Message,
        Severity
    };
    FieldRef() = default;
    FieldRef(NodeId type, std::vector<QualifiedName> browsePath, UInt32 attribute)
        : typeDefinition(std::move(type)), path(std::move(browsePath)), attributeId(attribute) {
        if (path.size() != 1 || path[0].namespaceIndex != 0) return;
        static constexpr std::pair<std::string_view, Member> kMembers[] = {
            {"EventId", Member::EventId},
            {"EventType", Member::EventType},
            {"SourceNode", Member::SourceNode},
            {"SourceName", Member::SourceName},
            {"Time", Member::Time},
            {"ReceiveTime", Member::ReceiveTime},
            {"Message", Member::Message},
            {"Severity", Member::Severity}};
        for (const auto& [name, m] : kMembers)
            if (path[0].name == name) member = m;
    }

    NodeId typeDefinition;
    std::vector<QualifiedName> path;
    UInt32 attributeId = kAttrValue;
    Member member = Member::None;
};

struct Operand {
    enum class Kind { Element, Literal, Field } kind = Kind::Literal;
    UInt32 element = 0;
    Variant literal;
    FieldRef field;
};

struct FilterElement {
    FilterOperator op{};
    std::vector<Operand> operands;
};

struct CompiledEventFilter {
    std::vector<FieldRef> select;
    std::vector<FilterElement> where;
};

// An event as the filters see it.
struct EventRecord {
    Event event;
    DateTime receiveTime;
    std::shared_ptr<const std::vector<NodeId>> typeChain;  // the event type and its supertypes
};

bool hasType(const EventRecord& e, const NodeId& type) {
    return std::find(e.typeChain->begin(), e.typeChain->end(), type) != e.typeChain->end();
}

// hasType() for the select clauses of one item, which mostly name one type: the last answer
// is kept.
class TypeCheck {
  public:
    explicit TypeCheck(const EventRecord& r) : r_(r) {}
    bool operator()(const NodeId& type) {
        if (last_ == nullptr || !(*last_ == type)) {
            last_ = &type;
            answer_ = hasType(r_, type);
        }
        return answer_;
    }

  private:
    const EventRecord& r_;
    const NodeId* last_ = nullptr;
    bool answer_ = false;
};

Variant fieldValue(const EventRecord& r, const FieldRef& f, TypeCheck& isOfType) {
    const Event& e = r.event;
    if (!f.typeDefinition.isNull() && !isOfType(f.typeDefinition)) return {};
    if (f.path.empty()) return {};  // ConditionId / the event node itself: not a condition
    if (f.attributeId != kAttrValue) return {};
    switch (f.member) {
        case FieldRef::Member::None:
            break;
        case FieldRef::Member::EventId:
            return Variant(e.eventId);
        case FieldRef::Member::EventType:
            return Variant(e.eventType);
        case FieldRef::Member::SourceNode:
            return Variant(e.sourceNode);
        case FieldRef::Member::SourceName:
            return Variant(e.sourceName);
        case FieldRef::Member::Time:
            return Variant(*e.time);
        case FieldRef::Member::ReceiveTime:
            return Variant(r.receiveTime);
        case FieldRef::Member::Message:
            return Variant(e.message);
        case FieldRef::Member::Severity:
            return Variant(e.severity);
    }
    // The event's own fields first, then the shared ones.
    auto find = [&](auto matches) -> const Variant* {
        for (const Event::Fields* fields : {&e.fields, e.sharedFields.get()})
            if (fields != nullptr)
                for (const auto& [path, value] : *fields)
                    if (matches(path)) return &value;
        return nullptr;
    };
    const Variant* v = find([&](const auto& path) { return path == f.path; });
    // Clients often name custom fields without their namespace: match the names alone.
    if (v == nullptr)
        v = find([&](const auto& path) {
            return path.size() == f.path.size() &&
                   std::equal(path.begin(), path.end(), f.path.begin(),
                              [](const auto& a, const auto& b) { return a.name == b.name; });
        });
    return v != nullptr ? *v : Variant();
}

bool evaluateElement(const EventRecord& r, const CompiledEventFilter& f, UInt32 index, int depth);

Variant operandValue(const EventRecord& r, const CompiledEventFilter& f, const Operand& o,
                     int depth) {
    switch (o.kind) {
        case Operand::Kind::Literal:
            return o.literal;
        case Operand::Kind::Field: {
            TypeCheck isOfType(r);
            return fieldValue(r, o.field, isOfType);
        }
        case Operand::Kind::Element:
            return Variant(evaluateElement(r, f, o.element, depth + 1));
    }
    return {};
}

bool evaluateElement(const EventRecord& r, const CompiledEventFilter& f, UInt32 index, int depth) {
    // Element operands only point forward (checked when compiled), so depth is bounded by
    // the element count; the guard is a second line of defence.
    if (index >= f.where.size() || depth > 64) return false;
    const FilterElement& el = f.where[index];
    auto value = [&](std::size_t i) { return operandValue(r, f, el.operands[i], depth); };
    auto compare = [&](auto cmp) {
        auto a = numericValue(value(0));
        auto b = numericValue(value(1));
        return a && b && cmp(*a, *b);
    };
    switch (el.op) {
        case FilterOperator::Equals:
            return variantsEqual(value(0), value(1));
        case FilterOperator::IsNull:
            return value(0).isEmpty();
        case FilterOperator::GreaterThan:
            return compare([](double a, double b) { return a > b; });
        case FilterOperator::LessThan:
            return compare([](double a, double b) { return a < b; });
        case FilterOperator::GreaterThanOrEqual:
            return compare([](double a, double b) { return a >= b; });
        case FilterOperator::LessThanOrEqual:
            return compare([](double a, double b) { return a <= b; });
        case FilterOperator::Not: {
            const Variant v = value(0);
            const Boolean* b = v.scalar<Boolean>();
            return b != nullptr && !*b;
        }
        case FilterOperator::And:
        case FilterOperator::Or: {
            const Variant a = value(0);
            const Variant b = value(1);
            const Boolean* x = a.scalar<Boolean>();
            const Boolean* y = b.scalar<Boolean>();
            bool bx = x != nullptr && *x, by = y != nullptr && *y;
            return el.op == FilterOperator::And ? (bx && by) : (bx || by);
        }
        case FilterOperator::InList: {
            const Variant v = value(0);
            for (std::size_t i = 1; i < el.operands.size(); ++i)
                if (variantsEqual(v, value(i))) return true;
            return false;
        }
        case FilterOperator::OfType: {
            const NodeId* t = el.operands[0].literal.scalar<NodeId>();
            return t != nullptr && hasType(r, *t);
        }
        default:
            return false;
    }
}

bool matches(const EventRecord& r, const CompiledEventFilter& f) {
    return f.where.empty() || evaluateElement(r, f, 0, 0);
}

// ---- state ----------------------------------------------------------------------------------
struct Subscription;

struct MonitoredItem {
    UInt32 id = 0;
    UInt32 clientHandle = 0;
    Subscription* subscription = nullptr;
    ReadValueId itemToMonitor;
    MonitoringMode mode = MonitoringMode::Reporting;
    TimestampsToReturn timestamps = TimestampsToReturn::Both;
    double samplingInterval = 0;
    UInt32 queueSize = 1;
    bool discardOldest = true;
    bool isEvent = false;
    bool eventDriven = false;  // sampling interval 0 on a Value: fed by the value listener
    bool deleted = false;
    bool pending = false;    // in its subscription's pending list
    bool triggered = false;  // a triggering item reported: report this Sampling item once
    // data changes
    DataChangeTrigger trigger = DataChangeTrigger::StatusValue;
    double deadband = -1;  // absolute; < 0: none
    std::optional<DataValue> last;
    std::vector<DataValue> values;
    // events
    std::shared_ptr<const CompiledEventFilter> eventFilter;
    std::vector<std::vector<Variant>> events;
    // SetTriggering links (ids of triggered items of the same subscription)
    std::vector<UInt32> links;
    // sampling group membership
    double groupInterval = 0;
    std::size_t groupIndex = 0;

    bool hasQueued() const { return !values.empty() || !events.empty(); }
};
using ItemPtr = std::shared_ptr<MonitoredItem>;

struct Subscription {
    UInt32 id = 0;
    NodeId session;
    double publishingInterval = 0;
    UInt32 lifetimeCount = 0;
    UInt32 maxKeepAliveCount = 0;
    UInt32 maxNotificationsPerPublish = 0;
    bool publishingEnabled = true;
    Byte priority = 0;
    std::unordered_map<UInt32, ItemPtr> items;
    UInt32 nextItemId = 1;
    UInt32 nextSequenceNumber = 1;
    std::deque<NotificationMessage> retransmission;
    UInt32 keepAliveCounter = 0;
    UInt32 lifetimeCounter = 0;
    TimePoint nextCycle;
    TimePoint lastMessage;
    bool late = false;  // something to send (or a keep-alive due) but no request
    bool sentFirstMessage = false;
    std::vector<ItemPtr> pending;  // items with something to report
    std::optional<StatusCode> statusChange;
};

struct PendingPublish {
    std::shared_ptr<transport::ServerConnection> conn;
    UInt32 requestId = 0;
    UInt32 requestHandle = 0;
    std::vector<StatusCode> ackResults;
    TimePoint deadline = TimePoint::max();
};

// A StatusChangeNotification for a subscription that left its session (transferred or
// expired), waiting for the session's next Publish request.
struct StatusNotice {
    UInt32 subscriptionId = 0;
    UInt32 sequenceNumber = 0;
    StatusCode status;
};

struct SessionState {
    std::deque<PendingPublish> publishes;
    std::vector<UInt32> subscriptions;
    std::deque<StatusNotice> notices;  // at most maxSubscriptionsPerSession
    SessionIdentity user;
    bool closed = false;  // the session ended; its subscriptions wait for a transfer
};

bool sameUser(const SessionIdentity& a, const SessionIdentity& b) {
    return a.anonymous == b.anonymous && (a.anonymous || a.userName == b.userName);
}

// The timestamps a monitored item returns (TimestampsToReturn).
void keepTimestamps(DataValue& v, TimestampsToReturn ts) {
    if (ts != TimestampsToReturn::Source && ts != TimestampsToReturn::Both) {
        v.sourceTimestamp.reset();
        v.sourcePicoseconds.reset();
    }
    if (ts != TimestampsToReturn::Server && ts != TimestampsToReturn::Both) {
        v.serverTimestamp.reset();
        v.serverPicoseconds.reset();
    }
}

struct SamplingGroup {
    TimePoint next;
    std::vector<ItemPtr> items;
};
}  // namespace

struct SubscriptionEngine::Impl {
    using Connections = std::vector<std::shared_ptr<transport::ServerConnection>>;
    AddressSpace& as;
    SubscriptionLimits limits;
    DecodeLimits decodeLimits;

    mutable std::mutex mutex;
    std::condition_variable wake;
    std::thread timer;
    bool stopping = false;

    std::unordered_map<NodeId, SessionState> sessions;
    std::map<UInt32, std::unique_ptr<Subscription>> subscriptions;
    UInt32 nextSubscriptionId = 1;
    std::map<double, SamplingGroup> groups;  // by sampling interval (ms)
    std::unordered_map<NodeId, std::vector<MonitoredItem*>> valueWatchers;  // event-driven items
    std::unordered_map<NodeId, std::vector<MonitoredItem*>> eventWatchers;  // by notifier
    std::atomic<std::size_t> watchedValues{0};
    std::size_t itemCount = 0;
    std::size_t keptSubscriptions = 0;  // of closed sessions
    std::uint64_t messagesSent = 0;
    std::uint64_t samples = 0;

    Impl(AddressSpace& a, SubscriptionLimits l, DecodeLimits d)
        : as(a), limits(l), decodeLimits(d) {}

    // ---- revision -----------------------------------------------------------------------------
    double revisePublishingInterval(double requested) const {
        if (!(requested >= limits.minPublishingIntervalMs)) return limits.minPublishingIntervalMs;
        return std::min(requested, limits.maxPublishingIntervalMs);
    }
    void reviseCounts(Subscription& s, UInt32 lifetime, UInt32 keepAlive) const {
        s.maxKeepAliveCount = std::clamp<UInt32>(keepAlive, 1, limits.maxKeepAliveCount);
        // The lifetime is at least three keep-alive periods (§5.13.2.2).
        UInt32 minLifetime = s.maxKeepAliveCount * 3;
        s.lifetimeCount = std::clamp<UInt32>(lifetime, minLifetime,
                                             std::max(limits.maxLifetimeCount, minLifetime));
    }

    Subscription* find(const NodeId& session, UInt32 id) {
        auto it = subscriptions.find(id);
        if (it == subscriptions.end() || it->second->session != session) return nullptr;
        return it->second.get();
    }
    // The same for a service that fails as a whole on an unknown subscription.
    Subscription* find(const NodeId& session, UInt32 id, ResponseHeader& header) {
        Subscription* s = find(session, id);
        if (s == nullptr) header.serviceResult = status::BadSubscriptionIdInvalid;
        return s;
    }

    // A subscription of a session with the engine's lock held; empty (lock released, the
    // service failed with Bad_SubscriptionIdInvalid) when the session has no such one.
    class Locked {
      public:
        Locked(std::unique_lock<std::mutex> lock, Subscription* s)
            : lock_(std::move(lock)), s_(s) {}
        explicit operator bool() const { return s_ != nullptr; }
        Subscription* get() const { return s_; }
        Subscription* operator->() const { return s_; }
        Subscription& operator*() const { return *s_; }

      private:
        std::unique_lock<std::mutex> lock_;
        Subscription* s_;
    };
    Locked lockSubscription(const NodeId& session, UInt32 id, ResponseHeader& header) {
        std::unique_lock lock(mutex);
        Subscription* s = find(session, id, header);
        if (s == nullptr) lock.unlock();
        return {std::move(lock), s};
    }
    // For services on a list of subscriptions (the lock held): fn(subscription) for each of
    // `ids` that is one of the session's, Bad_SubscriptionIdInvalid for the others.
    template <class F>
    std::vector<StatusCode> eachSubscription(const NodeId& session, const std::vector<UInt32>& ids,
                                             F fn) {
        std::vector<StatusCode> results;
        results.reserve(ids.size());
        for (UInt32 id : ids) {
            Subscription* s = find(session, id);
            if (s == nullptr) {
                results.push_back(status::BadSubscriptionIdInvalid);
                continue;
            }
            fn(*s);
            results.push_back(status::Good);
        }
        return results;
    }

    // ---- items ----------------------------------------------------------------------------------
    void addToGroup(const ItemPtr& item, double interval) {
        auto [it, added] = groups.try_emplace(interval);
        if (added) it->second.next = Clock::now() + toDuration(interval);
        item->groupInterval = interval;
        item->groupIndex = it->second.items.size();
        it->second.items.push_back(item);
        wake.notify_one();
    }
    void removeFromGroup(MonitoredItem& item) {
        auto it = groups.find(item.groupInterval);
        if (it == groups.end()) return;
        auto& v = it->second.items;
        if (item.groupIndex < v.size() && v[item.groupIndex].get() == &item) {
            v[item.groupIndex] = std::move(v.back());
            v[item.groupIndex]->groupIndex = item.groupIndex;
            v.pop_back();
        }
        if (v.empty()) groups.erase(it);
    }
    static void unwatch(std::unordered_map<NodeId, std::vector<MonitoredItem*>>& m,
                        const NodeId& node, MonitoredItem* item) {
        auto it = m.find(node);
        if (it == m.end()) return;
        std::erase(it->second, item);
        if (it->second.empty()) m.erase(it);
    }
    void detach(MonitoredItem& item) {
        item.deleted = true;
        if (item.isEvent) {
            unwatch(eventWatchers, item.itemToMonitor.nodeId, &item);
            return;
        }
        if (item.eventDriven) {
            unwatch(valueWatchers, item.itemToMonitor.nodeId, &item);
            watchedValues.fetch_sub(1, std::memory_order_relaxed);
        }
        removeFromGroup(item);
    }
    void attach(const ItemPtr& item, double fallbackInterval) {
        if (item->isEvent) {
            eventWatchers[item->itemToMonitor.nodeId].push_back(item.get());
            return;
        }
        if (item->eventDriven) {
            valueWatchers[item->itemToMonitor.nodeId].push_back(item.get());
            watchedValues.fetch_add(1, std::memory_order_relaxed);
            // Values served by read callbacks never reach the listener: sample them too.
            addToGroup(item, fallbackInterval);
        } else {
            addToGroup(item, item->samplingInterval);
        }
    }
    void deleteSubscription(UInt32 id) {
        auto it = subscriptions.find(id);
        if (it == subscriptions.end()) return;
        Subscription& s = *it->second;
        for (auto& [_, item] : s.items) detach(*item);
        itemCount -= s.items.size();
        const NodeId session = s.session;
        subscriptions.erase(it);
        leave(session, id);
    }
    // Subscription `id` left `session` (deleted or transferred).
    void leave(const NodeId& session, UInt32 id) {
        auto st = sessions.find(session);
        if (st == sessions.end()) return;
        if (std::erase(st->second.subscriptions, id) != 0 && st->second.closed) --keptSubscriptions;
        if (st->second.closed && st->second.subscriptions.empty()) sessions.erase(st);
    }
    // Publish requests of a session without subscriptions would wait forever.
    void releasePublishes(const NodeId& session) {
        auto st = sessions.find(session);
        if (st == sessions.end() || !st->second.subscriptions.empty()) return;
        for (auto& p : st->second.publishes)
            p.conn->sendServiceFault(p.requestId, p.requestHandle, status::BadNoSubscription);
        st->second.publishes.clear();
    }

    bool changed(const MonitoredItem& item, const DataValue& old, const DataValue& now) const {
        if (old.statusOrGood() != now.statusOrGood()) return true;
        if (item.trigger == DataChangeTrigger::Status) return false;
        bool valueChanged;
        if (!old.value || !now.value)
            valueChanged = old.value.has_value() != now.value.has_value();
        else if (item.deadband >= 0)
            valueChanged = exceedsDeadband(*old.value, *now.value, item.deadband);
        else
            valueChanged = !(*old.value == *now.value);
        if (valueChanged) return true;
        // With a deadband, StatusValueTimestamp behaves as StatusValue (Part 4 §7.10).
        return item.trigger == DataChangeTrigger::StatusValueTimestamp && item.deadband < 0 &&
               old.sourceTimestamp != now.sourceTimestamp;
    }

    void markPending(Subscription& s, const ItemPtr& item) {
        if (item->pending) return;
        item->pending = true;
        s.pending.push_back(item);
    }

    // A new value for a data item (sampled or from the listener). Returns whether it was
    // queued for reporting.
    bool applyValue(const ItemPtr& item, DataValue v) {
        if (item->deleted || item->mode == MonitoringMode::Disabled) return false;
        if (item->last) {
            const auto& prev = item->last->sourceTimestamp;
            if (prev && v.sourceTimestamp && *v.sourceTimestamp < *prev) return false;  // stale
            if (!changed(*item, *item->last, v)) return false;
        }
        item->last = v;
        keepTimestamps(v, item->timestamps);
        auto& q = item->values;
        if (q.size() >= item->queueSize) {
            if (item->queueSize == 1) {
                q.clear();
            } else if (item->discardOldest) {
                q.erase(q.begin());
                q.front().status = StatusCode(q.front().statusOrGood().value | kOverflowBits);
            } else {
                q.pop_back();
                v.status = StatusCode(v.statusOrGood().value | kOverflowBits);
            }
        }
        q.push_back(std::move(v));
        return report(item);
    }

    bool report(const ItemPtr& item) {
        Subscription& s = *item->subscription;
        if (item->mode != MonitoringMode::Reporting) return false;
        markPending(s, item);
        for (UInt32 link : item->links) {
            auto it = s.items.find(link);
            if (it == s.items.end() || it->second->mode != MonitoringMode::Sampling ||
                !it->second->hasQueued())
                continue;
            it->second->triggered = true;
            markPending(s, it->second);
        }
        return true;
    }

    // ---- publishing -----------------------------------------------------------------------------
    bool hasNotifications(const Subscription& s) const {
        return (s.publishingEnabled && !s.pending.empty()) || s.statusChange.has_value();
    }

    // The oldest usable Publish request of the session (expired ones are answered).
    std::optional<PendingPublish> takePublish(const NodeId& session, TimePoint now) {
        auto it = sessions.find(session);
        if (it == sessions.end()) return std::nullopt;
        auto& q = it->second.publishes;
        while (!q.empty()) {
            PendingPublish p = std::move(q.front());
            q.pop_front();
            if (p.conn->isClosed()) continue;
            if (now > p.deadline) {
                p.conn->sendServiceFault(p.requestId, p.requestHandle, status::BadTimeout);
                continue;
            }
            return p;
        }
        return std::nullopt;
    }
    bool publishAvailable(const NodeId& session) const {
        auto it = sessions.find(session);
        return it != sessions.end() && !it->second.publishes.empty();
    }

    // Answers `p` with a StatusChangeNotification of a subscription that left the session.
    void sendNotice(PendingPublish& p, const StatusNotice& n) {
        PublishResponse r;
        r.subscriptionId = n.subscriptionId;
        r.results = std::move(p.ackResults);
        r.notificationMessage.sequenceNumber = n.sequenceNumber;
        r.notificationMessage.publishTime = DateTime::now();
        StatusChangeNotification sc;
        sc.status = n.status;
        r.notificationMessage.notificationData.push_back(toExtensionObject(sc));
        ++messagesSent;
        sendResponse(*p.conn, p.requestId, p.requestHandle, r);
    }
    // Tells an open session that subscription `s` left it (§7.20.4): on a queued Publish
    // request at once, otherwise on the next one.
    void notify(const NodeId& session, const Subscription& s, StatusCode status, TimePoint now) {
        auto st = sessions.find(session);
        if (st == sessions.end() || st->second.closed) return;
        StatusNotice n{s.id, s.nextSequenceNumber, status};
        if (auto p = takePublish(session, now)) {
            sendNotice(*p, n);
            return;
        }
        auto& q = st->second.notices;
        if (q.size() >= limits.maxSubscriptionsPerSession) q.pop_front();
        q.push_back(n);
    }

    // The lifetime of subscription `id` ran out (§5.13.1.2): its session, while open, gets a
    // StatusChangeNotification Bad_Timeout, and the subscription is deleted.
    void expire(UInt32 id, TimePoint now) {
        auto it = subscriptions.find(id);
        if (it == subscriptions.end()) return;
        const NodeId session = it->second->session;
        notify(session, *it->second, status::BadTimeout, now);
        deleteSubscription(id);
        releasePublishes(session);
    }

    // Subscription `s` moves to session `to` (TransferSubscriptions).
    void move(Subscription& s, const NodeId& to, SessionState& target, TimePoint now) {
        const NodeId from = s.session;
        s.session = to;
        s.lifetimeCounter = 0;
        target.subscriptions.push_back(s.id);
        notify(from, s, status::GoodSubscriptionTransferred, now);
        leave(from, s.id);
        releasePublishes(from);
    }
    // sendInitialValues: the current value of every data item in Reporting mode goes out with
    // the next message (the queued one, else the last one reported again).
    void queueInitialValues(Subscription& s) {
        for (auto& [_, item] : s.items) {
            if (item->isEvent || item->mode != MonitoringMode::Reporting) continue;
            if (item->values.empty() && item->last) {
                DataValue v = *item->last;
                keepTimestamps(v, item->timestamps);
                item->values.push_back(std::move(v));
            }
            if (item->hasQueued()) markPending(s, item);
        }
    }

    NotificationMessage buildMessage(Subscription& s, bool& more) {
        NotificationMessage m;
        m.publishTime = DateTime::now();
        DataChangeNotification data;
        EventNotificationList events;
        std::size_t budget = s.maxNotificationsPerPublish;
        std::size_t used = 0;
        std::size_t i = 0;
        if (s.publishingEnabled) {
            for (; i < s.pending.size() && used < budget; ++i) {
                MonitoredItem& item = *s.pending[i];
                item.pending = false;
                if (item.deleted) continue;
                if (item.mode == MonitoringMode::Sampling && !item.triggered) continue;
                std::size_t nv = std::min(item.values.size(), budget - used);
                for (std::size_t k = 0; k < nv; ++k)
                    data.monitoredItems.push_back({item.clientHandle, std::move(item.values[k])});
                item.values.erase(item.values.begin(),
                                  item.values.begin() + static_cast<std::ptrdiff_t>(nv));
                used += nv;
                std::size_t ne = std::min(item.events.size(), budget - used);
                for (std::size_t k = 0; k < ne; ++k)
                    events.events.push_back({item.clientHandle, std::move(item.events[k])});
                item.events.erase(item.events.begin(),
                                  item.events.begin() + static_cast<std::ptrdiff_t>(ne));
                used += ne;
                if (item.hasQueued()) {
                    item.pending = true;  // the rest goes into the next message
                    break;
                }
                item.triggered = false;
            }
            s.pending.erase(s.pending.begin(), s.pending.begin() + static_cast<std::ptrdiff_t>(i));
        }
        more = !s.pending.empty() && s.publishingEnabled;
        if (!data.monitoredItems.empty()) m.notificationData.push_back(toExtensionObject(data));
        if (!events.events.empty()) m.notificationData.push_back(toExtensionObject(events));
        if (s.statusChange) {
            StatusChangeNotification sc;
            sc.status = *s.statusChange;
            m.notificationData.push_back(toExtensionObject(sc));
            s.statusChange.reset();
        }
        return m;
    }

    // Sends a NotificationMessage (or a keep-alive) of `s` on `p`.
    void send(Subscription& s, PendingPublish& p, bool keepAlive, TimePoint now) {
        PublishResponse r;
        r.subscriptionId = s.id;
        r.results = std::move(p.ackResults);
        bool more = false;
        if (!keepAlive) r.notificationMessage = buildMessage(s, more);
        const bool keptForRepublish = !r.notificationMessage.notificationData.empty();
        r.notificationMessage.sequenceNumber = s.nextSequenceNumber;
        if (keptForRepublish) {
            s.nextSequenceNumber =
                s.nextSequenceNumber == 0xFFFFFFFFu ? 1 : s.nextSequenceNumber + 1;
            while (s.retransmission.size() >= limits.maxRetransmissionQueue &&
                   !s.retransmission.empty())
                s.retransmission.pop_front();
        } else {
            // Keep-alive: the next sequence number, not consumed (§5.13.1.1).
            r.notificationMessage.publishTime = DateTime::now();
        }
        r.moreNotifications = more;
        r.availableSequenceNumbers.reserve(s.retransmission.size() + 1);
        for (const auto& m : s.retransmission)
            r.availableSequenceNumbers.push_back(m.sequenceNumber);
        if (keptForRepublish && limits.maxRetransmissionQueue > 0)
            r.availableSequenceNumbers.push_back(r.notificationMessage.sequenceNumber);
        s.keepAliveCounter = 0;
        s.lifetimeCounter = 0;
        s.lastMessage = now;
        s.sentFirstMessage = true;
        s.late = more;
        ++messagesSent;
        sendResponse(*p.conn, p.requestId, p.requestHandle, r);
        // Kept after sending (moved, not copied: the change reaches the wire first).
        if (keptForRepublish && limits.maxRetransmissionQueue > 0)
            s.retransmission.push_back(std::move(r.notificationMessage));
    }

    // One publishing cycle of `s` (§5.13.1.2, simplified state machine). Returns false when
    // the subscription expired.
    bool cycle(Subscription& s, TimePoint now) {
        bool wantsToSend = hasNotifications(s);
        bool keepAliveDue =
            !wantsToSend && (!s.sentFirstMessage || ++s.keepAliveCounter >= s.maxKeepAliveCount);
        if (wantsToSend || keepAliveDue || s.late) {
            if (auto p = takePublish(s.session, now)) {
                send(s, *p, !wantsToSend, now);
                return true;
            }
            s.late = true;
        }
        if (!publishAvailable(s.session) && ++s.lifetimeCounter >= s.lifetimeCount) {
            return false;
        }
        return true;
    }

    // A Publish request arrived or a notification was queued: answer late subscriptions.
    void serveLate(const NodeId& session, TimePoint now) {
        auto st = sessions.find(session);
        if (st == sessions.end()) return;
        for (UInt32 id : std::vector<UInt32>(st->second.subscriptions)) {
            auto it = subscriptions.find(id);
            if (it == subscriptions.end()) continue;
            Subscription& s = *it->second;
            if (!s.late) continue;
            auto p = takePublish(session, now);
            if (!p) return;
            send(s, *p, !hasNotifications(s), now);
        }
    }

    // After a value or an event was queued outside the timer: answers a waiting Publish of
    // `s` at once when the publishing interval allows; adds its connection to `sentOn`.
    void publishEarly(Subscription& s, TimePoint now, Connections& sentOn) {
        if (!s.publishingEnabled) return;
        if (now - s.lastMessage < toDuration(s.publishingInterval) && s.sentFirstMessage) return;
        if (auto p = takePublish(s.session, now)) {
            sentOn.push_back(p->conn);
            send(s, *p, false, now);
            s.nextCycle = now + toDuration(s.publishingInterval);
        } else {
            s.late = true;
        }
    }

    // A notification that a handler caused leaves before the rest of the handler's work
    // (the request's own response, state variables that follow an event): called without
    // the engine's lock.
    static void flush(const Connections& sentOn) {
        for (const auto& c : sentOn) c->flush();
    }

    void onValue(const NodeId& node, const DataValue& value) {
        Connections sentOn;
        {
            std::lock_guard lock(mutex);
            auto it = valueWatchers.find(node);
            if (it == valueWatchers.end()) return;
            auto now = Clock::now();
            std::vector<Subscription*> touched;
            for (MonitoredItem* raw : it->second) {
                Subscription& s = *raw->subscription;
                auto item = s.items.find(raw->id);
                if (item == s.items.end()) continue;
                if (applyValue(item->second, value)) touched.push_back(&s);
            }
            for (Subscription* s : touched) publishEarly(*s, now, sentOn);
        }
        flush(sentOn);
    }

    // ---- the timer thread ----------------------------------------------------------------------
    void run() {
        std::unique_lock lock(mutex);
        ReadRequest read;
        read.timestampsToReturn = TimestampsToReturn::Both;
        std::vector<ItemPtr> sampled;
        while (!stopping) {
            auto now = Clock::now();
            // Sampling: snapshot the due groups, read without the lock, apply.
            read.nodesToRead.clear();
            sampled.clear();
            for (auto& [interval, g] : groups) {
                if (now < g.next) continue;
                g.next += toDuration(interval);
                if (g.next < now) g.next = now + toDuration(interval);
                for (const auto& item : g.items) {
                    if (item->mode == MonitoringMode::Disabled) continue;
                    sampled.push_back(item);
                    read.nodesToRead.push_back(item->itemToMonitor);
                }
            }
            if (!sampled.empty()) {
                lock.unlock();
                ReadResponse values = as.read(read);
                lock.lock();
                samples += sampled.size();
                // Queued values go out with the next publishing cycle.
                for (std::size_t i = 0; i < sampled.size() && i < values.results.size(); ++i)
                    applyValue(sampled[i], std::move(values.results[i]));
                sampled.clear();
                if (stopping) break;
                now = Clock::now();
            }
            // Publishing cycles.
            std::vector<UInt32> expired;
            for (auto& [id, s] : subscriptions) {
                if (now < s->nextCycle) continue;
                s->nextCycle += toDuration(s->publishingInterval);
                if (s->nextCycle < now) s->nextCycle = now + toDuration(s->publishingInterval);
                if (!cycle(*s, now)) expired.push_back(id);
            }
            for (UInt32 id : expired) expire(id, now);
            // Publish requests past their timeout hint.
            for (auto& [_, st] : sessions)
                std::erase_if(st.publishes, [&](PendingPublish& p) {
                    if (p.conn->isClosed()) return true;
                    if (now <= p.deadline) return false;
                    p.conn->sendServiceFault(p.requestId, p.requestHandle, status::BadTimeout);
                    return true;
                });
            TimePoint next = now + std::chrono::seconds(1);
            for (auto& [_, g] : groups) next = std::min(next, g.next);
            for (auto& [_, s] : subscriptions) next = std::min(next, s->nextCycle);
            wake.wait_until(lock, next);
        }
    }

    // ---- monitored item parameters ---------------------------------------------------------
    struct ItemSetup {
        StatusCode status;
        double samplingInterval = 0;
        UInt32 queueSize = 1;
        bool eventDriven = false;
        DataChangeTrigger trigger = DataChangeTrigger::StatusValue;
        double deadband = -1;
        std::shared_ptr<const CompiledEventFilter> eventFilter;
        ExtensionObject filterResult;
    };

    StatusCode compileOperand(const ExtensionObject& x, std::size_t self, std::size_t count,
                              Operand& out) const {
        try {
            if (auto e = fromExtensionObject<ElementOperand>(x, decodeLimits)) {
                if (e->index <= self || e->index >= count) return status::BadFilterOperandInvalid;
                out.kind = Operand::Kind::Element;
                out.element = e->index;
                return status::Good;
            }
            if (auto l = fromExtensionObject<LiteralOperand>(x, decodeLimits)) {
                out.kind = Operand::Kind::Literal;
                out.literal = std::move(l->value);
                return status::Good;
            }
            if (auto a = fromExtensionObject<SimpleAttributeOperand>(x, decodeLimits)) {
                out.kind = Operand::Kind::Field;
                out.field = {a->typeDefinitionId, std::move(a->browsePath), a->attributeId};
                return status::Good;
            }
        } catch (const DecodeError&) {
            return status::BadFilterOperandInvalid;
        }
        return status::BadFilterOperandInvalid;  // AttributeOperand and others
    }

    StatusCode checkSelect(const SimpleAttributeOperand& o) const {
        if (o.attributeId != kAttrValue && !(o.attributeId == kAttrNodeId && o.browsePath.empty()))
            return status::BadAttributeIdInvalid;
        NodeId base(0, ns0::BaseEventType);
        if (!o.typeDefinitionId.isNull() && !as.isSubtypeOf(o.typeDefinitionId, base))
            return status::BadTypeDefinitionInvalid;
        for (const auto& q : o.browsePath)
            if (q.name.empty()) return status::BadBrowseNameInvalid;
        return status::Good;
    }

    void setUpEventFilter(const ExtensionObject& x, ItemSetup& out) const {
        std::optional<EventFilter> f;
        try {
            f = fromExtensionObject<EventFilter>(x, decodeLimits);
        } catch (const DecodeError&) {
        }
        if (!f) {
            out.status = x.typeId.isNull() ? status::BadMonitoredItemFilterInvalid
                                           : status::BadMonitoredItemFilterUnsupported;
            return;
        }
        EventFilterResult result;
        auto compiled = std::make_shared<CompiledEventFilter>();
        bool bad = false;
        if (f->selectClauses.empty() || f->selectClauses.size() > limits.maxSelectClauses ||
            f->whereClause.elements.size() > limits.maxWhereClauseElements) {
            out.status = status::BadMonitoredItemFilterInvalid;
            return;
        }
        bool anyGood = false;
        for (const auto& s : f->selectClauses) {
            StatusCode c = checkSelect(s);
            result.selectClauseResults.push_back(c);
            anyGood |= c.isGood();
            compiled->select.push_back({s.typeDefinitionId, s.browsePath, s.attributeId});
        }
        const auto& els = f->whereClause.elements;
        for (std::size_t i = 0; i < els.size(); ++i) {
            ContentFilterElementResult er;
            FilterElement el{els[i].filterOperator, {}};
            std::size_t n = els[i].filterOperands.size();
            std::size_t minOps = 2, maxOps = 2;
            switch (el.op) {
                case FilterOperator::Equals:
                case FilterOperator::GreaterThan:
                case FilterOperator::LessThan:
                case FilterOperator::GreaterThanOrEqual:
                case FilterOperator::LessThanOrEqual:
                case FilterOperator::And:
                case FilterOperator::Or:
                    break;
                case FilterOperator::IsNull:
                case FilterOperator::Not:
                case FilterOperator::OfType:
                    minOps = maxOps = 1;
                    break;
                case FilterOperator::InList:
                    maxOps = decodeLimits.maxArrayLength;
                    break;
                case FilterOperator::Like:
                case FilterOperator::Between:
                case FilterOperator::Cast:
                case FilterOperator::InView:
                case FilterOperator::RelatedTo:
                case FilterOperator::BitwiseAnd:
                case FilterOperator::BitwiseOr:
                    er.statusCode = status::BadFilterOperatorUnsupported;
                    break;
                default:
                    er.statusCode = status::BadFilterOperatorInvalid;
            }
            if (er.statusCode.isGood() && (n < minOps || n > maxOps))
                er.statusCode = status::BadFilterOperandCountMismatch;
            if (er.statusCode.isGood()) {
                bool operandsBad = false;
                for (const auto& o : els[i].filterOperands) {
                    Operand op;
                    StatusCode c = compileOperand(o, i, els.size(), op);
                    er.operandStatusCodes.push_back(c);
                    operandsBad |= c.isBad();
                    el.operands.push_back(std::move(op));
                }
                if (el.op == FilterOperator::OfType && !operandsBad &&
                    (el.operands[0].kind != Operand::Kind::Literal ||
                     el.operands[0].literal.scalar<NodeId>() == nullptr)) {
                    er.operandStatusCodes[0] = status::BadFilterOperandInvalid;
                    operandsBad = true;
                }
                if (operandsBad)
                    er.statusCode = status::BadFilterOperandInvalid;
                else
                    er.operandStatusCodes.clear();
            }
            bad |= er.statusCode.isBad();
            result.whereClauseResult.elementResults.push_back(std::move(er));
            compiled->where.push_back(std::move(el));
        }
        if (!bad) result.whereClauseResult.elementResults.clear();
        bool selectBad =
            std::any_of(result.selectClauseResults.begin(), result.selectClauseResults.end(),
                        [](StatusCode c) { return c.isBad(); });
        if (!selectBad) result.selectClauseResults.clear();
        if (bad || selectBad) out.filterResult = toExtensionObject(result);
        if (bad || !anyGood) {
            out.status = status::BadMonitoredItemFilterInvalid;
            return;
        }
        out.eventFilter = std::move(compiled);
    }

    // Checks an item's node, attribute and filter (address space reads: no engine lock held).
    ItemSetup setUp(const ReadValueId& what, const MonitoringParameters& p,
                    double publishingInterval) const {
        ItemSetup out;
        DataValue probe = as.read(what, TimestampsToReturn::Neither);
        StatusCode ps = probe.statusOrGood();
        if (ps == status::BadNodeIdUnknown || ps == status::BadNodeIdInvalid ||
            ps == status::BadAttributeIdInvalid || ps == status::BadIndexRangeInvalid ||
            ps == status::BadNotReadable || ps == status::BadDataEncodingInvalid ||
            ps == status::BadDataEncodingUnsupported) {
            out.status = ps;
            return out;
        }
        if (what.attributeId == kAttrEventNotifier) {
            const Byte* notifier = probe.value ? probe.value->scalar<Byte>() : nullptr;
            if (notifier == nullptr || (*notifier & 1u) == 0) {
                out.status = status::BadNotSupported;  // not an event notifier
                return out;
            }
            out.queueSize =
                p.queueSize == 0 ? limits.maxQueueSize : std::min(p.queueSize, limits.maxQueueSize);
            setUpEventFilter(p.filter, out);
            return out;
        }
        // Data items.
        double si = p.samplingInterval;
        bool canBeEventDriven = what.attributeId == kAttrValue && what.indexRange.empty();
        if (si < 0) si = publishingInterval;
        if (si == 0 && canBeEventDriven)
            out.eventDriven = true;
        else
            si = std::clamp(si, limits.minSamplingIntervalMs, limits.maxSamplingIntervalMs);
        if (std::isnan(si)) si = publishingInterval;
        out.samplingInterval = si;
        out.queueSize = std::clamp<UInt32>(p.queueSize, 1, limits.maxQueueSize);
        if (p.filter.typeId.isNull() && p.filter.body.empty()) return out;
        std::optional<DataChangeFilter> f;
        try {
            f = fromExtensionObject<DataChangeFilter>(p.filter, decodeLimits);
        } catch (const DecodeError&) {
            out.status = status::BadMonitoredItemFilterInvalid;
            return out;
        }
        if (!f) {
            out.status = fromExtensionObject<EventFilter>(p.filter, decodeLimits)
                             ? status::BadFilterNotAllowed
                             : status::BadMonitoredItemFilterUnsupported;
            return out;
        }
        if (what.attributeId != kAttrValue) {
            out.status = status::BadFilterNotAllowed;
            return out;
        }
        auto trig = static_cast<Int32>(f->trigger);
        if (trig < 0 || trig > 2) {
            out.status = status::BadMonitoredItemFilterInvalid;
            return out;
        }
        out.trigger = f->trigger;
        auto type = static_cast<DeadbandType>(f->deadbandType);
        if (type == DeadbandType::None) return out;
        if ((type != DeadbandType::Absolute && type != DeadbandType::Percent) ||
            !(f->deadbandValue >= 0) || (type == DeadbandType::Percent && f->deadbandValue > 100)) {
            out.status = status::BadDeadbandFilterInvalid;
            return out;
        }
        // Deadbands apply to numeric variables only.
        DataValue dt = as.readAttribute(what.nodeId, AttributeId::DataType);
        const NodeId* dataType = dt.value ? dt.value->scalar<NodeId>() : nullptr;
        if (dataType == nullptr || !as.isSubtypeOf(*dataType, NodeId(0, ns0::Number))) {
            out.status = status::BadFilterNotAllowed;
            return out;
        }
        if (type == DeadbandType::Absolute) {
            out.deadband = f->deadbandValue;
            return out;
        }
        // Percent of the EURange (OPC 10000-8 AnalogItemType).
        std::vector<QualifiedName> path{QualifiedName{0, "EURange"}};
        auto range = as.resolvePath(what.nodeId, path);
        std::optional<Range> r;
        if (range) {
            DataValue rv = as.readValue(*range);
            const ExtensionObject* x = rv.value ? rv.value->scalar<ExtensionObject>() : nullptr;
            try {
                if (x) r = fromExtensionObject<Range>(*x, decodeLimits);
            } catch (const DecodeError&) {
            }
        }
        if (!r) {
            // No EURange: PercentDeadband unsupported for it (OPC 10000-8 §7.2).
            out.status = status::BadDeadbandFilterInvalid;
            return out;
        }
        out.deadband = f->deadbandValue / 100.0 * std::fabs(r->high - r->low);
        return out;
    }

    // ---- events ---------------------------------------------------------------------------------
    // Sources of inverse references of `refType` (and subtypes) to `node`.
    std::vector<NodeId> inverseSources(const NodeId& node, UInt32 refType, UInt32 max) const {
        ContinuationPointStore points(1);
        BrowseDescription d;
        d.nodeId = node;
        d.browseDirection = BrowseDirection::Inverse;
        d.referenceTypeId = NodeId(0, refType);
        d.includeSubtypes = true;
        std::vector<NodeId> out;
        for (const auto& ref : as.browse(d, max, points).references)
            out.push_back(ref.nodeId.nodeId);
        return out;
    }

    std::vector<NodeId> typeChain(const NodeId& type) const {
        std::vector<NodeId> chain{type};
        for (int depth = 0; depth < 32; ++depth) {
            auto super = inverseSources(chain.back(), ns0::HasSubtype, 1);
            if (super.empty()) break;
            chain.push_back(super[0]);
        }
        return chain;
    }

    // The notifiers an event at `source` reaches: the source and every node above it over
    // inverse HasEventSource (HasNotifier included), plus the Server object.
    std::vector<NodeId> notifiersOf(const NodeId& source) const {
        std::vector<NodeId> seen{source};
        for (std::size_t i = 0; i < seen.size() && seen.size() < 256; ++i)
            for (const NodeId& n : inverseSources(seen[i], ns0::HasEventSource, 256))
                if (std::find(seen.begin(), seen.end(), n) == seen.end()) seen.push_back(n);
        NodeId server(0, ns0::Server);
        if (std::find(seen.begin(), seen.end(), server) == seen.end()) seen.push_back(server);
        return seen;
    }

    // Type chains and notifier paths of the event types and sources seen, for one structure
    // generation of the address space (a handful of Browses per event otherwise). The
    // generation is read before computing: a change during the computation invalidates it.
    struct EventPaths {
        std::mutex mutex;
        std::uint64_t generation = ~std::uint64_t{0};
        std::unordered_map<NodeId, std::shared_ptr<const std::vector<NodeId>>> typeChains;
        std::unordered_map<NodeId, std::shared_ptr<const std::vector<NodeId>>> notifiers;
    };
    mutable EventPaths eventPaths;
    static constexpr std::size_t kMaxCachedPaths = 4096;  // bounded: sources come from users

    using Paths = std::shared_ptr<const std::vector<NodeId>>;
    Paths cachedPath(bool typeChainOf, const NodeId& node) const {
        const std::uint64_t gen = as.structureGeneration();
        auto& map = typeChainOf ? eventPaths.typeChains : eventPaths.notifiers;
        {
            std::lock_guard lock(eventPaths.mutex);
            if (eventPaths.generation != gen) {
                eventPaths.typeChains.clear();
                eventPaths.notifiers.clear();
                eventPaths.generation = gen;
            }
            auto it = map.find(node);
            if (it != map.end()) return it->second;
        }
        auto path = std::make_shared<const std::vector<NodeId>>(typeChainOf ? typeChain(node)
                                                                            : notifiersOf(node));
        std::lock_guard lock(eventPaths.mutex);
        if (eventPaths.generation == gen) {
            if (map.size() >= kMaxCachedPaths) map.clear();
            map.emplace(node, path);
        }
        return path;
    }
};

SubscriptionEngine::SubscriptionEngine(AddressSpace& addressSpace, SubscriptionLimits limits,
                                       DecodeLimits decodeLimits)
    : impl_(std::make_unique<Impl>(addressSpace, limits, decodeLimits)) {
    addressSpace.setValueListener([impl = impl_.get()](const NodeId& n, const DataValue& v) {
        if (impl->watchedValues.load(std::memory_order_relaxed) != 0) impl->onValue(n, v);
    });
}

SubscriptionEngine::~SubscriptionEngine() {
    stop();
    impl_->as.setValueListener({});
}

void SubscriptionEngine::start() {
    std::lock_guard lock(impl_->mutex);
    if (impl_->timer.joinable()) return;
    impl_->stopping = false;
    impl_->timer = std::thread([this] { impl_->run(); });
}

void SubscriptionEngine::stop() {
    {
        std::lock_guard lock(impl_->mutex);
        impl_->stopping = true;
    }
    impl_->wake.notify_all();
    if (impl_->timer.joinable()) impl_->timer.join();
}

// ---- subscription services ------------------------------------------------------------------
void SubscriptionEngine::createSubscription(const NodeId& session,
                                            const CreateSubscriptionRequest& req,
                                            CreateSubscriptionResponse& resp) {
    Impl& m = *impl_;
    std::lock_guard lock(m.mutex);
    auto& st = m.sessions[session];
    if (st.subscriptions.size() >= m.limits.maxSubscriptionsPerSession) {
        resp.responseHeader.serviceResult = status::BadTooManySubscriptions;
        return;
    }
    auto s = std::make_unique<Subscription>();
    s->id = m.nextSubscriptionId++;
    if (m.nextSubscriptionId == 0) m.nextSubscriptionId = 1;
    s->session = session;
    s->publishingInterval = m.revisePublishingInterval(req.requestedPublishingInterval);
    m.reviseCounts(*s, req.requestedLifetimeCount, req.requestedMaxKeepAliveCount);
    s->maxNotificationsPerPublish =
        req.maxNotificationsPerPublish == 0
            ? m.limits.maxNotificationsPerPublish
            : std::min(req.maxNotificationsPerPublish, m.limits.maxNotificationsPerPublish);
    s->publishingEnabled = req.publishingEnabled;
    s->priority = req.priority;
    auto now = Clock::now();
    s->nextCycle = now + toDuration(s->publishingInterval);
    s->lastMessage = now;
    resp.subscriptionId = s->id;
    resp.revisedPublishingInterval = s->publishingInterval;
    resp.revisedLifetimeCount = s->lifetimeCount;
    resp.revisedMaxKeepAliveCount = s->maxKeepAliveCount;
    st.subscriptions.push_back(s->id);
    m.subscriptions.emplace(s->id, std::move(s));
    m.wake.notify_one();
}

void SubscriptionEngine::modifySubscription(const NodeId& session,
                                            const ModifySubscriptionRequest& req,
                                            ModifySubscriptionResponse& resp) {
    Impl& m = *impl_;
    auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
    if (!s) return;
    s->publishingInterval = m.revisePublishingInterval(req.requestedPublishingInterval);
    m.reviseCounts(*s, req.requestedLifetimeCount, req.requestedMaxKeepAliveCount);
    s->maxNotificationsPerPublish =
        req.maxNotificationsPerPublish == 0
            ? m.limits.maxNotificationsPerPublish
            : std::min(req.maxNotificationsPerPublish, m.limits.maxNotificationsPerPublish);
    s->priority = req.priority;
    s->nextCycle = Clock::now() + toDuration(s->publishingInterval);
    resp.revisedPublishingInterval = s->publishingInterval;
    resp.revisedLifetimeCount = s->lifetimeCount;
    resp.revisedMaxKeepAliveCount = s->maxKeepAliveCount;
    m.wake.notify_one();
}

void SubscriptionEngine::deleteSubscriptions(const NodeId& session,
                                             const DeleteSubscriptionsRequest& req,
                                             DeleteSubscriptionsResponse& resp) {
    Impl& m = *impl_;
    std::lock_guard lock(m.mutex);
    resp.results = m.eachSubscription(session, req.subscriptionIds,
                                      [&](Subscription& s) { m.deleteSubscription(s.id); });
    m.releasePublishes(session);
}

void SubscriptionEngine::setPublishingMode(const NodeId& session,
                                           const SetPublishingModeRequest& req,
                                           SetPublishingModeResponse& resp) {
    Impl& m = *impl_;
    std::lock_guard lock(m.mutex);
    resp.results = m.eachSubscription(session, req.subscriptionIds, [&](Subscription& s) {
        s.publishingEnabled = req.publishingEnabled;
    });
}

void SubscriptionEngine::republish(const NodeId& session, const RepublishRequest& req,
                                   RepublishResponse& resp) {
    Impl& m = *impl_;
    auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
    if (!s) return;
    for (const auto& msg : s->retransmission) {
        if (msg.sequenceNumber == req.retransmitSequenceNumber) {
            resp.notificationMessage = msg;
            return;
        }
    }
    resp.responseHeader.serviceResult = status::BadMessageNotAvailable;
}

void SubscriptionEngine::publish(const NodeId& session, const Connection& conn, UInt32 requestId,
                                 const PublishRequest& req) {
    Impl& m = *impl_;
    std::lock_guard lock(m.mutex);
    auto now = Clock::now();
    // More acknowledgements than messages that can be kept are not honest ones.
    if (req.subscriptionAcknowledgements.size() >
        std::size_t{m.limits.maxSubscriptionsPerSession} * m.limits.maxRetransmissionQueue) {
        conn->sendServiceFault(requestId, req.requestHeader.requestHandle,
                               status::BadTooManyOperations);
        return;
    }
    auto& st = m.sessions[session];
    PendingPublish p;
    p.conn = conn;
    p.requestId = requestId;
    p.requestHandle = req.requestHeader.requestHandle;
    if (req.requestHeader.timeoutHint != 0)
        p.deadline = now + std::chrono::milliseconds(req.requestHeader.timeoutHint);
    for (const auto& ack : req.subscriptionAcknowledgements) {
        Subscription* s = m.find(session, ack.subscriptionId);
        if (s == nullptr) {
            p.ackResults.push_back(status::BadSubscriptionIdInvalid);
            continue;
        }
        auto it =
            std::find_if(s->retransmission.begin(), s->retransmission.end(),
                         [&](const auto& msg) { return msg.sequenceNumber == ack.sequenceNumber; });
        if (it == s->retransmission.end()) {
            p.ackResults.push_back(status::BadSequenceNumberUnknown);
        } else {
            s->retransmission.erase(it);
            p.ackResults.push_back(status::Good);
        }
    }
    for (UInt32 id : st.subscriptions)
        if (auto it = m.subscriptions.find(id); it != m.subscriptions.end())
            it->second->lifetimeCounter = 0;
    // A subscription that left the session (transferred, expired) says so first.
    if (!st.notices.empty()) {
        StatusNotice n = st.notices.front();
        st.notices.pop_front();
        m.sendNotice(p, n);
        return;
    }
    if (st.subscriptions.empty()) {
        conn->sendServiceFault(requestId, p.requestHandle, status::BadNoSubscription);
        return;
    }
    if (st.publishes.size() >= m.limits.maxPublishRequestsPerSession) {
        PendingPublish& old = st.publishes.front();
        old.conn->sendServiceFault(old.requestId, old.requestHandle,
                                   status::BadTooManyPublishRequests);
        st.publishes.pop_front();
    }
    st.publishes.push_back(std::move(p));
    m.serveLate(session, now);
}

// ---- monitored item services ----------------------------------------------------------------
void SubscriptionEngine::createMonitoredItems(const NodeId& session,
                                              const CreateMonitoredItemsRequest& req,
                                              CreateMonitoredItemsResponse& resp) {
    Impl& m = *impl_;
    auto tsr = static_cast<Int32>(req.timestampsToReturn);
    if (tsr < 0 || tsr > 3) {
        resp.responseHeader.serviceResult = status::BadTimestampsToReturnInvalid;
        return;
    }
    double publishingInterval = 0;
    {
        auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
        if (!s) return;
        publishingInterval = s->publishingInterval;
    }
    // Node and filter checks read the address space: without the engine's lock.
    std::vector<Impl::ItemSetup> setups;
    setups.reserve(req.itemsToCreate.size());
    for (const auto& c : req.itemsToCreate) {
        auto mode = static_cast<Int32>(c.monitoringMode);
        if (mode < 0 || mode > 2) {
            Impl::ItemSetup bad;
            bad.status = status::BadMonitoringModeInvalid;
            setups.push_back(std::move(bad));
            continue;
        }
        setups.push_back(m.setUp(c.itemToMonitor, c.requestedParameters, publishingInterval));
    }
    std::vector<ItemPtr> created;
    {
        auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
        if (!s) return;
        for (std::size_t i = 0; i < req.itemsToCreate.size(); ++i) {
            const auto& c = req.itemsToCreate[i];
            auto& setup = setups[i];
            MonitoredItemCreateResult r;
            r.filterResult = std::move(setup.filterResult);
            if (setup.status.isGood() &&
                s->items.size() >= m.limits.maxMonitoredItemsPerSubscription)
                setup.status = status::BadTooManyMonitoredItems;
            r.statusCode = setup.status;
            if (setup.status.isBad()) {
                resp.results.push_back(std::move(r));
                continue;
            }
            auto item = std::make_shared<MonitoredItem>();
            item->id = s->nextItemId++;
            item->clientHandle = c.requestedParameters.clientHandle;
            item->subscription = s.get();
            item->itemToMonitor = c.itemToMonitor;
            item->mode = c.monitoringMode;
            item->timestamps = req.timestampsToReturn;
            item->samplingInterval = setup.samplingInterval;
            item->queueSize = setup.queueSize;
            item->discardOldest = c.requestedParameters.discardOldest;
            item->isEvent = c.itemToMonitor.attributeId == kAttrEventNotifier;
            item->eventDriven = setup.eventDriven;
            item->trigger = setup.trigger;
            item->deadband = setup.deadband;
            item->eventFilter = std::move(setup.eventFilter);
            s->items.emplace(item->id, item);
            ++m.itemCount;
            m.attach(item, s->publishingInterval);
            if (!item->isEvent) created.push_back(item);
            r.monitoredItemId = item->id;
            r.revisedSamplingInterval = item->samplingInterval;
            r.revisedQueueSize = item->queueSize;
            resp.results.push_back(std::move(r));
        }
    }
    // The first value of every data item (§5.12.1.2), read without the engine's lock;
    // applyValue() drops it if the listener delivered a newer one meanwhile.
    if (created.empty()) return;
    ReadRequest read;
    read.timestampsToReturn = TimestampsToReturn::Both;
    for (const auto& item : created) read.nodesToRead.push_back(item->itemToMonitor);
    ReadResponse values = m.as.read(read);
    std::lock_guard lock(m.mutex);
    for (std::size_t i = 0; i < created.size() && i < values.results.size(); ++i)
        m.applyValue(created[i], std::move(values.results[i]));
}

void SubscriptionEngine::modifyMonitoredItems(const NodeId& session,
                                              const ModifyMonitoredItemsRequest& req,
                                              ModifyMonitoredItemsResponse& resp) {
    Impl& m = *impl_;
    auto tsr = static_cast<Int32>(req.timestampsToReturn);
    if (tsr < 0 || tsr > 3) {
        resp.responseHeader.serviceResult = status::BadTimestampsToReturnInvalid;
        return;
    }
    struct Target {
        ReadValueId what;
        double publishingInterval = 0;
        bool found = false;
    };
    std::vector<Target> targets(req.itemsToModify.size());
    {
        auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
        if (!s) return;
        for (std::size_t i = 0; i < req.itemsToModify.size(); ++i) {
            auto it = s->items.find(req.itemsToModify[i].monitoredItemId);
            if (it == s->items.end()) continue;
            targets[i] = {it->second->itemToMonitor, s->publishingInterval, true};
        }
    }
    std::vector<Impl::ItemSetup> setups(req.itemsToModify.size());
    for (std::size_t i = 0; i < targets.size(); ++i)
        if (targets[i].found)
            setups[i] = m.setUp(targets[i].what, req.itemsToModify[i].requestedParameters,
                                targets[i].publishingInterval);
    auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
    if (!s) return;
    for (std::size_t i = 0; i < req.itemsToModify.size(); ++i) {
        MonitoredItemModifyResult r;
        auto it = s->items.find(req.itemsToModify[i].monitoredItemId);
        if (!targets[i].found || it == s->items.end()) {
            r.statusCode = status::BadMonitoredItemIdInvalid;
            resp.results.push_back(std::move(r));
            continue;
        }
        auto& setup = setups[i];
        r.statusCode = setup.status;
        r.filterResult = std::move(setup.filterResult);
        if (setup.status.isBad()) {
            resp.results.push_back(std::move(r));
            continue;
        }
        const ItemPtr& item = it->second;
        const auto& p = req.itemsToModify[i].requestedParameters;
        m.detach(*item);
        item->deleted = false;
        item->clientHandle = p.clientHandle;
        item->timestamps = req.timestampsToReturn;
        item->samplingInterval = setup.samplingInterval;
        item->queueSize = setup.queueSize;
        item->discardOldest = p.discardOldest;
        item->eventDriven = setup.eventDriven;
        item->trigger = setup.trigger;
        item->deadband = setup.deadband;
        if (item->isEvent) item->eventFilter = std::move(setup.eventFilter);
        while (item->values.size() > item->queueSize) item->values.erase(item->values.begin());
        while (item->events.size() > item->queueSize) item->events.erase(item->events.begin());
        m.attach(item, s->publishingInterval);
        r.revisedSamplingInterval = item->samplingInterval;
        r.revisedQueueSize = item->queueSize;
        resp.results.push_back(std::move(r));
    }
}

void SubscriptionEngine::deleteMonitoredItems(const NodeId& session,
                                              const DeleteMonitoredItemsRequest& req,
                                              DeleteMonitoredItemsResponse& resp) {
    Impl& m = *impl_;
    auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
    if (!s) return;
    for (UInt32 id : req.monitoredItemIds) {
        auto it = s->items.find(id);
        if (it == s->items.end()) {
            resp.results.push_back(status::BadMonitoredItemIdInvalid);
            continue;
        }
        m.detach(*it->second);
        s->items.erase(it);
        --m.itemCount;
        resp.results.push_back(status::Good);
    }
    std::erase_if(s->pending, [](const ItemPtr& i) { return i->deleted; });
}

void SubscriptionEngine::setMonitoringMode(const NodeId& session,
                                           const SetMonitoringModeRequest& req,
                                           SetMonitoringModeResponse& resp) {
    Impl& m = *impl_;
    auto mode = static_cast<Int32>(req.monitoringMode);
    if (mode < 0 || mode > 2) {
        resp.responseHeader.serviceResult = status::BadMonitoringModeInvalid;
        return;
    }
    auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
    if (!s) return;
    for (UInt32 id : req.monitoredItemIds) {
        auto it = s->items.find(id);
        if (it == s->items.end()) {
            resp.results.push_back(status::BadMonitoredItemIdInvalid);
            continue;
        }
        MonitoredItem& item = *it->second;
        MonitoringMode before = item.mode;
        item.mode = req.monitoringMode;
        if (item.mode == MonitoringMode::Disabled) {
            item.values.clear();
            item.events.clear();
            item.last.reset();  // re-enabling reports the current value again
        } else if (item.mode == MonitoringMode::Reporting && before == MonitoringMode::Sampling &&
                   item.hasQueued()) {
            m.markPending(*s, it->second);
        }
        resp.results.push_back(status::Good);
    }
}

void SubscriptionEngine::setTriggering(const NodeId& session, const SetTriggeringRequest& req,
                                       SetTriggeringResponse& resp) {
    Impl& m = *impl_;
    auto s = m.lockSubscription(session, req.subscriptionId, resp.responseHeader);
    if (!s) return;
    auto trig = s->items.find(req.triggeringItemId);
    if (trig == s->items.end()) {
        resp.responseHeader.serviceResult = status::BadMonitoredItemIdInvalid;
        return;
    }
    auto& links = trig->second->links;
    for (UInt32 id : req.linksToAdd) {
        if (s->items.find(id) == s->items.end()) {
            resp.addResults.push_back(status::BadMonitoredItemIdInvalid);
            continue;
        }
        if (std::find(links.begin(), links.end(), id) == links.end()) links.push_back(id);
        resp.addResults.push_back(status::Good);
    }
    for (UInt32 id : req.linksToRemove) {
        auto it = std::find(links.begin(), links.end(), id);
        if (it == links.end()) {
            resp.removeResults.push_back(status::BadMonitoredItemIdInvalid);
            continue;
        }
        links.erase(it);
        resp.removeResults.push_back(status::Good);
    }
}

void SubscriptionEngine::transferSubscriptions(const NodeId& session,
                                               const TransferSubscriptionsRequest& req,
                                               TransferSubscriptionsResponse& resp) {
    Impl& m = *impl_;
    std::lock_guard lock(m.mutex);
    auto now = Clock::now();
    SessionState& target = m.sessions[session];
    for (UInt32 id : req.subscriptionIds) {
        TransferResult r;
        auto it = m.subscriptions.find(id);
        if (it == m.subscriptions.end()) {
            r.statusCode = status::BadSubscriptionIdInvalid;
            resp.results.push_back(std::move(r));
            continue;
        }
        Subscription& s = *it->second;
        if (s.session != session) {
            auto from = m.sessions.find(s.session);
            if (from == m.sessions.end() || !sameUser(from->second.user, target.user))
                r.statusCode = status::BadUserAccessDenied;
            else if (target.subscriptions.size() >= m.limits.maxSubscriptionsPerSession)
                r.statusCode = status::BadTooManySubscriptions;
            else
                m.move(s, session, target, now);
        }
        if (r.statusCode.isGood()) {
            if (req.sendInitialValues) m.queueInitialValues(s);
            for (const auto& msg : s.retransmission)
                r.availableSequenceNumbers.push_back(msg.sequenceNumber);
        }
        resp.results.push_back(std::move(r));
    }
    m.wake.notify_one();
}

void SubscriptionEngine::setSessionUser(const NodeId& session, const SessionIdentity& user) {
    std::lock_guard lock(impl_->mutex);
    impl_->sessions[session].user = user;
}

void SubscriptionEngine::removeSession(const NodeId& session, bool deleteSubscriptions) {
    Impl& m = *impl_;
    std::lock_guard lock(m.mutex);
    auto st = m.sessions.find(session);
    if (st == m.sessions.end()) return;
    for (auto& p : st->second.publishes)
        p.conn->sendServiceFault(p.requestId, p.requestHandle, status::BadSessionClosed);
    st->second.publishes.clear();
    st->second.notices.clear();
    // Kept subscriptions go on counting their lifetime (no Publish requests can come).
    auto& subs = st->second.subscriptions;
    const std::size_t keep =
        deleteSubscriptions
            ? 0
            : std::min(subs.size(), m.limits.maxKeptSubscriptions -
                                        std::min<std::size_t>(m.keptSubscriptions,
                                                              m.limits.maxKeptSubscriptions));
    while (subs.size() > keep) m.deleteSubscription(subs.back());
    if (subs.empty()) {
        m.sessions.erase(st);
        return;
    }
    st->second.closed = true;
    m.keptSubscriptions += subs.size();
}

// ---- events -----------------------------------------------------------------------------------
void SubscriptionEngine::fireEvent(Event event) {
    Impl& m = *impl_;
    if (event.sourceNode.isNull()) event.sourceNode = NodeId(0, ns0::Server);
    if (event.eventId.empty()) event.eventId = randomEventId();
    if (!event.time) event.time = DateTime::now();
    EventRecord r;
    r.receiveTime = DateTime::now();
    r.typeChain = m.cachedPath(true, event.eventType);
    r.event = std::move(event);
    const Impl::Paths notifiers = m.cachedPath(false, r.event.sourceNode);
    // A session receives events from a notifier only with the ReceiveEvents permission on it
    // (OPC 10000-3 §8.55); the rules are looked up before the engine's lock (lock order).
    std::vector<AddressSpace::EffectivePermissions> receive;
    if (m.as.enforcesPermissions()) {
        receive.reserve(notifiers->size());
        for (const NodeId& n : *notifiers) receive.push_back(m.as.effectivePermissions(n));
    }

    Impl::Connections sentOn;
    {
        std::lock_guard lock(m.mutex);
        auto now = Clock::now();
        std::vector<Subscription*> touched;
        for (std::size_t ni = 0; ni < notifiers->size(); ++ni) {
            const NodeId& n = (*notifiers)[ni];
            auto it = m.eventWatchers.find(n);
            if (it == m.eventWatchers.end()) continue;
            for (MonitoredItem* raw : it->second) {
                if (raw->mode == MonitoringMode::Disabled || !raw->eventFilter) continue;
                if (!receive.empty()) {
                    auto st = m.sessions.find(raw->subscription->session);
                    const SessionIdentity none;
                    const SessionIdentity& user = st == m.sessions.end() ? none : st->second.user;
                    if ((receive[ni].of(user) & permission::ReceiveEvents) == 0) continue;
                }
                const CompiledEventFilter& f = *raw->eventFilter;
                if (!matches(r, f)) continue;
                std::vector<Variant> fields;
                fields.reserve(f.select.size());
                TypeCheck isOfType(r);
                for (const auto& sel : f.select) fields.push_back(fieldValue(r, sel, isOfType));
                auto& q = raw->events;
                if (q.size() >= raw->queueSize) {
                    if (raw->discardOldest)
                        q.erase(q.begin());
                    else
                        q.pop_back();
                }
                q.push_back(std::move(fields));
                Subscription& s = *raw->subscription;
                auto item = s.items.find(raw->id);
                if (item != s.items.end() && m.report(item->second)) touched.push_back(&s);
            }
        }
        for (Subscription* s : touched) m.publishEarly(*s, now, sentOn);
    }
    Impl::flush(sentOn);
}

SubscriptionEngine::Statistics SubscriptionEngine::statistics() const {
    std::lock_guard lock(impl_->mutex);
    Statistics st;
    st.subscriptions = impl_->subscriptions.size();
    st.monitoredItems = impl_->itemCount;
    for (const auto& [_, s] : impl_->sessions) st.queuedPublishRequests += s.publishes.size();
    st.notificationMessagesSent = impl_->messagesSent;
    st.samples = impl_->samples;
    return st;
}

}  // namespace pnp::ua::server
