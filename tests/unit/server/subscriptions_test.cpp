// Subscriptions, monitored items and events on the server, exercised by our client's generic
// request() over real sockets (the client's own subscription API is written elsewhere).
#include "ua/server/subscriptions.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <map>
#include <memory>
#include <string>
#include <thread>

#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/server/server.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp::ua;
using namespace std::chrono_literals;
using client::Client;
using pnp::testing::errorOf;
using pnp::testing::url;

namespace {

server::ServerConfig testConfig() {
    server::ServerConfig c = pnp::testing::loopbackConfig();
    c.subscriptionLimits.maxSubscriptionsPerSession = 3;
    c.subscriptionLimits.maxMonitoredItemsPerCall = 100;
    c.subscriptionLimits.maxRetransmissionQueue = 4;
    return c;
}

// A server with a few variables in ns=1.
struct Fixture {
    server::Server server{testConfig()};
    Client c;
    NodeId dbl{1, "Double"};
    NodeId text{1, "Text"};
    NodeId analog{1, "Analog"};

    Fixture() {
        auto& as = server.addressSpace();
        server::VariableAttributes a;
        a.dataType = NodeId(0, ns0::Double);
        a.value = DataValue(Variant(Double{0}));
        a.accessLevel = server::access_level::CurrentRead | server::access_level::CurrentWrite;
        as.addVariable(NodeId(0, ns0::ObjectsFolder), dbl, QualifiedName{1, "Double"}, a);
        as.addVariable(NodeId(0, ns0::ObjectsFolder), analog, QualifiedName{1, "Analog"}, a);
        server::VariableAttributes r;
        r.dataType = NodeId(0, ns0::Range);
        r.value = DataValue(Variant(toExtensionObject(Range{0, 200})));
        as.addProperty(analog, NodeId(1, "Analog.EURange"), QualifiedName{0, "EURange"}, r);
        server::VariableAttributes t;
        t.dataType = NodeId(0, ns0::String);
        t.value = DataValue(Variant(String("a")));
        as.addVariable(NodeId(0, ns0::ObjectsFolder), text, QualifiedName{1, "Text"}, t);
        server.start();
        c.connect(url(server));
    }

    UInt32 subscribe(Double interval = 20, UInt32 keepAlive = 10, bool enabled = true) {
        CreateSubscriptionRequest req;
        req.requestedPublishingInterval = interval;
        req.requestedMaxKeepAliveCount = keepAlive;
        req.requestedLifetimeCount = keepAlive * 3;
        req.publishingEnabled = enabled;
        return c.request(req).subscriptionId;
    }

    MonitoredItemCreateResult monitor(UInt32 sub, const NodeId& node, UInt32 handle,
                                      Double sampling = 0, ExtensionObject filter = {},
                                      UInt32 queueSize = 1, bool discardOldest = true,
                                      UInt32 attribute = 13) {
        CreateMonitoredItemsRequest req;
        req.subscriptionId = sub;
        req.timestampsToReturn = TimestampsToReturn::Both;
        MonitoredItemCreateRequest item;
        item.itemToMonitor.nodeId = node;
        item.itemToMonitor.attributeId = attribute;
        item.monitoringMode = MonitoringMode::Reporting;
        item.requestedParameters.clientHandle = handle;
        item.requestedParameters.samplingInterval = sampling;
        item.requestedParameters.filter = std::move(filter);
        item.requestedParameters.queueSize = queueSize;
        item.requestedParameters.discardOldest = discardOldest;
        req.itemsToCreate.push_back(item);
        auto resp = c.request(req);
        EXPECT_EQ(resp.results.size(), 1u);
        return resp.results.at(0);
    }

    PublishResponse publish(std::vector<SubscriptionAcknowledgement> acks = {}) {
        PublishRequest req;
        req.subscriptionAcknowledgements = std::move(acks);
        return c.request(req, 5s);
    }

    // Publishes until a message with data arrives (bounded).
    PublishResponse publishData() {
        for (int i = 0; i < 50; ++i) {
            auto r = publish();
            if (!r.notificationMessage.notificationData.empty()) return r;
        }
        ADD_FAILURE() << "no data in 50 Publish responses";
        return {};
    }
};

std::vector<MonitoredItemNotification> dataOf(const PublishResponse& r) {
    std::vector<MonitoredItemNotification> out;
    for (const auto& x : r.notificationMessage.notificationData)
        if (auto d = fromExtensionObject<DataChangeNotification>(x))
            out.insert(out.end(), d->monitoredItems.begin(), d->monitoredItems.end());
    return out;
}

std::vector<EventFieldList> eventsOf(const PublishResponse& r) {
    std::vector<EventFieldList> out;
    for (const auto& x : r.notificationMessage.notificationData)
        if (auto d = fromExtensionObject<EventNotificationList>(x))
            out.insert(out.end(), d->events.begin(), d->events.end());
    return out;
}

double doubleOf(const MonitoredItemNotification& n) {
    const Double* d = n.value.value ? n.value.value->scalar<Double>() : nullptr;
    return d ? *d : -1;
}

// A subscription with nothing to send for a long time (1 s, first keep-alive after 1 s).
CreateSubscriptionRequest quietSubscription() {
    CreateSubscriptionRequest cs;
    cs.requestedPublishingInterval = 1000;
    cs.requestedMaxKeepAliveCount = 100;
    cs.publishingEnabled = true;
    return cs;
}

std::vector<StatusCode> statusChangesOf(const PublishResponse& r) {
    std::vector<StatusCode> out;
    for (const auto& x : r.notificationMessage.notificationData)
        if (auto d = fromExtensionObject<StatusChangeNotification>(x)) out.push_back(d->status);
    return out;
}

// Publishes on `c` until a message with notifications arrives (bounded).
PublishResponse publishData(Client& c) {
    for (int i = 0; i < 50; ++i) {
        auto r = c.request(PublishRequest{}, 5s);
        if (!r.notificationMessage.notificationData.empty()) return r;
    }
    ADD_FAILURE() << "no data in 50 Publish responses";
    return {};
}

ExtensionObject absoluteDeadband(Double v, DeadbandType type = DeadbandType::Absolute) {
    DataChangeFilter f;
    f.trigger = DataChangeTrigger::StatusValue;
    f.deadbandType = static_cast<UInt32>(type);
    f.deadbandValue = v;
    return toExtensionObject(f);
}

SimpleAttributeOperand field(std::vector<QualifiedName> path) {
    SimpleAttributeOperand o;
    o.typeDefinitionId = NodeId(0, ns0::BaseEventType);
    o.browsePath = std::move(path);
    o.attributeId = 13;
    return o;
}

}  // namespace

