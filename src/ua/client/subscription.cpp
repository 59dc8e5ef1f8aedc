#include "ua/client/subscription.hpp"

#include <algorithm>

#include "ua/client/subscription_engine.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {

namespace {

constexpr UInt32 kMaxRepublishPerGap = 32;
constexpr std::size_t kMaxMissing = 64;  // per subscription

// Under the engine's lock: sequence numbers from..to are awaited (bounded: the oldest go).
void markMissing(SubscriptionState& sub, UInt32 from, UInt32 to) {
    for (UInt32 seq = from; seq <= to && seq >= from; ++seq)
        if (std::find(sub.missing.begin(), sub.missing.end(), seq) == sub.missing.end())
            sub.missing.push_back(seq);
    if (sub.missing.size() > kMaxMissing)
        sub.missing.erase(
            sub.missing.begin(),
            sub.missing.begin() + static_cast<std::ptrdiff_t>(sub.missing.size() - kMaxMissing));
}

// Under the engine's lock: true (and no longer awaited) when `seq` was missing.
bool takeMissing(SubscriptionState& sub, UInt32 seq) {
    auto it = std::find(sub.missing.begin(), sub.missing.end(), seq);
    if (it == sub.missing.end()) return false;
    sub.missing.erase(it);
    return true;
}
constexpr UInt32 kMaxConsecutivePublishErrors = 5;
constexpr std::size_t kItemsPerRequest = 1000;

// Publish failures after which the reconnect (and SessionChange) restarts publishing.
bool waitsForReconnect(StatusCode s) {
    switch (s.code()) {
        case status::BadConnectionClosed.value:
        case status::BadNotConnected.value:
        case status::BadSecureChannelClosed.value:
        case status::BadSecureChannelIdInvalid.value:
        case status::BadShutdown.value:
        case status::BadServerNotConnected.value:
        case status::BadCommunicationError.value:
        case status::BadDisconnect.value:
        case status::BadSessionIdInvalid.value:
        case status::BadSessionClosed.value:
        case status::BadSessionNotActivated.value:
            return true;
        default:
            return false;
    }
}

std::vector<QualifiedName> parseBrowsePath(std::string_view path) {
    std::vector<QualifiedName> out;
    while (!path.empty()) {
        std::size_t slash = path.find('/');
        std::string_view part = path.substr(0, slash);
        if (!part.empty()) out.push_back(QualifiedName::parse(part));
        if (slash == std::string_view::npos) break;
        path.remove_prefix(slash + 1);
    }
    return out;
}

// SimpleAttributeOperand with a null IndexRange (see services.hpp: node-opcua reads an empty,
// non-null NumericRange as invalid).
void encodeOperand(BinaryEncoder& e, const SimpleAttributeOperand& op) {
    encode(e, op.typeDefinitionId);
    encode(e, op.browsePath);
    encode(e, op.attributeId);
    detail::encodeIndexRange(e, op.indexRange);
}

ExtensionObject encodedObject(UInt32 encodingId, const Buffer& b) {
    ExtensionObject x;
    x.typeId = NodeId(0, encodingId);
    x.encoding = ExtensionObject::Encoding::Binary;
    x.body.assign(reinterpret_cast<const char*>(b.data()), b.size());
    return x;
}

ExtensionObject eventFilterObject(const EventOptions& o) {
    Buffer b;
    BinaryEncoder e(b);
    e.number<Int32>(static_cast<Int32>(o.select.size()));
    for (const auto& s : o.select) encodeOperand(e, eventField(s, o.eventType));
    encode(e, o.where);
    return encodedObject(DataTypeInfo<EventFilter>::binaryEncodingId, b);
}

MonitoringParameters dataParameters(UInt32 handle, const DataChangeOptions& o) {
    MonitoringParameters p{};
    p.clientHandle = handle;
    p.samplingInterval = o.samplingInterval;
    p.queueSize = o.queueSize;
    p.discardOldest = o.discardOldest;
    if (o.filter) p.filter = toExtensionObject(*o.filter);
    return p;
}

template <class T>
void runCallback(const T& f, auto&&... args) {
    if (!f) return;
    try {
        f(std::forward<decltype(args)>(args)...);
    } catch (...) {
        // Callbacks must not throw; there is nobody to report it to.
    }
}

StatusCode firstResult(const std::vector<StatusCode>& results, std::string_view service) {
    if (results.size() != 1)
        throw Error(status::BadUnexpectedError, std::string(service) + ": expected one result");
    return results.front();
}

}  // namespace

