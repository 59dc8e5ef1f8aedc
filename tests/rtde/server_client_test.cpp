// The RTDE server and client against each other over loopback sockets: handshake, recipes,
// streaming rate, pause/start, inputs, input ownership, malformed packages, slow clients.
#include <gtest/gtest.h>

#include <chrono>
#include <memory>

#include "rtde/client.hpp"
#include "rtde/codec.hpp"
#include "rtde/server.hpp"
#include "rtde_helpers.hpp"

namespace pnp::rtde {
namespace {

using namespace std::chrono_literals;
using test::RawSocket;
using test::waitFor;

class RtdeServerTest : public ::testing::Test {
  protected:
    void SetUp() override {
        ServerConfig config;
        config.bindAddress = "127.0.0.1";
        config.port = 0;
        config.controllerVersion = {5, 16, 1, 4242};
        server_ = std::make_unique<Server>(config, store_);
        server_->start();
        ASSERT_NE(server_->port(), 0);
    }
    void TearDown() override { server_->stop(); }

    // A client that connected and negotiated version 2.
    std::unique_ptr<Client> ready() {
        auto c = std::make_unique<Client>();
        Status s = c->connect("127.0.0.1", server_->port(), deadlineIn(2000ms));
        EXPECT_TRUE(s.ok()) << s.message;
        s = c->negotiateProtocolVersion(deadlineIn(2000ms));
        EXPECT_TRUE(s.ok()) << s.message;
        return c;
    }

    // Receives data samples of any recipe for `span`; text messages are skipped.
    static int countSamples(Client& c, std::chrono::milliseconds span) {
        int n = 0;
        const auto end = deadlineIn(span);
        while (Clock::now() < end) {
            auto r = c.receive(end);
            if (!r.ok()) break;
            if (std::holds_alternative<DataSample>(r.value())) ++n;
        }
        return n;
    }

    // Empties what is queued or in flight, until nothing arrives for `quiet`.
    static void drain(Client& c, std::chrono::milliseconds quiet = 100ms) {
        for (int i = 0; i < 10000; ++i) {
            if (!c.receive(deadlineIn(quiet)).ok()) return;
        }
    }