TEST(Subscriptions, DataChangesArriveAndValuesAreRevised) {
    Fixture f;
    CreateSubscriptionRequest req;
    req.requestedPublishingInterval = 0;  // below the minimum
    req.requestedMaxKeepAliveCount = 5;
    req.requestedLifetimeCount = 1;  // below 3 x keep-alive
    req.publishingEnabled = true;
    auto sub = f.c.request(req);
    EXPECT_EQ(sub.revisedPublishingInterval,
              testConfig().subscriptionLimits.minPublishingIntervalMs);
    EXPECT_EQ(sub.revisedMaxKeepAliveCount, 5u);
    EXPECT_GE(sub.revisedLifetimeCount, 15u);

    auto item = f.monitor(sub.subscriptionId, f.dbl, 7);
    ASSERT_TRUE(item.statusCode.isGood()) << item.statusCode.toString();
    EXPECT_EQ(item.revisedSamplingInterval, 0);  // event-driven
    EXPECT_EQ(item.revisedQueueSize, 1u);

    auto first = f.publishData();  // the initial value
    auto d = dataOf(first);
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(d[0].clientHandle, 7u);
    EXPECT_EQ(doubleOf(d[0]), 0.0);
    EXPECT_TRUE(d[0].value.sourceTimestamp.has_value());

    // A change made by the application and one made through Write.
    f.server.addressSpace().setValue(f.dbl, DataValue(Variant(Double{42})));
    d = dataOf(f.publishData());
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(doubleOf(d[0]), 42.0);
    f.c.writeValue(f.dbl, Variant(Double{43}));
    d = dataOf(f.publishData());
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(doubleOf(d[0]), 43.0);
}

TEST(Subscriptions, SampledItemsSeeCallbackValues) {
    Fixture f;
    std::atomic<int> reads{0};
    NodeId node(1, "Callback");
    server::VariableAttributes a;
    a.dataType = NodeId(0, ns0::Int32);
    a.value = DataValue(Variant(Int32{0}));
    f.server.addressSpace().addVariable(NodeId(0, ns0::ObjectsFolder), node,
                                        QualifiedName{1, "Callback"}, a);
    f.server.addressSpace().setValueCallback(
        node, {[&](const NodeId&) { return DataValue(Variant(Int32{++reads})); }, {}});
    UInt32 sub = f.subscribe(20);
    auto item = f.monitor(sub, node, 1, 30);
    ASSERT_TRUE(item.statusCode.isGood());
    EXPECT_EQ(item.revisedSamplingInterval, 30);
    std::set<Int32> seen;
    for (int i = 0; i < 50 && seen.size() < 3; ++i)
        for (const auto& n : dataOf(f.publish()))
            if (const Int32* v = n.value.value->scalar<Int32>()) seen.insert(*v);
    EXPECT_GE(seen.size(), 3u);
}

TEST(Subscriptions, KeepAliveAcknowledgeAndRepublish) {
    Fixture f;
    UInt32 sub = f.subscribe(10, 3);
    ASSERT_TRUE(f.monitor(sub, f.dbl, 1).statusCode.isGood());
    auto first = f.publishData();
    UInt32 seq = first.notificationMessage.sequenceNumber;
    EXPECT_EQ(first.subscriptionId, sub);
    ASSERT_EQ(first.availableSequenceNumbers.size(), 1u);
    EXPECT_EQ(first.availableSequenceNumbers[0], seq);

    // Nothing changes: a keep-alive after ~3 publishing intervals carries the next number.
    auto t0 = std::chrono::steady_clock::now();
    auto keepAlive = f.publish();
    EXPECT_TRUE(keepAlive.notificationMessage.notificationData.empty());
    EXPECT_EQ(keepAlive.notificationMessage.sequenceNumber, seq + 1);
    EXPECT_LT(std::chrono::steady_clock::now() - t0, 2s);

    RepublishRequest rp;
    rp.subscriptionId = sub;
    rp.retransmitSequenceNumber = seq;
    EXPECT_EQ(f.c.request(rp).notificationMessage.sequenceNumber, seq);

    // Acknowledge it (once Good, then unknown) and it is gone.
    auto acked = f.publish({{sub, seq}, {sub, seq + 100}, {sub + 50, 1}});
    ASSERT_EQ(acked.results.size(), 3u);
    EXPECT_EQ(acked.results[0], StatusCode(status::Good));
    EXPECT_EQ(acked.results[1], StatusCode(status::BadSequenceNumberUnknown));
    EXPECT_EQ(acked.results[2], StatusCode(status::BadSubscriptionIdInvalid));
    EXPECT_EQ(errorOf([&] { f.c.request(rp); }), StatusCode(status::BadMessageNotAvailable));
}

TEST(Subscriptions, RetransmissionQueueIsBounded) {
    Fixture f;
    UInt32 sub = f.subscribe(10);
    ASSERT_TRUE(f.monitor(sub, f.dbl, 1).statusCode.isGood());
    f.publishData();
    for (int i = 1; i <= 8; ++i) {
        f.server.addressSpace().setValue(f.dbl, DataValue(Variant(Double(i))));
        auto r = f.publishData();
        EXPECT_LE(r.availableSequenceNumbers.size(),
                  testConfig().subscriptionLimits.maxRetransmissionQueue);
    }
}