// ---- free helpers ----------------------------------------------------------------------------

const Variant* EventFields::get(std::string_view name) const {
    for (std::size_t i = 0; i < names_->size() && i < values_->size(); ++i)
        if ((*names_)[i] == name) return &(*values_)[i];
    return nullptr;
}

SimpleAttributeOperand eventField(std::string_view path, const NodeId& eventType) {
    SimpleAttributeOperand op{};
    op.typeDefinitionId = eventType;
    op.browsePath = parseBrowsePath(path);
    op.attributeId = static_cast<UInt32>(AttributeId::Value);
    return op;
}

ContentFilter whereOfType(const NodeId& eventType) {
    ContentFilterElement el{};
    el.filterOperator = FilterOperator::OfType;
    el.filterOperands.push_back(toExtensionObject(LiteralOperand{Variant(eventType)}));
    ContentFilter f;
    f.elements.push_back(std::move(el));
    return f;
}

// ---- engine ----------------------------------------------------------------------------------

void SubscriptionEngine::rebind(Client* client) {
    std::lock_guard lock(mutex_);
    client_ = client;
}

Client& SubscriptionEngine::client() {
    std::lock_guard lock(mutex_);
    if (!client_) throw Error(status::BadNotConnected, "the client of this subscription is gone");
    return *client_;
}

SubscriptionEngineStats SubscriptionEngine::stats() const {
    std::lock_guard lock(mutex_);
    return stats_;
}

void SubscriptionEngine::add(const std::shared_ptr<SubscriptionState>& sub) {
    {
        std::lock_guard lock(mutex_);
        subs_[sub->revised.subscriptionId] = sub;
    }
    fill();
}

void SubscriptionEngine::erase(const std::shared_ptr<SubscriptionState>& sub) {
    std::lock_guard lock(mutex_);
    auto it = subs_.find(sub->revised.subscriptionId);
    if (it != subs_.end() && it->second == sub) subs_.erase(it);
}

void SubscriptionEngine::fill() {
    // Bounded: at most maxOutstanding_ requests are sent per call.
    for (UInt32 i = 0; i < 8; ++i) {
        PublishRequest req{};
        Client* c = nullptr;
        std::uint64_t gen = 0;
        Clock::duration timeout{};
        {
            std::lock_guard lock(mutex_);
            UInt32 target =
                std::min<UInt32>(maxOutstanding_, static_cast<UInt32>(subs_.size()) + 1);
            if (!client_ || subs_.empty() || outstanding_ >= target) return;
            ++outstanding_;
            req.subscriptionAcknowledgements.swap(acks_);
            gen = generation_;
            c = client_;
            // A Publish is answered at the latest after a keep-alive period of the slowest
            // subscription; give it that twice plus the normal request timeout.
            Double longest = 0;
            for (const auto& [id, s] : subs_)
                longest = std::max(longest, s->revised.publishingInterval *
                                                std::max<UInt32>(1, s->revised.maxKeepAliveCount));
            timeout = std::chrono::duration_cast<Clock::duration>(
                          std::chrono::duration<double, std::milli>(2 * longest)) +
                      c->config().requestTimeout;
        }
        c->requestAsync<PublishRequest>(
            std::move(req),
            [w = weak_from_this(), gen](Result<PublishResponse> r) {
                if (auto e = w.lock()) e->onPublish(std::move(r), gen);
            },
            Deadline(timeout));
    }
}