    RegisterStore store_;
    std::unique_ptr<Server> server_;
};

TEST_F(RtdeServerTest, VersionTwoAcceptedVersionOneRefused) {
    Client c;
    ASSERT_TRUE(c.connect("127.0.0.1", server_->port(), deadlineIn(2000ms)).ok());
    Status s = c.negotiateProtocolVersion(deadlineIn(2000ms), 1);
    EXPECT_EQ(s.code, Code::rejected) << s.message;
    s = c.negotiateProtocolVersion(deadlineIn(2000ms), 2);
    EXPECT_TRUE(s.ok()) << s.message;
}

TEST_F(RtdeServerTest, ControllerVersion) {
    auto c = ready();
    auto v = c->getControllerVersion(deadlineIn(2000ms));
    ASSERT_TRUE(v.ok()) << v.status().message;
    EXPECT_EQ(v.value(), (ControllerVersion{5, 16, 1, 4242}));
}

TEST_F(RtdeServerTest, SetupBeforeNegotiationClosesTheConnection) {
    Client c;
    ASSERT_TRUE(c.connect("127.0.0.1", server_->port(), deadlineIn(2000ms)).ok());
    auto r = c.setupOutputs(125, {"timestamp"}, deadlineIn(2000ms));
    EXPECT_EQ(r.status().code, Code::closed) << r.status().message;
    EXPECT_FALSE(c.connected());
}

TEST_F(RtdeServerTest, ConnectToClosedPortFails) {
    const std::uint16_t port = server_->port();
    server_->stop();
    Client c;
    Status s = c.connect("127.0.0.1", port, deadlineIn(2000ms));
    EXPECT_FALSE(s.ok());
    EXPECT_EQ(c.negotiateProtocolVersion(deadlineIn(100ms)).code, Code::notConnected);
    server_->start();  // restart works (TearDown stops it again)
    EXPECT_NE(server_->port(), 0);
}

TEST_F(RtdeServerTest, OutputRecipeWithUnknownName) {
    auto c = ready();
    auto r = c->setupOutputs(125, {"timestamp", "no_such_thing", "actual_q"}, deadlineIn(2000ms));
    ASSERT_TRUE(r.ok()) << r.status().message;
    EXPECT_FALSE(r->valid());
    EXPECT_EQ(r->typeNames, (std::vector<std::string>{"DOUBLE", "NOT_FOUND", "VECTOR6D"}));
    // An input name is not an output.
    r = c->setupOutputs(125, {"input_int_register_0"}, deadlineIn(2000ms));
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->typeNames, std::vector<std::string>{"NOT_FOUND"});
    r = c->setupOutputs(125, {"timestamp", "actual_q"}, deadlineIn(2000ms));
    ASSERT_TRUE(r.ok());
    EXPECT_TRUE(r->valid());
    EXPECT_EQ(r->types, (std::vector<Type>{Type::float64, Type::vector6d}));
}

TEST_F(RtdeServerTest, OutputFrequencyOutOfRangeRefused) {
    auto c = ready();
    for (double f : {0.0, -5.0, 501.0}) {
        auto r = c->setupOutputs(f, {"timestamp"}, deadlineIn(2000ms));
        ASSERT_TRUE(r.ok()) << r.status().message;
        EXPECT_FALSE(r->valid()) << f;
    }
    auto r = c->setupOutputs(500, {"timestamp"}, deadlineIn(2000ms));
    ASSERT_TRUE(r.ok());
    EXPECT_TRUE(r->valid());
}

TEST_F(RtdeServerTest, InputInUseUntilOwnerDisconnects) {
    auto a = ready();
    auto b = ready();
    auto ra = a->setupInputs({"input_int_register_0", "speed_slider_mask"}, deadlineIn(2000ms));
    ASSERT_TRUE(ra.ok() && ra->valid()) << ra.status().message;
    auto rb = b->setupInputs({"input_int_register_1", "input_int_register_0"}, deadlineIn(2000ms));
    ASSERT_TRUE(rb.ok());
    EXPECT_FALSE(rb->valid());
    EXPECT_EQ(rb->typeNames, (std::vector<std::string>{"INT32", "IN_USE"}));
    // The owner may set up the same input again.
    auto again = a->setupInputs({"input_int_register_0"}, deadlineIn(2000ms));
    ASSERT_TRUE(again.ok() && again->valid());
    a->close();
    bool freed = waitFor([&] {
        auto r =
            b->setupInputs({"input_int_register_1", "input_int_register_0"}, deadlineIn(2000ms));
        return r.ok() && r->valid();
    });
    EXPECT_TRUE(freed);
    auto unknown = b->setupInputs({"actual_q"}, deadlineIn(2000ms));
    ASSERT_TRUE(unknown.ok());
    EXPECT_EQ(unknown->typeNames, std::vector<std::string>{"NOT_FOUND"});
}

TEST_F(RtdeServerTest, StreamsAtTheRequestedFrequencyWithValues) {
    store_.set("output_int_register_5", std::int32_t{42});
    store_.set("actual_q", Vector6d{1, 2, 3, 4, 5, 6});
    auto c = ready();
    auto r = c->setupOutputs(125, {"output_int_register_5", "actual_q"}, deadlineIn(2000ms));
    ASSERT_TRUE(r.ok() && r->valid());
    ASSERT_TRUE(c->start(deadlineIn(2000ms)).ok());
    auto first = c->receive(deadlineIn(2000ms));
    ASSERT_TRUE(first.ok()) << first.status().message;
    auto& sample = std::get<DataSample>(first.value());
    EXPECT_EQ(sample.recipeId, r->id);
    ASSERT_EQ(sample.values.size(), 2u);
    EXPECT_EQ(sample.values[0], Value{std::int32_t{42}});
    EXPECT_EQ(sample.values[1], Value(Vector6d{1, 2, 3, 4, 5, 6}));
    int n = countSamples(*c, 1000ms);
    EXPECT_GE(n, 125 * 0.7);
    EXPECT_LE(n, 125 * 1.3);
}

TEST_F(RtdeServerTest, TwoRecipesStreamEachAtItsRate) {
    auto c = ready();
    auto fast = c->setupOutputs(200, {"timestamp"}, deadlineIn(2000ms));
    auto slow = c->setupOutputs(50, {"robot_mode"}, deadlineIn(2000ms));
    ASSERT_TRUE(fast.ok() && fast->valid() && slow.ok() && slow->valid());
    ASSERT_TRUE(c->start(deadlineIn(2000ms)).ok());
    int nFast = 0, nSlow = 0;
    const auto end = deadlineIn(1000ms);
    while (Clock::now() < end) {
        auto r = c->receive(end);
        if (!r.ok()) break;
        if (auto* s = std::get_if<DataSample>(&r.value())) {
            (s->recipeId == fast->id ? nFast : nSlow)++;
        }
    }
    EXPECT_NEAR(nFast, 200, 60);
    EXPECT_NEAR(nSlow, 50, 15);
}

TEST_F(RtdeServerTest, PauseStopsAndStartRestarts) {
    auto c = ready();
    ASSERT_TRUE(c->setupOutputs(250, {"timestamp"}, deadlineIn(2000ms))->valid());
    ASSERT_TRUE(c->start(deadlineIn(2000ms)).ok());
    EXPECT_GT(countSamples(*c, 200ms), 20);
    ASSERT_TRUE(c->pause(deadlineIn(2000ms)).ok());
    drain(*c, 50ms);  // the samples that came before the pause reply
    auto r = c->receive(deadlineIn(300ms));
    EXPECT_EQ(r.status().code, Code::timeout);
    // Recipes can only be changed while paused.
    ASSERT_TRUE(c->setupOutputs(250, {"actual_q"}, deadlineIn(2000ms))->valid());
    ASSERT_TRUE(c->start(deadlineIn(2000ms)).ok());
    EXPECT_GT(countSamples(*c, 200ms), 20);
    auto refused = c->setupOutputs(250, {"actual_qd"}, deadlineIn(2000ms));
    ASSERT_TRUE(refused.ok());
    EXPECT_FALSE(refused->valid());
}

TEST_F(RtdeServerTest, InputsReachTheStore) {
    auto c = ready();
    auto r = c->setupInputs({"input_int_register_3", "input_double_register_7",
                             "standard_digital_output_mask", "input_bit_register_64"},
                            deadlineIn(2000ms));
    ASSERT_TRUE(r.ok() && r->valid()) << r.status().message;
    EXPECT_EQ(r->types,
              (std::vector<Type>{Type::int32, Type::float64, Type::uint8, Type::boolean}));
    ASSERT_TRUE(c->start(deadlineIn(2000ms)).ok());
    std::vector<Value> values = {std::int32_t{-77}, 3.25, std::uint8_t{0x0f}, true};
    Status s = c->send(r->id, values, deadlineIn(2000ms));
    ASSERT_TRUE(s.ok()) << s.message;
    EXPECT_TRUE(waitFor([&] { return store_.get("input_bit_register_64") == Value{true}; }));
    EXPECT_EQ(store_.get("input_int_register_3"), Value{std::int32_t{-77}});
    EXPECT_EQ(store_.get("input_double_register_7"), Value{3.25});
    EXPECT_EQ(store_.get("standard_digital_output_mask"), Value{std::uint8_t{0x0f}});
    // Values that do not match the recipe are refused on the client side.
    std::vector<Value> wrong = {1.0, 3.25, std::uint8_t{0}, true};
    EXPECT_EQ(c->send(r->id, wrong, deadlineIn(2000ms)).code, Code::invalidArgument);
    EXPECT_EQ(c->send(99, values, deadlineIn(2000ms)).code, Code::invalidArgument);
}

TEST_F(RtdeServerTest, TextMessagesReachClients) {
    auto a = ready();
    auto b = ready();
    server_->sendText({"safety stop", "controller", WarningLevel::warning});
    for (Client* c : {a.get(), b.get()}) {
        auto r = c->receive(deadlineIn(2000ms));
        ASSERT_TRUE(r.ok()) << r.status().message;
        auto& t = std::get<TextMessage>(r.value());
        EXPECT_EQ(t.message, "safety stop");
        EXPECT_EQ(t.source, "controller");
        EXPECT_EQ(t.level, WarningLevel::warning);
    }
    EXPECT_TRUE(a->sendText({"hello", "client", WarningLevel::info}, deadlineIn(1000ms)).ok());
    EXPECT_TRUE(a->getControllerVersion(deadlineIn(2000ms)).ok());
}

struct Malformed {
    const char* name;
    std::vector<std::uint8_t> bytes;
    bool negotiateFirst;
};

class RtdeMalformedTest : public RtdeServerTest, public ::testing::WithParamInterface<Malformed> {};

TEST_P(RtdeMalformedTest, ClosesThatConnectionOnly) {
    auto good = ready();
    ASSERT_TRUE(good->setupOutputs(125, {"timestamp"}, deadlineIn(2000ms))->valid());
    ASSERT_TRUE(good->start(deadlineIn(2000ms)).ok());

    RawSocket bad(server_->port());
    ASSERT_TRUE(bad.connected());
    if (GetParam().negotiateFirst) {
        ASSERT_TRUE(bad.send(encode(RequestProtocolVersion{2})));
        EXPECT_EQ(bad.read(4, 2000ms), (std::vector<std::uint8_t>{0, 4, 'V', 1}));
        ASSERT_TRUE(bad.send(encode(SetupInputs{{"input_int_register_9"}})));
        auto reply = bad.read(3 + 1 + 5, 2000ms);  // recipe 1, "INT32"
        ASSERT_EQ(reply.size(), 9u);
        EXPECT_EQ(reply[3], 1);
    }
    const auto errorsBefore = server_->stats().connectionsClosedForErrors;
    ASSERT_TRUE(bad.send(GetParam().bytes));
    EXPECT_TRUE(bad.waitClosed(2000ms)) << GetParam().name;
    EXPECT_EQ(server_->stats().connectionsClosedForErrors, errorsBefore + 1);

    // The other client keeps streaming and answering.
    EXPECT_GT(countSamples(*good, 300ms), 20);
    auto second = ready();
    EXPECT_TRUE(second->getControllerVersion(deadlineIn(2000ms)).ok());
    if (GetParam().negotiateFirst) {
        // The bad connection's inputs were released.
        EXPECT_TRUE(waitFor([&] {
            auto r = second->setupInputs({"input_int_register_9"}, deadlineIn(2000ms));
            return r.ok() && r->valid();
        }));
    }
}

INSTANTIATE_TEST_SUITE_P(Packages, RtdeMalformedTest,
                         ::testing::Values(Malformed{"size2", {0, 2, 'V'}, false},
                                           Malformed{"unknownType", {0, 3, 'X'}, false},
                                           Malformed{"truncatedVersion", {0, 4, 'V', 0}, false},
                                           Malformed{"oversize", {0xff, 0xff, 'U', 1, 2, 3}, false},
                                           Malformed{"trailingStart", {0, 4, 'S', 0}, true},
                                           Malformed{"shortInputData", {0, 6, 'U', 1, 0, 0}, true}),
                         [](const auto& info) { return std::string(info.param.name); });

TEST_F(RtdeServerTest, DisconnectMidStreamDoesNotDisturbOthers) {
    auto a = ready();
    auto b = ready();
    for (Client* c : {a.get(), b.get()}) {
        ASSERT_TRUE(
            c->setupOutputs(250, {"timestamp", "actual_TCP_pose"}, deadlineIn(2000ms))->valid());
        ASSERT_TRUE(c->start(deadlineIn(2000ms)).ok());
    }
    EXPECT_GT(countSamples(*a, 100ms), 5);
    a->close();
    int n = countSamples(*b, 1000ms);
    EXPECT_NEAR(n, 250, 75);
    EXPECT_TRUE(waitFor([&] { return server_->stats().clients == 1; }));
}

TEST_F(RtdeServerTest, SlowClientIsSkippedNotBlocking) {
    // A client that sets up a large recipe at 500 Hz and never reads.
    RawSocket slow(server_->port(), 4096);
    ASSERT_TRUE(slow.connected());
    ASSERT_TRUE(slow.send(encode(RequestProtocolVersion{2})));
    std::vector<std::string> names;
    for (int i = 0; i < 40; ++i) names.push_back("output_double_register_" + std::to_string(i));
    names.push_back("actual_q");
    names.push_back("actual_TCP_pose");
    ASSERT_TRUE(slow.send(encode(SetupOutputs{500, names})));
    ASSERT_TRUE(slow.send(encode(Start{})));

    auto good = ready();
    ASSERT_TRUE(good->setupOutputs(125, {"timestamp"}, deadlineIn(2000ms))->valid());
    ASSERT_TRUE(good->start(deadlineIn(2000ms)).ok());
    EXPECT_TRUE(waitFor([&] { return server_->stats().dataPackagesSkipped > 0; }, 20000ms));
    drain(*good, 5ms);  // the backlog of the wait (the socket buffers hold it)
    int n = countSamples(*good, 1000ms);
    EXPECT_NEAR(n, 125, 40);
}

TEST_F(RtdeServerTest, ManyClientsAtOnce) {
    std::vector<std::unique_ptr<Client>> clients;
    for (int i = 0; i < 8; ++i) {
        clients.push_back(ready());
        ASSERT_TRUE(clients.back()->setupOutputs(100, {"timestamp"}, deadlineIn(2000ms))->valid());
        ASSERT_TRUE(clients.back()->start(deadlineIn(2000ms)).ok());
    }
    // Every client is served: each gets its samples (backlog included) in a bounded time.
    for (auto& c : clients) {
        int n = 0;
        const auto end = deadlineIn(2000ms);
        while (n < 20 && c->receive(end).ok()) ++n;
        EXPECT_EQ(n, 20);
    }
    EXPECT_EQ(server_->stats().clients, 8u);
}

TEST_F(RtdeServerTest, StopWithClientsConnected) {
    auto a = ready();
    ASSERT_TRUE(a->setupOutputs(500, {"actual_q"}, deadlineIn(2000ms))->valid());
    ASSERT_TRUE(a->start(deadlineIn(2000ms)).ok());
    server_->stop();
    auto r = a->receive(deadlineIn(2000ms));
    // Samples already sent may still be read; the stream then ends with `closed`.
    for (int i = 0; i < 10000 && r.ok(); ++i) r = a->receive(deadlineIn(2000ms));
    EXPECT_EQ(r.status().code, Code::closed) << r.status().message;
}

}  // namespace
}  // namespace pnp::rtde