TEST(Subscriptions, AbsoluteAndPercentDeadband) {
    Fixture f;
    UInt32 sub = f.subscribe(10);
    ASSERT_TRUE(f.monitor(sub, f.dbl, 1, 0, absoluteDeadband(1.0), 10).statusCode.isGood());
    // 10 % of the EURange 0..200 = 20.
    ASSERT_TRUE(f.monitor(sub, f.analog, 2, 0, absoluteDeadband(10, DeadbandType::Percent), 10)
                    .statusCode.isGood());
    f.publishData();  // initial values (0)
    auto& as = f.server.addressSpace();
    for (double v : {0.5, 1.5, 2.0, 2.6}) as.setValue(f.dbl, DataValue(Variant(Double{v})));
    for (double v : {10.0, 25.0, 30.0, 46.0}) as.setValue(f.analog, DataValue(Variant(Double{v})));
    std::vector<double> dbl, analog;
    for (int i = 0; i < 50 && (dbl.size() < 2 || analog.size() < 2); ++i)
        for (const auto& n : dataOf(f.publish()))
            (n.clientHandle == 1 ? dbl : analog).push_back(doubleOf(n));
    EXPECT_EQ(dbl, (std::vector<double>{1.5, 2.6}));
    EXPECT_EQ(analog, (std::vector<double>{25.0, 46.0}));

    // Deadbands need numbers (and Percent an EURange).
    EXPECT_EQ(f.monitor(sub, f.text, 3, 0, absoluteDeadband(1)).statusCode,
              StatusCode(status::BadFilterNotAllowed));
    EXPECT_EQ(f.monitor(sub, f.dbl, 3, 0, absoluteDeadband(5, DeadbandType::Percent)).statusCode,
              StatusCode(status::BadDeadbandFilterInvalid));  // no EURange
    EXPECT_EQ(
        f.monitor(sub, f.analog, 3, 0, absoluteDeadband(101, DeadbandType::Percent)).statusCode,
        StatusCode(status::BadDeadbandFilterInvalid));
    EXPECT_EQ(f.monitor(sub, f.dbl, 3, 0, absoluteDeadband(-1)).statusCode,
              StatusCode(status::BadDeadbandFilterInvalid));
}

TEST(Subscriptions, QueueOverflowDiscardsOldestAndFlagsIt) {
    Fixture f;
    UInt32 sub = f.subscribe(200);  // changes pile up between publishing cycles
    auto item = f.monitor(sub, f.dbl, 1, 0, {}, 3, true);
    ASSERT_TRUE(item.statusCode.isGood());
    EXPECT_EQ(item.revisedQueueSize, 3u);
    f.publishData();
    for (int i = 1; i <= 5; ++i)
        f.server.addressSpace().setValue(f.dbl, DataValue(Variant(Double(i))));
    auto d = dataOf(f.publishData());
    ASSERT_EQ(d.size(), 3u);
    EXPECT_EQ(doubleOf(d[0]), 3.0);
    EXPECT_EQ(doubleOf(d[2]), 5.0);
    EXPECT_EQ(d[0].value.statusOrGood().value & 0x0480u, 0x0480u);  // Overflow
    EXPECT_EQ(d[2].value.statusOrGood().value & 0x0480u, 0u);
}

TEST(Subscriptions, BadInputGetsStatusCodes) {
    Fixture f;
    // Publish without a subscription.
    EXPECT_EQ(errorOf([&] { f.publish(); }), StatusCode(status::BadNoSubscription));
    // Publish after the last subscription was deleted.
    UInt32 sub = f.subscribe();
    DeleteSubscriptionsRequest ds;
    ds.subscriptionIds = {sub};
    f.c.request(ds);
    EXPECT_EQ(errorOf([&] { f.publish(); }), StatusCode(status::BadNoSubscription));
}

TEST(Subscriptions, BadInputGetsStatusCodesPerItem) {
    Fixture f;
    UInt32 sub = f.subscribe();
    EXPECT_EQ(f.monitor(sub, NodeId(1, "nope"), 1).statusCode,
              StatusCode(status::BadNodeIdUnknown));
    EXPECT_EQ(f.monitor(sub, f.dbl, 1, 0, {}, 1, true, 99).statusCode,
              StatusCode(status::BadAttributeIdInvalid));
    EXPECT_EQ(f.monitor(sub, f.dbl, 1, 0, toExtensionObject(Range{})).statusCode,
              StatusCode(status::BadMonitoredItemFilterUnsupported));
    // An EventFilter on a variable's Value; events on a node that is not a notifier.
    EventFilter ef;
    ef.selectClauses.push_back(field({{0, "Message"}}));
    EXPECT_EQ(f.monitor(sub, f.dbl, 1, 0, toExtensionObject(ef)).statusCode,
              StatusCode(status::BadFilterNotAllowed));
    EXPECT_EQ(
        f.monitor(sub, NodeId(0, ns0::ObjectsFolder), 1, 0, toExtensionObject(ef), 1, true, 12)
            .statusCode,
        StatusCode(status::BadNotSupported));

    CreateMonitoredItemsRequest cm;
    cm.subscriptionId = sub + 1000;
    cm.itemsToCreate.resize(1);
    cm.itemsToCreate[0].itemToMonitor.nodeId = f.dbl;
    cm.itemsToCreate[0].itemToMonitor.attributeId = 13;
    EXPECT_EQ(errorOf([&] { f.c.request(cm); }), StatusCode(status::BadSubscriptionIdInvalid));
    cm.subscriptionId = sub;
    cm.itemsToCreate[0].monitoringMode = static_cast<MonitoringMode>(7);
    EXPECT_EQ(f.c.request(cm).results.at(0).statusCode,
              StatusCode(status::BadMonitoringModeInvalid));
    cm.itemsToCreate.assign(101, cm.itemsToCreate[0]);
    EXPECT_EQ(errorOf([&] { f.c.request(cm); }), StatusCode(status::BadTooManyOperations));
    cm.itemsToCreate.clear();
    EXPECT_EQ(errorOf([&] { f.c.request(cm); }), StatusCode(status::BadNothingToDo));
    cm.itemsToCreate.resize(1);
    cm.itemsToCreate[0].itemToMonitor.nodeId = f.dbl;
    cm.itemsToCreate[0].itemToMonitor.attributeId = 13;
    cm.timestampsToReturn = static_cast<TimestampsToReturn>(9);
    EXPECT_EQ(errorOf([&] { f.c.request(cm); }), StatusCode(status::BadTimestampsToReturnInvalid));

    DeleteMonitoredItemsRequest dm;
    dm.subscriptionId = sub;
    dm.monitoredItemIds = {12345};
    EXPECT_EQ(f.c.request(dm).results.at(0), StatusCode(status::BadMonitoredItemIdInvalid));
    SetMonitoringModeRequest sm;
    sm.subscriptionId = sub;
    sm.monitoringMode = MonitoringMode::Disabled;
    sm.monitoredItemIds = {12345};
    EXPECT_EQ(f.c.request(sm).results.at(0), StatusCode(status::BadMonitoredItemIdInvalid));
    SetTriggeringRequest st;
    st.subscriptionId = sub;
    st.triggeringItemId = 12345;
    st.linksToAdd = {1};
    EXPECT_EQ(errorOf([&] { f.c.request(st); }), StatusCode(status::BadMonitoredItemIdInvalid));
    ModifySubscriptionRequest ms;
    ms.subscriptionId = sub + 1000;
    EXPECT_EQ(errorOf([&] { f.c.request(ms); }), StatusCode(status::BadSubscriptionIdInvalid));
    RepublishRequest rp;
    rp.subscriptionId = sub;
    rp.retransmitSequenceNumber = 77;
    EXPECT_EQ(errorOf([&] { f.c.request(rp); }), StatusCode(status::BadMessageNotAvailable));

    // Too many subscriptions.
    f.subscribe();
    f.subscribe();
    EXPECT_EQ(errorOf([&] { f.subscribe(); }), StatusCode(status::BadTooManySubscriptions));
    DeleteSubscriptionsRequest ds;
    ds.subscriptionIds = {sub, sub, 9999};
    auto dr = f.c.request(ds);
    ASSERT_EQ(dr.results.size(), 3u);
    EXPECT_EQ(dr.results[0], StatusCode(status::Good));
    EXPECT_EQ(dr.results[1], StatusCode(status::BadSubscriptionIdInvalid));
    EXPECT_EQ(dr.results[2], StatusCode(status::BadSubscriptionIdInvalid));
    // The server still serves.
    EXPECT_EQ(f.c.readValue(f.dbl), Variant(Double{0}));
}