void SubscriptionEngine::onPublish(Result<PublishResponse> r, std::uint64_t gen) {
    std::shared_ptr<SubscriptionState> sub;
    bool refill = false;
    bool keepAlive = false;
    bool duplicate = false;
    UInt32 gapFrom = 0, gapTo = 0;
    bool serverHasAnother = false;
    std::vector<std::shared_ptr<SubscriptionState>> errorTargets;
    {
        std::lock_guard lock(mutex_);
        if (gen != generation_) return;  // sent on a session that has been replaced
        if (outstanding_ > 0) --outstanding_;
        serverHasAnother = outstanding_ > 0;
        if (!r.ok()) {
            StatusCode s = r.status();
            if (s.code() == status::BadTimeout.code()) {
                // Not even a keep-alive for twice the keep-alive period: tell the user (the
                // server may be hung) and ask again.
                refill = true;
                for (const auto& [id, x] : subs_) errorTargets.push_back(x);
            } else if (s.code() == status::BadTooManyPublishRequests.code()) {
                maxOutstanding_ = std::max<UInt32>(1, outstanding_);
            } else if (s.code() == status::BadNoSubscription.code() || waitsForReconnect(s)) {
                // Publishing restarts with the next subscription or the next session change.
            } else {
                refill = ++consecutiveErrors_ < kMaxConsecutivePublishErrors;
                for (const auto& [id, x] : subs_) errorTargets.push_back(x);
            }
        } else {
            consecutiveErrors_ = 0;
            ++stats_.publishResponses;
            PublishResponse& p = r.value();
            NotificationMessage& m = p.notificationMessage;
            keepAlive = m.notificationData.empty();
            if (!keepAlive) acks_.push_back({p.subscriptionId, m.sequenceNumber});
            auto it = subs_.find(p.subscriptionId);
            if (it == subs_.end()) {
                ++stats_.unknownHandles;
            } else {
                sub = it->second;
                // A keep-alive carries the next sequence number, a notification its own.
                UInt32 expected = sub->lastSequence + 1;
                if (m.sequenceNumber > expected) {
                    gapFrom = expected;
                    gapTo = std::min(m.sequenceNumber - 1, expected + kMaxRepublishPerGap - 1);
                    markMissing(*sub, gapFrom, gapTo);
                }
                // One that is not above the highest seen is delivered only if it was missing.
                if (!keepAlive && m.sequenceNumber > 0 && m.sequenceNumber < expected)
                    duplicate = !takeMissing(*sub, m.sequenceNumber);
                UInt32 seen = keepAlive ? m.sequenceNumber - 1 : m.sequenceNumber;
                if (m.sequenceNumber > 0) sub->lastSequence = std::max(sub->lastSequence, seen);
                if (keepAlive) ++stats_.keepAlives;
                if (duplicate) ++stats_.duplicates;
            }
            refill = true;
        }
    }
    // The server must always hold a Publish. If it still has one, the callbacks run first
    // (the send would delay them: latency); otherwise the next Publish goes out first.
    if (refill && !serverHasAnother) fill();
    for (const auto& s : errorTargets)
        report(s, SubscriptionStatus::Kind::PublishError, r.status(),
               r.error() ? r.error()->what() : "");
    if (r.ok() && sub) {
        if (keepAlive)
            report(sub, SubscriptionStatus::Kind::KeepAlive, StatusCode{}, {});
        else if (!duplicate)
            dispatch(sub, r.value().notificationMessage);
    }
    if (refill && serverHasAnother) fill();
    if (sub && gapTo >= gapFrom && gapFrom != 0) republish(sub, gapFrom, gapTo);
}

void SubscriptionEngine::report(const std::shared_ptr<SubscriptionState>& sub,
                                SubscriptionStatus::Kind kind, StatusCode s, std::string message) {
    runCallback(sub->onStatus, SubscriptionStatus{kind, s, std::move(message)});
}

// The items that notifications are for (null for unknown client handles), looked up under
// the lock; the callbacks then run without it.
template <class Notification>
std::vector<std::shared_ptr<MonitoredItemState>> SubscriptionEngine::itemsOf(
    const SubscriptionState& sub, const std::vector<Notification>& notifications) {
    std::vector<std::shared_ptr<MonitoredItemState>> targets(notifications.size());
    std::lock_guard lock(mutex_);
    for (std::size_t i = 0; i < targets.size(); ++i) {
        auto it = sub.items.find(notifications[i].clientHandle);
        if (it != sub.items.end())
            targets[i] = it->second;
        else
            ++stats_.unknownHandles;
    }
    return targets;
}

