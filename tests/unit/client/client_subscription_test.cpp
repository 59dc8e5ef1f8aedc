// The client's subscriptions against the scripted FakeServer: the test answers each Publish
// itself, so it controls sequence numbers, gaps, malformed and unknown notifications.
#include <gtest/gtest.h>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <thread>

#include "fake_server.hpp"
#include "support/wait.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/client/subscription_engine.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {
namespace {

using namespace std::chrono_literals;
using testing::FakeServer;

constexpr UInt32 kSubscriptionId = 7;

using pnp::testing::waitUntil;

// Subscription services of the FakeServer; Publish requests are queued for the test.
class Scripted {
  public:
    explicit Scripted(FakeServer& server) {
        server.setHook([this](const FakeServer::Request& r) { return handle(r); });
    }

    // The next Publish request (waits up to 3 s).
    std::optional<FakeServer::Request> nextPublish(std::chrono::milliseconds t = 3000ms) {
        std::unique_lock lock(m_);
        if (!cv_.wait_for(lock, t, [&] { return !publishes_.empty(); })) return std::nullopt;
        auto r = publishes_.front();
        publishes_.pop_front();
        return r;
    }
    std::size_t queuedPublishes() {
        std::lock_guard lock(m_);
        return publishes_.size();
    }
    void offerRepublish(UInt32 seq, NotificationMessage m) {
        std::lock_guard lock(m_);
        republish_[seq] = std::move(m);
    }
    std::vector<UInt32> republishRequests() {
        std::lock_guard lock(m_);
        return republished_;
    }
    std::vector<UInt32> deletedItems() {
        std::lock_guard lock(m_);
        return deletedItems_;
    }
    std::vector<UInt32> deletedSubscriptions() {
        std::lock_guard lock(m_);
        return deletedSubscriptions_;
    }
    // The result of TransferSubscriptions for every subscription.
    void setTransferResult(StatusCode s) {
        std::lock_guard lock(m_);
        transferResult_ = s;
    }
    // The client handles of every CreateMonitoredItems request, in order.
    std::vector<std::vector<UInt32>> createdHandles() {
        std::lock_guard lock(m_);
        return createdHandles_;
    }

  private:
    bool handle(const FakeServer::Request& r) {
        if (r.is<CreateSubscriptionRequest>()) {
            auto req = r.decodeAs<CreateSubscriptionRequest>();
            CreateSubscriptionResponse resp{};
            resp.subscriptionId = kSubscriptionId;
            resp.revisedPublishingInterval = req.requestedPublishingInterval * 2;
            resp.revisedLifetimeCount = req.requestedLifetimeCount;
            resp.revisedMaxKeepAliveCount = req.requestedMaxKeepAliveCount;
            FakeServer::respond(r, std::move(resp));
        } else if (r.is<CreateMonitoredItemsRequest>()) {
            auto req = r.decodeAs<CreateMonitoredItemsRequest>();
            {
                std::lock_guard lock(m_);
                createdHandles_.emplace_back();
                for (const auto& item : req.itemsToCreate)
                    createdHandles_.back().push_back(item.requestedParameters.clientHandle);
            }
            CreateMonitoredItemsResponse resp{};
            for (const auto& item : req.itemsToCreate) {
                MonitoredItemCreateResult res{};
                if (item.itemToMonitor.nodeId == NodeId(1, "Missing")) {
                    res.statusCode = status::BadNodeIdUnknown;
                } else {
                    res.monitoredItemId = 100 + item.requestedParameters.clientHandle;
                    res.revisedSamplingInterval = 50;
                    res.revisedQueueSize = item.requestedParameters.queueSize;
                }
                resp.results.push_back(res);
            }
            FakeServer::respond(r, std::move(resp));
        } else if (r.is<DeleteMonitoredItemsRequest>()) {
            auto req = r.decodeAs<DeleteMonitoredItemsRequest>();
            {
                std::lock_guard lock(m_);
                for (UInt32 id : req.monitoredItemIds) deletedItems_.push_back(id);
            }
            DeleteMonitoredItemsResponse resp{};
            resp.results.assign(req.monitoredItemIds.size(), StatusCode{});
            FakeServer::respond(r, std::move(resp));
        } else if (r.is<DeleteSubscriptionsRequest>()) {
            auto req = r.decodeAs<DeleteSubscriptionsRequest>();
            {
                std::lock_guard lock(m_);
                for (UInt32 id : req.subscriptionIds) deletedSubscriptions_.push_back(id);
            }
            DeleteSubscriptionsResponse resp{};
            resp.results.assign(req.subscriptionIds.size(), StatusCode{});
            FakeServer::respond(r, std::move(resp));
        } else if (r.is<RepublishRequest>()) {
            auto req = r.decodeAs<RepublishRequest>();
            std::optional<NotificationMessage> m;
            {
                std::lock_guard lock(m_);
                republished_.push_back(req.retransmitSequenceNumber);
                auto it = republish_.find(req.retransmitSequenceNumber);
                if (it != republish_.end()) m = it->second;
            }
            if (!m) {
                FakeServer::fault(r, status::BadMessageNotAvailable);
            } else {
                RepublishResponse resp{};
                resp.notificationMessage = std::move(*m);
                FakeServer::respond(r, std::move(resp));
            }
        } else if (r.is<TransferSubscriptionsRequest>()) {
            auto req = r.decodeAs<TransferSubscriptionsRequest>();
            TransferSubscriptionsResponse resp{};
            std::lock_guard lock(m_);
            for (std::size_t i = 0; i < req.subscriptionIds.size(); ++i)
                resp.results.push_back({transferResult_, {}});
            FakeServer::respond(r, std::move(resp));
        } else if (r.is<PublishRequest>()) {
            std::lock_guard lock(m_);
            publishes_.push_back(r);
            cv_.notify_all();
        } else {
            return false;
        }
        return true;
    }