TEST(Subscriptions, MonitoringModeAndTriggering) {
    Fixture f;
    UInt32 sub = f.subscribe(10);
    auto trig = f.monitor(sub, f.dbl, 1);
    auto linked = f.monitor(sub, f.text, 2);
    f.publishData();
    SetMonitoringModeRequest sm;
    sm.subscriptionId = sub;
    sm.monitoringMode = MonitoringMode::Sampling;
    sm.monitoredItemIds = {linked.monitoredItemId};
    EXPECT_EQ(f.c.request(sm).results.at(0), StatusCode(status::Good));
    SetTriggeringRequest st;
    st.subscriptionId = sub;
    st.triggeringItemId = trig.monitoredItemId;
    st.linksToAdd = {linked.monitoredItemId, 999};
    auto tr = f.c.request(st);
    ASSERT_EQ(tr.addResults.size(), 2u);
    EXPECT_EQ(tr.addResults[0], StatusCode(status::Good));
    EXPECT_EQ(tr.addResults[1], StatusCode(status::BadMonitoredItemIdInvalid));

    // The sampling item's change alone is not reported ...
    auto& as = f.server.addressSpace();
    as.setValue(f.text, DataValue(Variant(String("b"))));
    auto keepAlive = f.publish();
    EXPECT_TRUE(dataOf(keepAlive).empty());
    // ... until the triggering item reports.
    as.setValue(f.dbl, DataValue(Variant(Double{5})));
    std::set<UInt32> handles;
    for (int i = 0; i < 20 && handles.size() < 2; ++i)
        for (const auto& n : dataOf(f.publish())) handles.insert(n.clientHandle);
    EXPECT_EQ(handles, (std::set<UInt32>{1, 2}));
}

TEST(Subscriptions, ClosingTheSessionDeletesItsSubscriptions) {
    Fixture f;
    UInt32 sub = f.subscribe();
    ASSERT_TRUE(f.monitor(sub, f.dbl, 1).statusCode.isGood());
    EXPECT_EQ(f.server.subscriptions().statistics().subscriptions, 1u);
    EXPECT_EQ(f.server.subscriptions().statistics().monitoredItems, 1u);
    f.c.disconnect();
    for (int i = 0; i < 100 && f.server.subscriptions().statistics().subscriptions != 0; ++i)
        std::this_thread::sleep_for(10ms);
    EXPECT_EQ(f.server.subscriptions().statistics().subscriptions, 0u);
    EXPECT_EQ(f.server.subscriptions().statistics().monitoredItems, 0u);
}

TEST(Subscriptions, TooManyPublishRequestsAnswersTheOldest) {
    server::ServerConfig cfg = testConfig();
    cfg.subscriptionLimits.maxPublishRequestsPerSession = 2;
    server::Server server(cfg);
    server.start();
    Client c;
    c.connect(url(server));
    const CreateSubscriptionRequest cs = quietSubscription();
    c.request(cs);
    std::vector<std::future<PublishResponse>> f;
    for (int i = 0; i < 4; ++i) f.push_back(c.requestAsync(PublishRequest{}, 10s));
    // The first two are pushed out by the last two (long before the first cycle at 1 s).
    for (int i = 0; i < 200 && f[1].wait_for(0ms) != std::future_status::ready; ++i)
        c.runIterate(10ms);
    for (int i = 0; i < 2; ++i) {
        ASSERT_EQ(f[i].wait_for(0ms), std::future_status::ready);
        StatusCode st;
        try {
            f[i].get();
        } catch (const client::Error& e) {
            st = e.status();
        }
        EXPECT_EQ(st, StatusCode(status::BadTooManyPublishRequests));
    }
    EXPECT_EQ(server.subscriptions().statistics().queuedPublishRequests, 2u);
    // The held ones are answered (keep-alive) by the first publishing cycle.
    for (int i = 0; i < 300 && f[2].wait_for(0ms) != std::future_status::ready; ++i)
        c.runIterate(10ms);
    ASSERT_EQ(f[2].wait_for(0ms), std::future_status::ready);
    EXPECT_TRUE(f[2].get().notificationMessage.notificationData.empty());
    c.disconnect();
}