void SubscriptionEngine::dispatch(const std::shared_ptr<SubscriptionState>& sub,
                                  NotificationMessage& message) {
    DecodeLimits limits;
    {
        std::lock_guard lock(mutex_);
        if (client_) limits = client_->config().decodeLimits;
    }
    for (const ExtensionObject& x : message.notificationData) {
        try {
            if (auto dc = fromExtensionObject<DataChangeNotification>(x, limits)) {
                auto targets = itemsOf(*sub, dc->monitoredItems);
                for (std::size_t i = 0; i < targets.size(); ++i)
                    if (targets[i]) runCallback(targets[i]->onData, dc->monitoredItems[i].value);
            } else if (auto ev = fromExtensionObject<EventNotificationList>(x, limits)) {
                auto targets = itemsOf(*sub, ev->events);
                for (std::size_t i = 0; i < targets.size(); ++i) {
                    if (!targets[i] || !targets[i]->onEvent) continue;
                    EventFields fields(targets[i]->selectNames, ev->events[i].eventFields);
                    runCallback(targets[i]->onEvent, fields);
                }
            } else if (auto sc = fromExtensionObject<StatusChangeNotification>(x, limits)) {
                if (sc->status.isBad()) {
                    std::lock_guard lock(mutex_);
                    sub->lost = true;
                    auto it = subs_.find(sub->revised.subscriptionId);
                    if (it != subs_.end() && it->second == sub) subs_.erase(it);
                }
                report(sub, SubscriptionStatus::Kind::StatusChanged, sc->status,
                       "StatusChangeNotification");
            } else {
                std::lock_guard lock(mutex_);
                ++stats_.malformed;  // a notification type we do not know
            }
        } catch (const DecodeError&) {
            std::lock_guard lock(mutex_);
            ++stats_.malformed;
        }
    }
}

void SubscriptionEngine::republish(const std::shared_ptr<SubscriptionState>& sub, UInt32 from,
                                   UInt32 to) {
    Client* c = nullptr;
    {
        std::lock_guard lock(mutex_);
        c = client_;
    }
    if (!c) return;
    for (UInt32 seq = from; seq <= to && seq >= from; ++seq) {
        RepublishRequest req{};
        req.subscriptionId = sub->revised.subscriptionId;
        req.retransmitSequenceNumber = seq;
        c->requestAsync<RepublishRequest>(
            std::move(req), [w = weak_from_this(), sub, seq](Result<RepublishResponse> r) {
                auto e = w.lock();
                if (!e || !r.ok()) return;  // BadMessageNotAvailable: gone for good
                {
                    std::lock_guard lock(e->mutex_);
                    e->acks_.push_back({sub->revised.subscriptionId, seq});
                    // Arrived meanwhile by Publish (answered out of order): not twice.
                    if (!takeMissing(*sub, seq)) {
                        ++e->stats_.duplicates;
                        return;
                    }
                    ++e->stats_.republished;
                }
                e->dispatch(sub, r.value().notificationMessage);
            });
    }
}

void SubscriptionEngine::sessionChanged(SessionChange change) {
    {
        std::lock_guard lock(mutex_);
        ++generation_;
        outstanding_ = 0;
        consecutiveErrors_ = 0;
        if (change == SessionChange::Recreated) acks_.clear();
        if (subs_.empty()) return;
    }
    try {
        recover(change);
    } catch (const Error&) {
        // The connection dropped again: the next session change starts over.
    }
    fill();
}

