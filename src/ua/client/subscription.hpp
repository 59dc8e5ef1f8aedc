// Subscriptions and monitored items (OPC 10000-4 §5.12, §5.13) on a Client.
//
//   Subscription sub(client, {.publishingInterval = 100});
//   MonitoredItem counter = sub.monitorValue(NodeId(2, "Counter"),
//       [](const DataValue& v) { ... });
//   MonitoredItem alarms = sub.monitorEvents(NodeId(0, ns0::Server),
//       {.select = {"Message", "Severity", "2:CustomField"}},
//       [](EventFields& e) { const Variant* severity = e.get("Severity"); ... });
//   client.startBackgroundThread();   // or call client.runIterate() in your own loop
//
// Handles are RAII: destroying a MonitoredItem deletes it on the server, destroying a
// Subscription deletes the subscription (errors are swallowed; remove() throws them). The
// Client may be moved while they exist; once it is destroyed they are inert. Callbacks must
// not throw (exceptions are swallowed); they may call the client and remove their own item.
//
// Publishing. The client keeps a few Publish requests outstanding per session (one more
// than the number of subscriptions, at most 4; fewer after BadTooManyPublishRequests),
// acknowledges every NotificationMessage with the next Publish, republishes missing
// sequence numbers and sends a new Publish when one times out. Responses are dispatched like
// every async completion (runIterate(), the background thread, or inside a blocking call)
// and the callbacks run on that thread without the client's lock. Republished messages may
// arrive after newer ones (DataValue timestamps tell the order).
//
// Reconnect. When the client re-activates its session on a new channel, the messages
// missed meanwhile are republished; when it had to create a new session, the subscriptions
// are transferred (TransferSubscriptions, initial values resent) or, if the server no longer
// has them, recreated with their monitored items (same client handles; ids change). The
// status callback says which (SubscriptionStatus::Kind).
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "ua/client/client.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::client {

struct SubscriptionSettings {
    Double publishingInterval = 100;  // ms
    UInt32 lifetimeCount = 60;        // in publishing intervals; >= 3 x maxKeepAliveCount
    UInt32 maxKeepAliveCount = 10;
    UInt32 maxNotificationsPerPublish = 0;  // 0: no limit
    Byte priority = 0;
    bool publishingEnabled = true;
};

// The values the server granted.
struct RevisedSubscription {
    UInt32 subscriptionId = 0;
    Double publishingInterval = 0;
    UInt32 lifetimeCount = 0;
    UInt32 maxKeepAliveCount = 0;
};

// What happened to a subscription, reported to its status callback.
struct SubscriptionStatus {
    enum class Kind {
        KeepAlive,      // a keep-alive message arrived
        StatusChanged,  // StatusChangeNotification from the server (Bad: subscription gone)
        Republished,    // the session was re-activated; missed messages were republished
        Transferred,    // moved to the new session with TransferSubscriptions
        Recreated,      // created again (with its items) on a new session
        Lost,           // gone and could not be recreated; the handle is dead
        PublishError,   // a Publish failed (status says why; BadTimeout: no keep-alive in
                        // twice the keep-alive period); publishing continues
    };
    Kind kind;
    StatusCode status;
    std::string message;
};
using SubscriptionStatusCallback = std::function<void(const SubscriptionStatus&)>;

// Fields of one event, in the order of EventOptions::select.
class EventFields {
  public:
    EventFields(const std::vector<std::string>& names, std::vector<Variant>& values)
        : names_(&names), values_(&values) {}
    std::size_t size() const { return values_->size(); }
    const Variant& operator[](std::size_t i) const { return (*values_)[i]; }
    const std::vector<Variant>& values() const { return *values_; }
    // Moves the fields out (the callback owns them afterwards).
    std::vector<Variant> take() { return std::move(*values_); }
    // The field selected as `name` (spelled as in EventOptions::select), or nullptr.
    const Variant* get(std::string_view name) const;

  private:
    const std::vector<std::string>* names_;
    std::vector<Variant>* values_;
};

using DataChangeCallback = std::function<void(const DataValue&)>;
using EventCallback = std::function<void(EventFields&)>;

struct DataChangeOptions {
    Double samplingInterval = -1;  // ms; -1: the publishing interval
    UInt32 queueSize = 1;
    bool discardOldest = true;
    std::optional<DataChangeFilter> filter = std::nullopt;  // trigger, deadband
    MonitoringMode mode = MonitoringMode::Reporting;
    TimestampsToReturn timestamps = TimestampsToReturn::Both;
    AttributeId attribute = AttributeId::Value;
};