// ---- events ------------------------------------------------------------------------------
struct EventFixture : Fixture {
    NodeId robot{1, "Robot"};
    NodeId gripper{1, "Gripper"};
    NodeId eventType{1, "GripEventType"};
    EventFixture() {
        auto& as = server.addressSpace();
        server::ObjectAttributes o;
        o.eventNotifier = 1;
        as.addObject(NodeId(0, ns0::ObjectsFolder), robot, QualifiedName{1, "Robot"}, o);
        as.addObject(robot, gripper, QualifiedName{1, "Gripper"});
        as.addReference(robot, NodeId(0, ns0::HasEventSource), gripper);
        as.addReference(NodeId(0, ns0::Server), NodeId(0, ns0::HasNotifier), robot);
        as.addObjectType(NodeId(0, ns0::BaseEventType), eventType,
                         QualifiedName{1, "GripEventType"});
    }
    void fire(UInt16 severity, Int32 force, const NodeId& type) {
        server::Event e;
        e.eventType = type;
        e.sourceNode = gripper;
        e.sourceName = "Gripper";
        e.message = LocalizedText("en", "grip " + std::to_string(force));
        e.severity = severity;
        e.set(QualifiedName{1, "Force"}, Variant(Int32{force}));
        server.fireEvent(std::move(e));
    }
};

EventFilter gripFilter() {
    EventFilter ef;
    ef.selectClauses = {
        field({{0, "Message"}}),   field({{0, "Severity"}}),    field({{1, "Force"}}),
        field({{0, "EventType"}}), field({{0, "SourceNode"}}),  field({{0, "EventId"}}),
        field({{0, "Time"}}),      field({{0, "ReceiveTime"}}), field({{0, "SourceName"}})};
    return ef;
}

ExtensionObject literal(Variant v) { return toExtensionObject(LiteralOperand{std::move(v)}); }
ExtensionObject element(UInt32 i) { return toExtensionObject(ElementOperand{i}); }
ExtensionObject attr(std::vector<QualifiedName> path) {
    return toExtensionObject(field(std::move(path)));
}

TEST(Events, SelectClausesAndPropagationToTheServerObject) {
    EventFixture f;
    UInt32 sub = f.subscribe(10);
    auto onServer =
        f.monitor(sub, NodeId(0, ns0::Server), 1, 0, toExtensionObject(gripFilter()), 0, true, 12);
    ASSERT_TRUE(onServer.statusCode.isGood()) << onServer.statusCode.toString();
    auto onRobot = f.monitor(sub, f.robot, 2, 0, toExtensionObject(gripFilter()), 0, true, 12);
    ASSERT_TRUE(onRobot.statusCode.isGood());
    f.fire(700, 12, f.eventType);
    std::vector<EventFieldList> ev;
    for (int i = 0; i < 20 && ev.size() < 2; ++i) {
        auto got = eventsOf(f.publish());
        ev.insert(ev.end(), got.begin(), got.end());
    }
    ASSERT_EQ(ev.size(), 2u);
    std::set<UInt32> handles{ev[0].clientHandle, ev[1].clientHandle};
    EXPECT_EQ(handles, (std::set<UInt32>{1, 2}));
    const auto& fields = ev[0].eventFields;
    ASSERT_EQ(fields.size(), 9u);
    EXPECT_EQ(fields[0], Variant(LocalizedText("en", "grip 12")));
    EXPECT_EQ(fields[1], Variant(UInt16{700}));
    EXPECT_EQ(fields[2], Variant(Int32{12}));
    EXPECT_EQ(fields[3], Variant(f.eventType));
    EXPECT_EQ(fields[4], Variant(f.gripper));
    ASSERT_NE(fields[5].scalar<ByteString>(), nullptr);
    EXPECT_EQ(fields[5].scalar<ByteString>()->size(), 16u);
    EXPECT_NE(fields[6].scalar<DateTime>(), nullptr);
    EXPECT_NE(fields[7].scalar<DateTime>(), nullptr);
    EXPECT_EQ(fields[8], Variant(String("Gripper")));
}

// Fields shared by many events (a state machine's transition) are selected like the event's
// own; where both name a path, the event's own value wins.
TEST(Events, SharedFieldsAreSelectedAndTheEventsOwnWin) {
    EventFixture f;
    UInt32 sub = f.subscribe(10);
    EventFilter ef;
    ef.selectClauses = {field({{1, "Force"}}), field({{1, "Arm"}, {1, "Id"}}),
                        field({{1, "Unknown"}})};
    auto item = f.monitor(sub, f.robot, 1, 0, toExtensionObject(ef), 0, true, 12);
    ASSERT_TRUE(item.statusCode.isGood()) << item.statusCode.toString();
    auto shared = std::make_shared<server::Event::Fields>();
    shared->push_back({{QualifiedName{1, "Force"}}, Variant(Int32{1})});
    shared->push_back({{QualifiedName{1, "Arm"}, QualifiedName{1, "Id"}}, Variant(UInt32{7})});
    const std::shared_ptr<const server::Event::Fields> common = shared;
    for (Int32 force : {20, 30}) {
        server::Event e;
        e.eventType = f.eventType;
        e.sourceNode = f.gripper;
        e.sharedFields = common;
        e.set(QualifiedName{1, "Force"}, Variant(force));
        f.server.fireEvent(std::move(e));
    }
    std::vector<EventFieldList> ev;
    for (int i = 0; i < 20 && ev.size() < 2; ++i) {
        auto got = eventsOf(f.publish());
        ev.insert(ev.end(), got.begin(), got.end());
    }
    ASSERT_EQ(ev.size(), 2u);
    for (std::size_t k = 0; k < 2; ++k) {
        ASSERT_EQ(ev[k].eventFields.size(), 3u);
        EXPECT_EQ(ev[k].eventFields[0], Variant(Int32{k == 0 ? 20 : 30}));
        EXPECT_EQ(ev[k].eventFields[1], Variant(UInt32{7}));
        EXPECT_TRUE(ev[k].eventFields[2].isEmpty());
    }
    EXPECT_EQ(common->size(), 2u);  // not consumed by the events
}