    std::mutex m_;
    std::condition_variable cv_;
    std::deque<FakeServer::Request> publishes_;
    std::map<UInt32, NotificationMessage> republish_;
    std::vector<UInt32> republished_;
    std::vector<UInt32> deletedItems_;
    std::vector<UInt32> deletedSubscriptions_;
    StatusCode transferResult_;
    std::vector<std::vector<UInt32>> createdHandles_;
};

NotificationMessage dataMessage(UInt32 seq, std::vector<std::pair<UInt32, Int32>> values) {
    DataChangeNotification dc{};
    for (auto [handle, v] : values) dc.monitoredItems.push_back({handle, DataValue(Variant(v))});
    NotificationMessage m{};
    m.sequenceNumber = seq;
    m.publishTime = DateTime::now();
    m.notificationData.push_back(toExtensionObject(dc));
    return m;
}

void answer(const FakeServer::Request& r, NotificationMessage m, UInt32 sub = kSubscriptionId) {
    PublishResponse resp{};
    resp.subscriptionId = sub;
    resp.notificationMessage = std::move(m);
    FakeServer::respond(r, std::move(resp));
}

struct Values {
    std::mutex m;
    std::vector<Int32> got;
    void add(const DataValue& v) {
        std::lock_guard lock(m);
        got.push_back(v.value && v.value->scalar<Int32>() ? *v.value->scalar<Int32>() : -1);
    }
    std::vector<Int32> snapshot() {
        std::lock_guard lock(m);
        return got;
    }
};

class ClientSubscription : public ::testing::Test {
  protected:
    void SetUp() override { client.connect(server.url()); }
    FakeServer server;
    Scripted script{server};
    Client client;
};

TEST_F(ClientSubscription, RevisedValuesIdsAndAcknowledgements) {
    Values values;
    Subscription sub(client, {.publishingInterval = 25, .maxKeepAliveCount = 4});
    EXPECT_EQ(sub.id(), kSubscriptionId);
    EXPECT_EQ(sub.revised().publishingInterval, 50);
    EXPECT_EQ(sub.revised().maxKeepAliveCount, 4u);
    MonitoredItem item = sub.monitorValue(
        NodeId(1, "Int32"), [&](const DataValue& v) { values.add(v); }, {.queueSize = 3});
    EXPECT_EQ(item.id(), 100 + item.clientHandle());
    EXPECT_EQ(item.revisedQueueSize(), 3u);
    client.startBackgroundThread();

    auto p1 = script.nextPublish();
    ASSERT_TRUE(p1);
    EXPECT_TRUE(p1->decodeAs<PublishRequest>().subscriptionAcknowledgements.empty());
    answer(*p1, dataMessage(1, {{item.clientHandle(), 11}}));
    ASSERT_TRUE(waitUntil([&] { return values.snapshot().size() == 1; }));
    EXPECT_EQ(values.snapshot().front(), 11);

    // The next Publish acknowledges message 1 (an outstanding one may come first).
    bool acked = false;
    for (int i = 0; i < 3 && !acked; ++i) {
        auto p = script.nextPublish();
        ASSERT_TRUE(p);
        for (const auto& a : p->decodeAs<PublishRequest>().subscriptionAcknowledgements)
            acked = acked || (a.subscriptionId == kSubscriptionId && a.sequenceNumber == 1);
        if (!acked) answer(*p, NotificationMessage{2, DateTime::now(), {}});  // keep-alive
    }
    EXPECT_TRUE(acked);
}

TEST_F(ClientSubscription, MalformedUnknownAndForeignNotificationsAreCountedNotFatal) {
    Values values;
    Subscription sub(client);
    MonitoredItem item =
        sub.monitorValue(NodeId(1, "Int32"), [&](const DataValue& v) { values.add(v); });
    client.startBackgroundThread();
    auto engine = client.subscriptionEngine();

    NotificationMessage m = dataMessage(1, {{item.clientHandle() + 1000, 5},  // unknown handle
                                            {item.clientHandle(), 6}});
    ExtensionObject broken = toExtensionObject(DataChangeNotification{});
    broken.body = "\x05\x00\x00\x00garbage";  // 5 items announced, garbage follows
    m.notificationData.insert(m.notificationData.begin(), broken);
    ExtensionObject foreign;  // a type that is no notification at all
    foreign.typeId = NodeId(0, 12345);
    foreign.encoding = ExtensionObject::Encoding::Binary;
    foreign.body = "xyz";
    m.notificationData.push_back(foreign);
    auto p = script.nextPublish();
    ASSERT_TRUE(p);
    answer(*p, m);
    ASSERT_TRUE(waitUntil([&] { return values.snapshot().size() == 1; }));
    EXPECT_EQ(values.snapshot().front(), 6);
    ASSERT_TRUE(waitUntil([&] { return engine->stats().malformed == 2; }));
    EXPECT_EQ(engine->stats().unknownHandles, 1u);

    // A message for a subscription we do not have is ignored (and acknowledged).
    p = script.nextPublish();
    ASSERT_TRUE(p);
    answer(*p, dataMessage(2, {{item.clientHandle(), 7}}), 999);
    ASSERT_TRUE(waitUntil([&] { return engine->stats().unknownHandles == 2; }));
    EXPECT_EQ(values.snapshot().size(), 1u);
    EXPECT_TRUE(client.isChannelOpen());
}

TEST_F(ClientSubscription, GapsAreRepublished) {
    Values values;
    Subscription sub(client);
    MonitoredItem item =
        sub.monitorValue(NodeId(1, "Int32"), [&](const DataValue& v) { values.add(v); });
    UInt32 h = item.clientHandle();
    script.offerRepublish(2, dataMessage(2, {{h, 2}}));
    // 3 is gone for good (BadMessageNotAvailable).
    client.startBackgroundThread();
    auto p = script.nextPublish();
    ASSERT_TRUE(p);
    answer(*p, dataMessage(1, {{h, 1}}));
    p = script.nextPublish();
    ASSERT_TRUE(p);
    answer(*p, dataMessage(4, {{h, 4}}));
    ASSERT_TRUE(waitUntil([&] { return values.snapshot().size() == 3; }));
    auto got = values.snapshot();
    std::sort(got.begin(), got.end());
    EXPECT_EQ(got, (std::vector<Int32>{1, 2, 4}));
    // The Republish for 3 may still be on its way when 2's answer has been delivered.
    ASSERT_TRUE(waitUntil([&] { return script.republishRequests().size() >= 2; }));
    EXPECT_EQ(script.republishRequests(), (std::vector<UInt32>{2, 3}));

    // A keep-alive announcing sequence number 6 means 5 was missed.
    p = script.nextPublish();
    ASSERT_TRUE(p);
    answer(*p, NotificationMessage{6, DateTime::now(), {}});
    ASSERT_TRUE(waitUntil([&] { return script.republishRequests().size() == 3; }));
    EXPECT_EQ(script.republishRequests().back(), 5u);
}

TEST_F(ClientSubscription, TooManyPublishRequestsLowersTheNumberOutstanding) {
    Subscription sub(client);
    client.startBackgroundThread();
    // One subscription: two Publish requests outstanding.
    ASSERT_TRUE(waitUntil([&] { return script.queuedPublishes() == 2; }));
    auto p = script.nextPublish();
    ASSERT_TRUE(p);
    FakeServer::fault(*p, status::BadTooManyPublishRequests);
    std::this_thread::sleep_for(200ms);
    EXPECT_EQ(script.queuedPublishes(), 1u);  // not replaced
    // Answering the remaining one sends exactly one new request.
    p = script.nextPublish();
    ASSERT_TRUE(p);
    answer(*p, NotificationMessage{1, DateTime::now(), {}});
    ASSERT_TRUE(waitUntil([&] { return script.queuedPublishes() == 1; }));
    std::this_thread::sleep_for(200ms);
    EXPECT_EQ(script.queuedPublishes(), 1u);
}

TEST_F(ClientSubscription, StatusChangeReportsAndHandlesDeleteOnDestruction) {
    std::mutex m;
    std::vector<SubscriptionStatus> statuses;
    UInt32 itemId = 0;
    {
        Subscription sub(client, {}, [&](const SubscriptionStatus& s) {
            std::lock_guard lock(m);
            statuses.push_back(s);
        });
        {
            MonitoredItem item = sub.monitorValue(NodeId(1, "Int32"), [](const DataValue&) {});
            itemId = item.id();
            // A failed item throws with its status.
            try {
                sub.monitorValue(NodeId(1, "Missing"), [](const DataValue&) {});
                ADD_FAILURE() << "no error for a missing node";
            } catch (const Error& e) {
                EXPECT_EQ(e.status(), status::BadNodeIdUnknown);
            }
        }
        EXPECT_EQ(script.deletedItems(), (std::vector<UInt32>{itemId}));

        client.startBackgroundThread();
        auto p = script.nextPublish();
        ASSERT_TRUE(p);
        answer(*p, NotificationMessage{1, DateTime::now(), {}});  // keep-alive
        p = script.nextPublish();
        ASSERT_TRUE(p);
        NotificationMessage lost{};
        lost.sequenceNumber = 2;
        lost.notificationData.push_back(
            toExtensionObject(StatusChangeNotification{status::BadTimeout, {}}));
        answer(*p, lost);
        ASSERT_TRUE(waitUntil([&] {
            std::lock_guard lock(m);
            return std::any_of(statuses.begin(), statuses.end(), [](const SubscriptionStatus& s) {
                return s.kind == SubscriptionStatus::Kind::StatusChanged &&
                       s.status == status::BadTimeout;
            });
        }));
        std::lock_guard lock(m);
        EXPECT_EQ(statuses.front().kind, SubscriptionStatus::Kind::KeepAlive);
        // The server says the subscription is gone: operations fail, no Delete is sent.
        EXPECT_THROW(sub.setPublishingEnabled(false), Error);
    }
    EXPECT_TRUE(script.deletedSubscriptions().empty());

    { Subscription sub(client); }
    EXPECT_EQ(script.deletedSubscriptions(), (std::vector<UInt32>{kSubscriptionId}));
}

// The server forgets the session (a Publish answers BadSessionIdInvalid): the client
// creates a new one and moves the subscription over, or recreates it with its items.
class ClientSubscriptionSessionLoss : public ClientSubscription,
                                      public ::testing::WithParamInterface<bool> {};

TEST_P(ClientSubscriptionSessionLoss, TransferredOrRecreated) {
    const bool transferable = GetParam();
    script.setTransferResult(transferable ? StatusCode{} : status::BadSubscriptionIdInvalid);
    std::mutex m;
    std::vector<SubscriptionStatus::Kind> kinds;
    Values values;
    Subscription sub(client, {}, [&](const SubscriptionStatus& s) {
        std::lock_guard lock(m);
        if (s.kind != SubscriptionStatus::Kind::KeepAlive) kinds.push_back(s.kind);
    });
    MonitoredItem item =
        sub.monitorValue(NodeId(1, "Int32"), [&](const DataValue& v) { values.add(v); });
    const UInt32 handle = item.clientHandle();
    client.startBackgroundThread();
    NodeId oldSession = client.sessionId();

    server.forgetSessions();
    auto p = script.nextPublish();
    ASSERT_TRUE(p);
    FakeServer::fault(*p, status::BadSessionIdInvalid);
    const auto expected =
        transferable ? SubscriptionStatus::Kind::Transferred : SubscriptionStatus::Kind::Recreated;
    ASSERT_TRUE(waitUntil([&] {
        std::lock_guard lock(m);
        return std::find(kinds.begin(), kinds.end(), expected) != kinds.end();
    }));
    EXPECT_NE(client.sessionId(), oldSession);
    auto created = script.createdHandles();
    if (transferable) {
        EXPECT_EQ(created.size(), 1u);  // nothing created again
    } else {
        ASSERT_EQ(created.size(), 2u);  // the item again, with the same client handle
        EXPECT_EQ(created.back(), (std::vector<UInt32>{handle}));
    }
    // Notifications keep reaching the same callback (skip Publish requests of the old session).
    for (int i = 0; i < 4 && values.snapshot().empty(); ++i) {
        p = script.nextPublish();
        ASSERT_TRUE(p);
        answer(*p, dataMessage(1, {{handle, 99}}));
        waitUntil([&] { return !values.snapshot().empty(); }, 300ms);
    }
    ASSERT_EQ(values.snapshot(), (std::vector<Int32>{99}));
}

INSTANTIATE_TEST_SUITE_P(Both, ClientSubscriptionSessionLoss, ::testing::Bool());

}  // namespace
}  // namespace pnp::ua::client
