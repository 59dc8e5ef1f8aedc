// The client's Publish loop (internal to the client module; users see subscription.hpp).
//
// One engine per Client (created with the first Subscription, kept in Client::Impl). It
// owns the subscription states by server id, the acknowledgements to send, and the count of
// outstanding Publish requests. Its mutex is never held while calling the client or a user
// callback.
#pragma once

#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <vector>

#include "ua/client/subscription.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::client {

// What a reconnect did to the session (reported by the client, see Client::Impl).
enum class SessionChange { Reactivated, Recreated };

struct MonitoredItemState {
    UInt32 clientHandle = 0;
    UInt32 monitoredItemId = 0;
    ReadValueId itemToMonitor;
    MonitoringMode mode = MonitoringMode::Reporting;
    MonitoringParameters parameters;  // clientHandle, sampling, filter, queue
    TimestampsToReturn timestamps = TimestampsToReturn::Both;
    Double revisedSamplingInterval = 0;
    UInt32 revisedQueueSize = 0;
    DataChangeCallback onData;
    EventCallback onEvent;
    std::vector<std::string> selectNames;  // event items
};

struct SubscriptionState {
    SubscriptionSettings settings;
    RevisedSubscription revised;
    SubscriptionStatusCallback onStatus;
    UInt32 lastSequence = 0;  // highest sequence number received
    // Skipped sequence numbers (asked for by Republish, or arriving late: the server may
    // answer Publish requests out of order): delivered once, whichever way comes first.
    std::vector<UInt32> missing;
    std::atomic<bool> lost{false};
    std::map<UInt32, std::shared_ptr<MonitoredItemState>> items;  // by client handle
};

struct SubscriptionEngineStats {
    std::uint64_t publishResponses = 0;
    std::uint64_t keepAlives = 0;
    std::uint64_t republished = 0;
    std::uint64_t duplicates = 0;      // messages received twice (late and republished): dropped
    std::uint64_t unknownHandles = 0;  // notifications for items or subscriptions we do not know
    std::uint64_t malformed = 0;       // notification data that did not decode
};

class SubscriptionEngine : public std::enable_shared_from_this<SubscriptionEngine> {
  public:
    explicit SubscriptionEngine(Client* client) : client_(client) {}

    // The Client moved, or is being destroyed (nullptr): no more requests through it.
    void rebind(Client* client);
    // Called by the client after a reconnect, without its lock.
    void sessionChanged(SessionChange change);

    // Thread-safe access to the client pointer; throws BadNotConnected once detached.
    Client& client();
    std::mutex& mutex() { return mutex_; }

    void add(const std::shared_ptr<SubscriptionState>& sub);
    void erase(const std::shared_ptr<SubscriptionState>& sub);
    UInt32 nextClientHandle() { return ++clientHandle_; }
    // Sends Publish requests until enough are outstanding.
    void fill();
    SubscriptionEngineStats stats() const;

    // Creates the subscription and its items on the server (again), filling in ids.
    void create(SubscriptionState& sub, Deadline deadline);
    void createItems(SubscriptionState& sub,
                     const std::vector<std::shared_ptr<MonitoredItemState>>& items,
                     std::vector<StatusCode>& statuses, Deadline deadline);

  private:
    void onPublish(Result<PublishResponse> r, std::uint64_t generation);
    template <class Notification>
    std::vector<std::shared_ptr<MonitoredItemState>> itemsOf(
        const SubscriptionState& sub, const std::vector<Notification>& notifications);
    void dispatch(const std::shared_ptr<SubscriptionState>& sub, NotificationMessage& message);
    void republish(const std::shared_ptr<SubscriptionState>& sub, UInt32 from, UInt32 to);
    void report(const std::shared_ptr<SubscriptionState>& sub, SubscriptionStatus::Kind kind,
                StatusCode status, std::string message);
    void recover(SessionChange change);

    mutable std::mutex mutex_;
    Client* client_;
    std::map<UInt32, std::shared_ptr<SubscriptionState>> subs_;  // by subscription id
    std::vector<SubscriptionAcknowledgement> acks_;
    UInt32 outstanding_ = 0;
    UInt32 maxOutstanding_ = 4;     // lowered by BadTooManyPublishRequests
    std::uint64_t generation_ = 0;  // +1 per session change: older Publish calls do not count
    UInt32 consecutiveErrors_ = 0;
    std::atomic<UInt32> clientHandle_{0};
    SubscriptionEngineStats stats_;
};

}  // namespace pnp::ua::client