TEST(Events, WhereClauses) {
    EventFixture f;
    UInt32 sub = f.subscribe(10);
    // OfType(GripEventType) And (Severity InList [100, 700] Or Not(Force == 3)) ... i.e.
    // Or(InList(Severity, 100, 700), Not(Equals(Force, 3))).
    EventFilter ef = gripFilter();
    auto el = [](FilterOperator op, std::vector<ExtensionObject> ops) {
        ContentFilterElement e;
        e.filterOperator = op;
        e.filterOperands = std::move(ops);
        return e;
    };
    ef.whereClause.elements = {
        el(FilterOperator::And, {element(1), element(2)}),
        el(FilterOperator::OfType, {literal(Variant(f.eventType))}),
        el(FilterOperator::Or, {element(3), element(4)}),
        el(FilterOperator::InList,
           {attr({{0, "Severity"}}), literal(Variant(UInt16{100})), literal(Variant(Int32{700}))}),
        el(FilterOperator::Not, {element(5)}),
        el(FilterOperator::Equals, {attr({{1, "Force"}}), literal(Variant(Int32{3}))}),
    };
    auto item = f.monitor(sub, NodeId(0, ns0::Server), 1, 0, toExtensionObject(ef), 0, true, 12);
    ASSERT_TRUE(item.statusCode.isGood()) << item.statusCode.toString();
    f.fire(700, 3, f.eventType);                    // InList: yes
    f.fire(500, 3, f.eventType);                    // neither
    f.fire(500, 4, f.eventType);                    // Not(Force == 3): yes
    f.fire(700, 4, NodeId(0, ns0::BaseEventType));  // wrong type
    std::vector<Int32> forces;
    std::vector<UInt16> severities;
    for (int i = 0; i < 20 && forces.size() < 2; ++i)
        for (const auto& e : eventsOf(f.publish())) {
            forces.push_back(*e.eventFields.at(2).scalar<Int32>());
            severities.push_back(*e.eventFields.at(1).scalar<UInt16>());
        }
    // One more round: nothing else may arrive.
    for (const auto& e : eventsOf(f.publish()))
        forces.push_back(*e.eventFields.at(2).scalar<Int32>());
    EXPECT_EQ(forces, (std::vector<Int32>{3, 4}));
    EXPECT_EQ(severities, (std::vector<UInt16>{700, 500}));
}

TEST(Events, InvalidFiltersAreRefusedWithResults) {
    EventFixture f;
    UInt32 sub = f.subscribe(10);
    EventFilter ef = gripFilter();
    ContentFilterElement like;
    like.filterOperator = FilterOperator::Like;
    like.filterOperands = {attr({{0, "Message"}}), literal(Variant(String("a%")))};
    ContentFilterElement badOperand;
    badOperand.filterOperator = FilterOperator::Not;
    badOperand.filterOperands = {element(0)};  // points backwards: a loop
    ef.whereClause.elements = {like, badOperand};
    auto item = f.monitor(sub, NodeId(0, ns0::Server), 1, 0, toExtensionObject(ef), 0, true, 12);
    EXPECT_EQ(item.statusCode, StatusCode(status::BadMonitoredItemFilterInvalid));
    auto result = fromExtensionObject<EventFilterResult>(item.filterResult);
    ASSERT_TRUE(result);
    ASSERT_EQ(result->whereClauseResult.elementResults.size(), 2u);
    EXPECT_EQ(result->whereClauseResult.elementResults[0].statusCode,
              StatusCode(status::BadFilterOperatorUnsupported));
    EXPECT_EQ(result->whereClauseResult.elementResults[1].statusCode,
              StatusCode(status::BadFilterOperandInvalid));

    EventFilter badSelect;
    badSelect.selectClauses = {field({{0, "Message"}})};
    badSelect.selectClauses[0].attributeId = 5;  // DisplayName: not of an event field
    badSelect.selectClauses.push_back(field({{0, ""}}));
    item = f.monitor(sub, NodeId(0, ns0::Server), 1, 0, toExtensionObject(badSelect), 0, true, 12);
    EXPECT_EQ(item.statusCode, StatusCode(status::BadMonitoredItemFilterInvalid));
    result = fromExtensionObject<EventFilterResult>(item.filterResult);
    ASSERT_TRUE(result);
    ASSERT_EQ(result->selectClauseResults.size(), 2u);
    EXPECT_EQ(result->selectClauseResults[0], StatusCode(status::BadAttributeIdInvalid));
    EXPECT_EQ(result->selectClauseResults[1], StatusCode(status::BadBrowseNameInvalid));

    EXPECT_EQ(f.monitor(sub, NodeId(0, ns0::Server), 1, 0, {}, 0, true, 12).statusCode,
              StatusCode(status::BadMonitoredItemFilterInvalid));
    EXPECT_EQ(
        f.monitor(sub, NodeId(0, ns0::Server), 1, 0, toExtensionObject(EventFilter{}), 0, true, 12)
            .statusCode,
        StatusCode(status::BadMonitoredItemFilterInvalid));  // nothing selected
}

TEST(Subscriptions, LifetimeExpiresWithoutPublishRequests) {
    Fixture f;
    const UInt32 sub = f.subscribe(10, 1);  // keep-alive 1, lifetime revised to >= 3 intervals
    EXPECT_EQ(f.server.subscriptions().statistics().subscriptions, 1u);
    for (int i = 0; i < 200 && f.server.subscriptions().statistics().subscriptions != 0; ++i)
        std::this_thread::sleep_for(5ms);
    EXPECT_EQ(f.server.subscriptions().statistics().subscriptions, 0u);
    // The session, still open, hears of it on its next Publish request (§5.13.1.2).
    auto r = f.publish();
    EXPECT_EQ(r.subscriptionId, sub);
    EXPECT_EQ(statusChangesOf(r), std::vector<StatusCode>{status::BadTimeout});
    EXPECT_EQ(errorOf([&] { f.publish(); }), StatusCode(status::BadNoSubscription));
}