struct EventOptions {
    // Select clauses: browse paths from the event type, "[ns:]Name[/[ns:]Name...]".
    std::vector<std::string> select = {"EventId", "EventType", "SourceName",
                                       "Time",    "Message",   "Severity"};
    NodeId eventType = NodeId(0, 2041);  // typeDefinitionId of the select clauses
    ContentFilter where = {};            // empty: all events
    UInt32 queueSize = 100;
    bool discardOldest = true;
    MonitoringMode mode = MonitoringMode::Reporting;
};

// A where clause that passes only events of `eventType` or its subtypes.
ContentFilter whereOfType(const NodeId& eventType);
// The SimpleAttributeOperand of a select clause / operand, from "[ns:]Name[/...]".
SimpleAttributeOperand eventField(std::string_view path, const NodeId& eventType = NodeId(0, 2041));

class SubscriptionEngine;
struct SubscriptionState;
struct MonitoredItemState;

class MonitoredItem {
  public:
    MonitoredItem() = default;
    ~MonitoredItem();
    MonitoredItem(MonitoredItem&&) noexcept;
    MonitoredItem& operator=(MonitoredItem&&) noexcept;
    MonitoredItem(const MonitoredItem&) = delete;
    MonitoredItem& operator=(const MonitoredItem&) = delete;

    bool valid() const { return item_ != nullptr; }
    UInt32 id() const;            // the server's MonitoredItemId (changes on recreate)
    UInt32 clientHandle() const;  // ours, stable
    Double revisedSamplingInterval() const;
    UInt32 revisedQueueSize() const;

    void setMonitoringMode(MonitoringMode mode, Deadline deadline = {});
    // Sampling interval, queue size, discardOldest and filter of a data-change item.
    void modify(const DataChangeOptions& options, Deadline deadline = {});
    // DeleteMonitoredItems; the callback is not called afterwards. Throws Error.
    void remove(Deadline deadline = {});

  private:
    friend class Subscription;
    std::shared_ptr<SubscriptionEngine> engine_;
    std::shared_ptr<SubscriptionState> sub_;
    std::shared_ptr<MonitoredItemState> item_;
};

class Subscription {
  public:
    Subscription() = default;
    // CreateSubscription; throws Error. Starts the Publish loop of the client.
    explicit Subscription(Client& client, SubscriptionSettings settings = {},
                          SubscriptionStatusCallback onStatus = {}, Deadline deadline = {});
    ~Subscription();
    Subscription(Subscription&&) noexcept;
    Subscription& operator=(Subscription&&) noexcept;
    Subscription(const Subscription&) = delete;
    Subscription& operator=(const Subscription&) = delete;

    bool valid() const { return sub_ != nullptr; }
    UInt32 id() const;  // changes when the subscription is recreated
    RevisedSubscription revised() const;

    // CreateMonitoredItems for one data-change item; throws Error (also for a Bad result).
    MonitoredItem monitorValue(const NodeId& node, DataChangeCallback callback,
                               const DataChangeOptions& options = {}, Deadline deadline = {});
    // Many items in one request; the callback gets the index into `nodes`. Items whose
    // creation failed are returned invalid (!valid()), with their status in `statuses`.
    std::vector<MonitoredItem> monitorValues(
        const std::vector<NodeId>& nodes,
        std::function<void(std::size_t index, const DataValue&)> callback,
        const DataChangeOptions& options = {}, std::vector<StatusCode>* statuses = nullptr,
        Deadline deadline = {});
    // An event item on an object whose EventNotifier subscribes to events (e.g. the Server
    // object i=2253).
    MonitoredItem monitorEvents(const NodeId& notifier, EventOptions options,
                                EventCallback callback, Deadline deadline = {});

    void modify(const SubscriptionSettings& settings, Deadline deadline = {});
    void setPublishingEnabled(bool enabled, Deadline deadline = {});
    // DeleteSubscriptions (its items go with it). Throws Error.
    void remove(Deadline deadline = {});

  private:
    std::shared_ptr<SubscriptionEngine> engine_;
    std::shared_ptr<SubscriptionState> sub_;
};

}  // namespace pnp::ua::client