void SubscriptionEngine::recover(SessionChange change) {
    std::vector<std::shared_ptr<SubscriptionState>> subs;
    {
        std::lock_guard lock(mutex_);
        for (const auto& [id, s] : subs_) subs.push_back(s);
    }
    if (change == SessionChange::Reactivated) {
        // The subscriptions are still there; the sequence numbers of the next messages show
        // what was missed, and onPublish republishes it.
        for (const auto& s : subs)
            report(s, SubscriptionStatus::Kind::Republished, StatusCode{},
                   "session re-activated on a new connection");
        return;
    }
    Client& c = client();
    TransferSubscriptionsRequest req{};
    for (const auto& s : subs) req.subscriptionIds.push_back(s->revised.subscriptionId);
    req.sendInitialValues = true;
    std::vector<TransferResult> results;
    try {
        results = c.request(std::move(req)).results;
    } catch (const Error& e) {
        if (waitsForReconnect(e.status())) throw;
        // BadServiceUnsupported and the like: recreate below.
    }
    for (std::size_t i = 0; i < subs.size(); ++i) {
        const auto& s = subs[i];
        if (results.size() == subs.size() && results[i].statusCode.isGood()) {
            report(s, SubscriptionStatus::Kind::Transferred, StatusCode{},
                   "transferred to the new session");
            UInt32 from = 0, to = 0;
            for (UInt32 seq : results[i].availableSequenceNumbers) {
                if (seq <= s->lastSequence) continue;
                if (from == 0 || seq < from) from = seq;
                to = std::max(to, seq);
            }
            if (from != 0) {
                to = std::min(to, from + kMaxRepublishPerGap - 1);
                {
                    std::lock_guard lock(mutex_);
                    markMissing(*s, from, to);
                    s->lastSequence = std::max(s->lastSequence, to);
                }
                republish(s, from, to);
            }
            continue;
        }
        UInt32 oldId = s->revised.subscriptionId;
        try {
            create(*s, {});
            std::vector<std::shared_ptr<MonitoredItemState>> items;
            {
                std::lock_guard lock(mutex_);
                for (const auto& [h, item] : s->items) items.push_back(item);
                subs_.erase(oldId);
                subs_[s->revised.subscriptionId] = s;
            }
            std::vector<StatusCode> statuses;
            createItems(*s, items, statuses, {});
            report(s, SubscriptionStatus::Kind::Recreated, StatusCode{},
                   "recreated on the new session");
        } catch (const Error& e) {
            if (waitsForReconnect(e.status())) throw;
            {
                std::lock_guard lock(mutex_);
                s->lost = true;
                auto it = subs_.find(oldId);
                if (it != subs_.end() && it->second == s) subs_.erase(it);
            }
            report(s, SubscriptionStatus::Kind::Lost, e.status(), e.what());
        }
    }
}

void SubscriptionEngine::create(SubscriptionState& sub, Deadline deadline) {
    CreateSubscriptionRequest req{};
    req.requestedPublishingInterval = sub.settings.publishingInterval;
    req.requestedLifetimeCount = sub.settings.lifetimeCount;
    req.requestedMaxKeepAliveCount = sub.settings.maxKeepAliveCount;
    req.maxNotificationsPerPublish = sub.settings.maxNotificationsPerPublish;
    req.publishingEnabled = sub.settings.publishingEnabled;
    req.priority = sub.settings.priority;
    CreateSubscriptionResponse resp = client().request(std::move(req), deadline);
    std::lock_guard lock(mutex_);
    sub.revised = {resp.subscriptionId, resp.revisedPublishingInterval, resp.revisedLifetimeCount,
                   resp.revisedMaxKeepAliveCount};
    sub.lastSequence = 0;
    sub.missing.clear();
    sub.lost = false;
}

void SubscriptionEngine::createItems(SubscriptionState& sub,
                                     const std::vector<std::shared_ptr<MonitoredItemState>>& items,
                                     std::vector<StatusCode>& statuses, Deadline deadline) {
    statuses.assign(items.size(), StatusCode{});
    Client& c = client();
    Clock::time_point dl = deadline.resolve(Clock::now(), c.config().requestTimeout);
    for (std::size_t start = 0; start < items.size(); start += kItemsPerRequest) {
        std::size_t end = std::min(items.size(), start + kItemsPerRequest);
        CreateMonitoredItemsRequest req{};
        std::vector<bool> fresh(end - start);  // registered here (not already, as on recreate)
        {
            // Registered before the request goes out: the server may send an item's first
            // notification (a held Publish answered at once) before the
            // CreateMonitoredItems response, and it must not be dropped as unknown.
            std::lock_guard lock(mutex_);
            req.subscriptionId = sub.revised.subscriptionId;
            req.timestampsToReturn = items[start]->timestamps;
            for (std::size_t i = start; i < end; ++i) {
                req.itemsToCreate.push_back(
                    {items[i]->itemToMonitor, items[i]->mode, items[i]->parameters});
                fresh[i - start] = sub.items.emplace(items[i]->clientHandle, items[i]).second;
            }
        }
        auto unregister = [&](std::size_t from, std::size_t to, bool onlyBad) {
            for (std::size_t i = from; i < to; ++i)
                if (fresh[i - from] && (!onlyBad || statuses[i].isBad()))
                    sub.items.erase(items[i]->clientHandle);
        };
        std::vector<MonitoredItemCreateResult> results;
        try {
            results = c.request(std::move(req), dl).results;
            if (results.size() != end - start)
                throw Error(status::BadUnexpectedError,
                            "CreateMonitoredItems: result count does not match the request");
        } catch (...) {
            std::lock_guard lock(mutex_);
            unregister(start, end, false);
            throw;
        }
        std::lock_guard lock(mutex_);
        for (std::size_t i = start; i < end; ++i) {
            const MonitoredItemCreateResult& r = results[i - start];
            statuses[i] = r.statusCode;
            items[i]->monitoredItemId = r.monitoredItemId;
            items[i]->revisedSamplingInterval = r.revisedSamplingInterval;
            items[i]->revisedQueueSize = r.revisedQueueSize;
        }
        unregister(start, end, true);
    }
}