TEST(Subscriptions, TransferToAnotherSessionWithInitialValues) {
    Fixture f;
    UInt32 sub = f.subscribe(20, 10);
    ASSERT_TRUE(f.monitor(sub, f.dbl, 7).statusCode.isGood());
    auto first = f.publishData();  // the first value, not acknowledged
    ASSERT_EQ(dataOf(first).size(), 1u);
    const UInt32 seq = first.notificationMessage.sequenceNumber;

    Client b;
    b.connect(url(f.server));
    TransferSubscriptionsRequest t;
    t.subscriptionIds = {sub, sub + 99};
    t.sendInitialValues = true;
    auto tr = b.request(t);
    ASSERT_EQ(tr.results.size(), 2u);
    EXPECT_EQ(tr.results[0].statusCode, StatusCode(status::Good));
    EXPECT_EQ(tr.results[0].availableSequenceNumbers, std::vector<UInt32>{seq});
    EXPECT_EQ(tr.results[1].statusCode, StatusCode(status::BadSubscriptionIdInvalid));

    // B receives the current value again, although it did not change.
    auto r = publishData(b);
    EXPECT_EQ(r.subscriptionId, sub);
    auto d = dataOf(r);
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(d[0].clientHandle, 7u);
    EXPECT_EQ(doubleOf(d[0]), 0.0);
    f.server.addressSpace().setValue(f.dbl, DataValue(Variant(Double{4})));
    d = dataOf(publishData(b));
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(doubleOf(d[0]), 4.0);

    // A is told on its next Publish request, and has no subscription left.
    auto a = f.publish();
    EXPECT_EQ(a.subscriptionId, sub);
    EXPECT_EQ(statusChangesOf(a), std::vector<StatusCode>{status::GoodSubscriptionTransferred});
    EXPECT_EQ(errorOf([&] { f.publish(); }), StatusCode(status::BadNoSubscription));
    DeleteSubscriptionsRequest del;
    del.subscriptionIds = {sub};
    EXPECT_EQ(f.c.request(del).results.at(0), StatusCode(status::BadSubscriptionIdInvalid));
    EXPECT_EQ(b.request(del).results.at(0), StatusCode(status::Good));
}

TEST(Subscriptions, TransferAnswersAWaitingPublishOfTheOldSession) {
    Fixture f;
    UInt32 sub = f.subscribe(1000, 100);  // no keep-alive for a long time
    f.publish();                          // the first keep-alive
    std::atomic<bool> done{false};
    PublishResponse a;
    StatusCode aError;
    std::thread waiting([&] {
        aError = errorOf([&] { a = f.publish(); });
        done = true;
    });
    for (int i = 0; i < 300 && f.server.subscriptions().statistics().queuedPublishRequests == 0;
         ++i)
        std::this_thread::sleep_for(10ms);
    Client b;
    b.connect(url(f.server));
    TransferSubscriptionsRequest t;
    t.subscriptionIds = {sub};
    EXPECT_EQ(b.request(t).results.at(0).statusCode, StatusCode(status::Good));
    waiting.join();
    EXPECT_TRUE(done);
    EXPECT_EQ(aError, StatusCode(status::Good));
    EXPECT_EQ(a.subscriptionId, sub);
    EXPECT_EQ(statusChangesOf(a), std::vector<StatusCode>{status::GoodSubscriptionTransferred});
}

TEST(Subscriptions, TransferNeedsTheSameUser) {
    auto cfg = testConfig();
    cfg.accessControl = std::make_shared<server::DefaultAccessControl>(
        true, std::map<std::string, std::string>{{"alice", "a"}, {"bob", "b"}});
    server::Server server(cfg);
    server.start();
    Client anon, alice, alice2, bob;
    anon.connect(url(server));
    alice.connect(url(server), client::UserName{"alice", "a"});
    alice2.connect(url(server), client::UserName{"alice", "a"});
    bob.connect(url(server), client::UserName{"bob", "b"});
    const CreateSubscriptionRequest cs = quietSubscription();
    const UInt32 anonSub = anon.request(cs).subscriptionId;
    const UInt32 aliceSub = alice.request(cs).subscriptionId;
    TransferSubscriptionsRequest t;
    t.subscriptionIds = {anonSub, aliceSub};
    auto byBob = bob.request(t);
    ASSERT_EQ(byBob.results.size(), 2u);
    EXPECT_EQ(byBob.results[0].statusCode, StatusCode(status::BadUserAccessDenied));
    EXPECT_EQ(byBob.results[1].statusCode, StatusCode(status::BadUserAccessDenied));
    auto byAnon = anon.request(t);
    EXPECT_EQ(byAnon.results.at(0).statusCode, StatusCode(status::Good));  // its own
    EXPECT_EQ(byAnon.results.at(1).statusCode, StatusCode(status::BadUserAccessDenied));
    auto byAlice2 = alice2.request(t);
    EXPECT_EQ(byAlice2.results.at(0).statusCode, StatusCode(status::BadUserAccessDenied));
    EXPECT_EQ(byAlice2.results.at(1).statusCode, StatusCode(status::Good));
    // Bounded like the other subscription services.
    t.subscriptionIds.assign(cfg.subscriptionLimits.maxMonitoredItemsPerCall + 1, anonSub);
    EXPECT_EQ(errorOf([&] { bob.request(t); }), StatusCode(status::BadTooManyOperations));
    t.subscriptionIds.clear();
    EXPECT_EQ(errorOf([&] { bob.request(t); }), StatusCode(status::BadNothingToDo));
}

TEST(Subscriptions, CloseSessionCanKeepSubscriptionsForATransfer) {
    Fixture f;
    const UInt32 kept = f.subscribe(1000, 10);  // lifetime 30 s
    ASSERT_TRUE(f.monitor(kept, f.dbl, 3).statusCode.isGood());
    const UInt32 expiring = f.subscribe(50, 4);  // lifetime 12 x 50 ms
    CloseSessionRequest close;
    close.deleteSubscriptions = false;
    f.c.request(close);
    EXPECT_EQ(f.server.subscriptions().statistics().subscriptions, 2u);
    // Orphaned subscriptions keep counting their lifetime.
    for (int i = 0; i < 300 && f.server.subscriptions().statistics().subscriptions != 1; ++i)
        std::this_thread::sleep_for(10ms);
    EXPECT_EQ(f.server.subscriptions().statistics().subscriptions, 1u);

    f.server.addressSpace().setValue(f.dbl, DataValue(Variant(Double{8})));
    Client b;
    b.connect(url(f.server));
    TransferSubscriptionsRequest t;
    t.subscriptionIds = {kept, expiring};
    t.sendInitialValues = true;
    auto tr = b.request(t);
    ASSERT_EQ(tr.results.size(), 2u);
    EXPECT_EQ(tr.results[0].statusCode, StatusCode(status::Good));
    EXPECT_EQ(tr.results[1].statusCode, StatusCode(status::BadSubscriptionIdInvalid));
    auto r = publishData(b);
    EXPECT_EQ(r.subscriptionId, kept);
    auto d = dataOf(r);
    ASSERT_FALSE(d.empty());
    EXPECT_EQ(d.back().clientHandle, 3u);
    EXPECT_EQ(doubleOf(d.back()), 8.0);
}

