// Subscriptions, monitored items and events (OPC 10000-4 §5.12, §5.13, §7.22, §7.4).
//
// The SubscriptionEngine holds every session's subscriptions and monitored items and the
// Publish requests waiting for them. The Server forwards the subscription services to it
// (on the network thread) and tells it when a session ends.
//
// Threads and locks: the engine has one mutex of its own and one timer thread. The timer
// thread runs every subscription's publishing cycle and samples the items that need
// sampling, grouped by sampling interval (one timer entry per interval, not per item: 10,000
// items at 100 ms are one batched Read every 100 ms). Items with sampling interval 0 on a
// variable's Value are driven by AddressSpace::setValue / Write (the address space's value
// listener), so a change is queued without waiting for a timer, and a waiting Publish
// request is answered at once when the publishing interval allows. The engine never calls
// into the AddressSpace while it holds its mutex (the listener is called with the address
// space locked, so the order is always address space -> engine). Responses go out with
// ServerConnection::send(), which is thread-safe; nothing here blocks an event loop.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <thread>
#include <unordered_map>
#include <vector>

#include "ua/server/access_control.hpp"
#include "ua/server/address_space.hpp"
#include "ua/transport/tcp_server.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

// Server limits; every count from the wire is bounded by one of them. Revised values stay
// within [min, max].
struct SubscriptionLimits {
    UInt32 maxSubscriptionsPerSession = 100;
    UInt32 maxMonitoredItemsPerSubscription = 100000;
    UInt32 maxMonitoredItemsPerCall = 10000;  // Create/Modify/Delete/SetMonitoringMode
    UInt32 maxPublishRequestsPerSession = 20;
    // Kept after their session ended (CloseSession without deleteSubscriptions, session
    // timeout), waiting for TransferSubscriptions; beyond this they are deleted at once.
    UInt32 maxKeptSubscriptions = 1000;
    UInt32 maxRetransmissionQueue = 32;         // kept NotificationMessages per subscription
    UInt32 maxNotificationsPerPublish = 10000;  // server cap (0 from the client: this)
    UInt32 maxQueueSize = 1000;                 // per monitored item
    Double minPublishingIntervalMs = 10;
    Double maxPublishingIntervalMs = 3600000;
    Double minSamplingIntervalMs = 10;  // 0 (event-driven) stays 0 where possible
    Double maxSamplingIntervalMs = 3600000;
    UInt32 maxKeepAliveCount = 10000;
    UInt32 maxLifetimeCount = 300000;
    UInt32 maxSelectClauses = 64;        // EventFilter
    UInt32 maxWhereClauseElements = 64;  // EventFilter
};

// An event to fire (OPC 10000-5 §6.4.2 BaseEventType). Unset fields get defaults: EventId a
// random 16-byte id, Time and ReceiveTime now, SourceNode the Server object.
struct Event {
    NodeId eventType = NodeId(0, ns0::BaseEventType);
    NodeId sourceNode;
    String sourceName;
    std::optional<DateTime> time;
    LocalizedText message;
    UInt16 severity = 500;
    ByteString eventId;
    using Fields = std::vector<std::pair<std::vector<QualifiedName>, Variant>>;
    // Further fields (of the event type or its subtypes) by browse path from the event.
    Fields fields;
    // More of them, shared by many events of one kind (e.g. a state machine's transition:
    // Transition, FromState, ToState) rather than copied into each. `fields` win when both
    // have a path.
    std::shared_ptr<const Fields> sharedFields;

    Event& set(const QualifiedName& name, Variant value) {
        fields.push_back({{name}, std::move(value)});
        return *this;
    }
};

class SubscriptionEngine {
  public:
    using Connection = std::shared_ptr<transport::ServerConnection>;

    SubscriptionEngine(AddressSpace& addressSpace, SubscriptionLimits limits,
                       DecodeLimits decodeLimits);
    ~SubscriptionEngine();  // stop()
    SubscriptionEngine(const SubscriptionEngine&) = delete;
    SubscriptionEngine& operator=(const SubscriptionEngine&) = delete;

    void start();  // the timer thread
    void stop();

    // Services; `session` identifies the session (its SessionId). Publish answers later
    // (from any thread) through conn; the others fill `resp`.
    void createSubscription(const NodeId& session, const CreateSubscriptionRequest& req,
                            CreateSubscriptionResponse& resp);
    void modifySubscription(const NodeId& session, const ModifySubscriptionRequest& req,
                            ModifySubscriptionResponse& resp);
    void deleteSubscriptions(const NodeId& session, const DeleteSubscriptionsRequest& req,
                             DeleteSubscriptionsResponse& resp);
    void setPublishingMode(const NodeId& session, const SetPublishingModeRequest& req,
                           SetPublishingModeResponse& resp);
    void republish(const NodeId& session, const RepublishRequest& req, RepublishResponse& resp);
    void publish(const NodeId& session, const Connection& conn, UInt32 requestId,
                 const PublishRequest& req);
    void createMonitoredItems(const NodeId& session, const CreateMonitoredItemsRequest& req,
                              CreateMonitoredItemsResponse& resp);
    void modifyMonitoredItems(const NodeId& session, const ModifyMonitoredItemsRequest& req,
                              ModifyMonitoredItemsResponse& resp);
    void deleteMonitoredItems(const NodeId& session, const DeleteMonitoredItemsRequest& req,
                              DeleteMonitoredItemsResponse& resp);
    void setMonitoringMode(const NodeId& session, const SetMonitoringModeRequest& req,
                           SetMonitoringModeResponse& resp);
    void setTriggering(const NodeId& session, const SetTriggeringRequest& req,
                       SetTriggeringResponse& resp);
    // Moves subscriptions of another session of the same user, or kept after their session
    // ended, to `session` (§5.13.7); the old session, while it exists, is told with a
    // StatusChangeNotification Good_SubscriptionTransferred.
    void transferSubscriptions(const NodeId& session, const TransferSubscriptionsRequest& req,
                               TransferSubscriptionsResponse& resp);

    // Who the session acts for (from ActivateSession): subscriptions move only between
    // sessions of the same user.
    void setSessionUser(const NodeId& session, const SessionIdentity& user);
    // The session is gone: its Publish requests are answered Bad_SessionClosed. Its
    // subscriptions are deleted, or with deleteSubscriptions false kept until their lifetime
    // expires or another session takes them over with TransferSubscriptions.
    void removeSession(const NodeId& session, bool deleteSubscriptions = true);

    // Fires an event at its SourceNode: items on the source (when it is a notifier) and on
    // every notifier above it (inverse HasEventSource / HasNotifier, and always the Server
    // object) receive it. Any thread.
    void fireEvent(Event event);

    struct Statistics {
        std::size_t subscriptions = 0;
        std::size_t monitoredItems = 0;
        std::size_t queuedPublishRequests = 0;
        std::uint64_t notificationMessagesSent = 0;
        std::uint64_t samples = 0;  // values read by the sampling timer
    };
    Statistics statistics() const;

    struct Impl;  // defined in subscriptions.cpp

  private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::ua::server