// ---- Subscription ----------------------------------------------------------------------------

Subscription::Subscription(Client& client, SubscriptionSettings settings,
                           SubscriptionStatusCallback onStatus, Deadline deadline)
    : engine_(client.subscriptionEngine()), sub_(std::make_shared<SubscriptionState>()) {
    sub_->settings = settings;
    sub_->onStatus = std::move(onStatus);
    engine_->create(*sub_, deadline);
    engine_->add(sub_);
}

Subscription::~Subscription() {
    if (!sub_) return;
    try {
        remove(engine_->client().config().closeTimeout);
    } catch (...) {
    }
}

Subscription::Subscription(Subscription&& o) noexcept = default;

Subscription& Subscription::operator=(Subscription&& o) noexcept {
    if (this != &o) {
        Subscription old(std::move(*this));
        engine_ = std::move(o.engine_);
        sub_ = std::move(o.sub_);
    }
    return *this;
}

UInt32 Subscription::id() const {
    if (!sub_) return 0;
    std::lock_guard lock(engine_->mutex());
    return sub_->revised.subscriptionId;
}

RevisedSubscription Subscription::revised() const {
    if (!sub_) return {};
    std::lock_guard lock(engine_->mutex());
    return sub_->revised;
}

namespace {
void requireLive(const std::shared_ptr<SubscriptionState>& sub, std::string_view what) {
    if (!sub)
        throw Error(status::BadSubscriptionIdInvalid, std::string(what) + ": no subscription");
    if (sub->lost)
        throw Error(status::BadSubscriptionIdInvalid, std::string(what) + ": subscription lost");
}
}  // namespace

std::vector<MonitoredItem> Subscription::monitorValues(
    const std::vector<NodeId>& nodes,
    std::function<void(std::size_t index, const DataValue&)> callback,
    const DataChangeOptions& options, std::vector<StatusCode>* statuses, Deadline deadline) {
    requireLive(sub_, "CreateMonitoredItems");
    auto shared =
        std::make_shared<std::function<void(std::size_t, const DataValue&)>>(std::move(callback));
    std::vector<std::shared_ptr<MonitoredItemState>> items;
    items.reserve(nodes.size());
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        auto item = std::make_shared<MonitoredItemState>();
        item->clientHandle = engine_->nextClientHandle();
        item->itemToMonitor.nodeId = nodes[i];
        item->itemToMonitor.attributeId = static_cast<UInt32>(options.attribute);
        item->mode = options.mode;
        item->parameters = dataParameters(item->clientHandle, options);
        item->timestamps = options.timestamps;
        item->onData = [shared, i](const DataValue& v) { (*shared)(i, v); };
        items.push_back(std::move(item));
    }
    std::vector<StatusCode> results;
    engine_->createItems(*sub_, items, results, deadline);
    std::vector<MonitoredItem> out(items.size());
    for (std::size_t i = 0; i < items.size(); ++i) {
        if (results[i].isBad()) continue;  // createItems() registered only the good ones
        out[i].engine_ = engine_;
        out[i].sub_ = sub_;
        out[i].item_ = items[i];
    }
    if (statuses) *statuses = std::move(results);
    return out;
}