TEST(Subscriptions, PublishingDisabledSendsKeepAlivesOnly) {
    Fixture f;
    UInt32 sub = f.subscribe(10, 2);
    ASSERT_TRUE(f.monitor(sub, f.dbl, 1).statusCode.isGood());
    f.publishData();
    SetPublishingModeRequest pm;
    pm.publishingEnabled = false;
    pm.subscriptionIds = {sub, sub + 77};
    auto r = f.c.request(pm);
    ASSERT_EQ(r.results.size(), 2u);
    EXPECT_EQ(r.results[0], StatusCode(status::Good));
    EXPECT_EQ(r.results[1], StatusCode(status::BadSubscriptionIdInvalid));
    f.server.addressSpace().setValue(f.dbl, DataValue(Variant(Double{9})));
    for (int i = 0; i < 3; ++i) EXPECT_TRUE(dataOf(f.publish()).empty());
    pm.publishingEnabled = true;
    pm.subscriptionIds = {sub};
    f.c.request(pm);
    auto d = dataOf(f.publishData());
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(doubleOf(d[0]), 9.0);
}

TEST(Subscriptions, ModifyMonitoredItemsRevisesAndAppliesTheFilter) {
    Fixture f;
    UInt32 sub = f.subscribe(10);
    auto item = f.monitor(sub, f.dbl, 1, -1);  // -1: the publishing interval
    ASSERT_TRUE(item.statusCode.isGood());
    EXPECT_EQ(item.revisedSamplingInterval, 10);
    f.publishData();
    ModifyMonitoredItemsRequest mm;
    mm.subscriptionId = sub;
    mm.timestampsToReturn = TimestampsToReturn::Neither;
    MonitoredItemModifyRequest m;
    m.monitoredItemId = item.monitoredItemId;
    m.requestedParameters.clientHandle = 5;
    m.requestedParameters.samplingInterval = 0;
    m.requestedParameters.queueSize = 100000;  // beyond the server's limit
    m.requestedParameters.filter = absoluteDeadband(10);
    mm.itemsToModify = {m, m};
    mm.itemsToModify[1].monitoredItemId = 4242;
    auto r = f.c.request(mm);
    ASSERT_EQ(r.results.size(), 2u);
    EXPECT_TRUE(r.results[0].statusCode.isGood());
    EXPECT_EQ(r.results[0].revisedQueueSize, testConfig().subscriptionLimits.maxQueueSize);
    EXPECT_EQ(r.results[0].revisedSamplingInterval, 0);
    EXPECT_EQ(r.results[1].statusCode, StatusCode(status::BadMonitoredItemIdInvalid));
    auto& as = f.server.addressSpace();
    as.setValue(f.dbl, DataValue(Variant(Double{5})));   // within the deadband of 0
    as.setValue(f.dbl, DataValue(Variant(Double{20})));  // beyond it
    auto d = dataOf(f.publishData());
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(d[0].clientHandle, 5u);
    EXPECT_EQ(doubleOf(d[0]), 20.0);
    EXPECT_FALSE(d[0].value.sourceTimestamp.has_value());  // Neither
    EXPECT_FALSE(d[0].value.serverTimestamp.has_value());
}

TEST(Subscriptions, PublishRequestsTimeOutByTheirHint) {
    Fixture f;
    f.subscribe(1000, 100);  // nothing to send for a long time
    f.publish();             // the first keep-alive (after one interval)
    PublishRequest p;
    auto t0 = std::chrono::steady_clock::now();
    // The client sends its deadline as the timeoutHint; the server answers BadTimeout.
    EXPECT_EQ(errorOf([&] { f.c.request(p, 300ms); }), StatusCode(status::BadTimeout));
    EXPECT_LT(std::chrono::steady_clock::now() - t0, 3s);
    // The server no longer holds it (it would otherwise wait for the next keep-alive, 100 s).
    for (int i = 0; i < 300 && f.server.subscriptions().statistics().queuedPublishRequests != 0;
         ++i)
        std::this_thread::sleep_for(10ms);
    EXPECT_EQ(f.server.subscriptions().statistics().queuedPublishRequests, 0u);
}

TEST(Subscriptions, TooManyAcknowledgementsAreRefused) {
    Fixture f;
    UInt32 sub = f.subscribe();
    const auto lim = testConfig().subscriptionLimits;
    std::vector<SubscriptionAcknowledgement> acks(
        lim.maxSubscriptionsPerSession * lim.maxRetransmissionQueue + 1, {sub, 1});
    EXPECT_EQ(errorOf([&] { f.publish(acks); }), StatusCode(status::BadTooManyOperations));
    EXPECT_EQ(f.server.subscriptions().statistics().subscriptions, 1u);
}

TEST(Subscriptions, KeptSubscriptionsAreBounded) {
    auto cfg = testConfig();
    cfg.subscriptionLimits.maxKeptSubscriptions = 1;
    server::Server server(cfg);
    server.start();
    const CreateSubscriptionRequest cs = quietSubscription();
    CloseSessionRequest close;
    close.deleteSubscriptions = false;
    Client a, b;
    a.connect(url(server));
    b.connect(url(server));
    a.request(cs);
    a.request(cs);
    b.request(cs);
    EXPECT_EQ(server.subscriptions().statistics().subscriptions, 3u);
    a.request(close);
    EXPECT_EQ(server.subscriptions().statistics().subscriptions, 2u);  // one of a's is kept
    b.request(close);
    EXPECT_EQ(server.subscriptions().statistics().subscriptions, 1u);  // no room for b's
}