MonitoredItem Subscription::monitorValue(const NodeId& node, DataChangeCallback callback,
                                         const DataChangeOptions& options, Deadline deadline) {
    std::vector<StatusCode> statuses;
    auto items = monitorValues(
        {node}, [cb = std::move(callback)](std::size_t, const DataValue& v) { cb(v); }, options,
        &statuses, deadline);
    if (statuses.front().isBad())
        throw Error(statuses.front(), "CreateMonitoredItems of " + node.toString());
    return std::move(items.front());
}

MonitoredItem Subscription::monitorEvents(const NodeId& notifier, EventOptions options,
                                          EventCallback callback, Deadline deadline) {
    requireLive(sub_, "CreateMonitoredItems");
    auto item = std::make_shared<MonitoredItemState>();
    item->clientHandle = engine_->nextClientHandle();
    item->itemToMonitor.nodeId = notifier;
    item->itemToMonitor.attributeId = static_cast<UInt32>(AttributeId::EventNotifier);
    item->mode = options.mode;
    item->parameters.clientHandle = item->clientHandle;
    item->parameters.samplingInterval = 0;
    item->parameters.queueSize = options.queueSize;
    item->parameters.discardOldest = options.discardOldest;
    item->parameters.filter = eventFilterObject(options);
    item->timestamps = TimestampsToReturn::Neither;
    item->onEvent = std::move(callback);
    item->selectNames = std::move(options.select);
    std::vector<StatusCode> statuses;
    engine_->createItems(*sub_, {item}, statuses, deadline);
    if (statuses.front().isBad())
        throw Error(statuses.front(), "CreateMonitoredItems (events) of " + notifier.toString());
    MonitoredItem out;  // registered by createItems()
    out.engine_ = engine_;
    out.sub_ = sub_;
    out.item_ = std::move(item);
    return out;
}

void Subscription::modify(const SubscriptionSettings& settings, Deadline deadline) {
    requireLive(sub_, "ModifySubscription");
    ModifySubscriptionRequest req{};
    req.subscriptionId = id();
    req.requestedPublishingInterval = settings.publishingInterval;
    req.requestedLifetimeCount = settings.lifetimeCount;
    req.requestedMaxKeepAliveCount = settings.maxKeepAliveCount;
    req.maxNotificationsPerPublish = settings.maxNotificationsPerPublish;
    req.priority = settings.priority;
    auto resp = engine_->client().request(std::move(req), deadline);
    std::lock_guard lock(engine_->mutex());
    bool enabled = sub_->settings.publishingEnabled;  // changed by setPublishingEnabled only
    sub_->settings = settings;
    sub_->settings.publishingEnabled = enabled;
    sub_->revised.publishingInterval = resp.revisedPublishingInterval;
    sub_->revised.lifetimeCount = resp.revisedLifetimeCount;
    sub_->revised.maxKeepAliveCount = resp.revisedMaxKeepAliveCount;
}

void Subscription::setPublishingEnabled(bool enabled, Deadline deadline) {
    requireLive(sub_, "SetPublishingMode");
    SetPublishingModeRequest req{};
    req.publishingEnabled = enabled;
    req.subscriptionIds.push_back(id());
    StatusCode s = firstResult(engine_->client().request(std::move(req), deadline).results,
                               "SetPublishingMode");
    if (s.isBad()) throw Error(s, "SetPublishingMode");
    std::lock_guard lock(engine_->mutex());
    sub_->settings.publishingEnabled = enabled;
}

void Subscription::remove(Deadline deadline) {
    if (!sub_) return;
    auto sub = std::move(sub_);
    auto engine = std::move(engine_);
    engine->erase(sub);
    if (sub->lost) return;
    DeleteSubscriptionsRequest req{};
    {
        std::lock_guard lock(engine->mutex());
        req.subscriptionIds.push_back(sub->revised.subscriptionId);
        sub->lost = true;
    }
    StatusCode s = firstResult(engine->client().request(std::move(req), deadline).results,
                               "DeleteSubscriptions");
    if (s.isBad() && s.code() != status::BadSubscriptionIdInvalid.code())
        throw Error(s, "DeleteSubscriptions");
}

// ---- MonitoredItem ---------------------------------------------------------------------------

MonitoredItem::~MonitoredItem() {
    if (!item_) return;
    try {
        remove(engine_->client().config().closeTimeout);
    } catch (...) {
    }
}

MonitoredItem::MonitoredItem(MonitoredItem&&) noexcept = default;

MonitoredItem& MonitoredItem::operator=(MonitoredItem&& o) noexcept {
    if (this != &o) {
        MonitoredItem old(std::move(*this));
        engine_ = std::move(o.engine_);
        sub_ = std::move(o.sub_);
        item_ = std::move(o.item_);
    }
    return *this;
}

UInt32 MonitoredItem::id() const {
    if (!item_) return 0;
    std::lock_guard lock(engine_->mutex());
    return item_->monitoredItemId;
}

UInt32 MonitoredItem::clientHandle() const { return item_ ? item_->clientHandle : 0; }

Double MonitoredItem::revisedSamplingInterval() const {
    if (!item_) return 0;
    std::lock_guard lock(engine_->mutex());
    return item_->revisedSamplingInterval;
}

UInt32 MonitoredItem::revisedQueueSize() const {
    if (!item_) return 0;
    std::lock_guard lock(engine_->mutex());
    return item_->revisedQueueSize;
}

void MonitoredItem::setMonitoringMode(MonitoringMode mode, Deadline deadline) {
    if (!item_) throw Error(status::BadMonitoredItemIdInvalid, "SetMonitoringMode: no item");
    requireLive(sub_, "SetMonitoringMode");
    SetMonitoringModeRequest req{};
    {
        std::lock_guard lock(engine_->mutex());
        req.subscriptionId = sub_->revised.subscriptionId;
        req.monitoredItemIds.push_back(item_->monitoredItemId);
    }
    req.monitoringMode = mode;
    StatusCode s = firstResult(engine_->client().request(std::move(req), deadline).results,
                               "SetMonitoringMode");
    if (s.isBad()) throw Error(s, "SetMonitoringMode");
    std::lock_guard lock(engine_->mutex());
    item_->mode = mode;
}

void MonitoredItem::modify(const DataChangeOptions& options, Deadline deadline) {
    if (!item_) throw Error(status::BadMonitoredItemIdInvalid, "ModifyMonitoredItems: no item");
    requireLive(sub_, "ModifyMonitoredItems");
    ModifyMonitoredItemsRequest req{};
    MonitoringParameters p = dataParameters(item_->clientHandle, options);
    {
        std::lock_guard lock(engine_->mutex());
        req.subscriptionId = sub_->revised.subscriptionId;
        req.itemsToModify.push_back({item_->monitoredItemId, p});
    }
    req.timestampsToReturn = options.timestamps;
    auto results = engine_->client().request(std::move(req), deadline).results;
    if (results.size() != 1)
        throw Error(status::BadUnexpectedError, "ModifyMonitoredItems: expected one result");
    if (results.front().statusCode.isBad())
        throw Error(results.front().statusCode, "ModifyMonitoredItems");
    std::lock_guard lock(engine_->mutex());
    item_->parameters = std::move(p);
    item_->timestamps = options.timestamps;
    item_->revisedSamplingInterval = results.front().revisedSamplingInterval;
    item_->revisedQueueSize = results.front().revisedQueueSize;
}

void MonitoredItem::remove(Deadline deadline) {
    if (!item_) return;
    auto item = std::move(item_);
    auto sub = std::move(sub_);
    auto engine = std::move(engine_);
    DeleteMonitoredItemsRequest req{};
    {
        std::lock_guard lock(engine->mutex());
        sub->items.erase(item->clientHandle);
        if (sub->lost) return;  // gone with its subscription
        req.subscriptionId = sub->revised.subscriptionId;
        req.monitoredItemIds.push_back(item->monitoredItemId);
    }
    StatusCode s = firstResult(engine->client().request(std::move(req), deadline).results,
                               "DeleteMonitoredItems");
    if (s.isBad() && s.code() != status::BadMonitoredItemIdInvalid.code())
        throw Error(s, "DeleteMonitoredItems");
}

}  // namespace pnp::ua::client
