// The RTDE codec: every package and value type round-trips, malformed frames give DecodeError.
#include "rtde/codec.hpp"

#include <gtest/gtest.h>

#include <set>
#include <stdexcept>

#include "rtde/catalogue.hpp"

namespace pnp::rtde {
namespace {

std::vector<std::uint8_t> bytes(std::initializer_list<int> list) {
    std::vector<std::uint8_t> v;
    for (int b : list) v.push_back(static_cast<std::uint8_t>(b));
    return v;
}

Package roundTrip(const Package& p, Direction direction) {
    auto wire = encode(p);
    EXPECT_EQ(((wire[0] << 8) | wire[1]), static_cast<int>(wire.size()));
    EXPECT_EQ(wire[2], static_cast<std::uint8_t>(packageTypeOf(p)));
    auto decoded = decode(wire, direction);
    if (auto* e = std::get_if<DecodeError>(&decoded)) {
        ADD_FAILURE() << e->message;
        return p;
    }
    return std::get<Package>(decoded);
}

TEST(RtdeCodec, RequestsRoundTrip) {
    auto v = roundTrip(RequestProtocolVersion{2}, Direction::toController);
    EXPECT_EQ(std::get<RequestProtocolVersion>(v).version, 2);
    EXPECT_EQ(encode(RequestProtocolVersion{2}), bytes({0, 5, 'V', 0, 2}));
    EXPECT_TRUE(std::holds_alternative<GetControllerVersion>(
        roundTrip(GetControllerVersion{}, Direction::toController)));
    auto o = std::get<SetupOutputs>(
        roundTrip(SetupOutputs{250.0, {"timestamp", "actual_q"}}, Direction::toController));
    EXPECT_EQ(o.frequency, 250.0);
    EXPECT_EQ(o.names, (std::vector<std::string>{"timestamp", "actual_q"}));
    auto i = std::get<SetupInputs>(
        roundTrip(SetupInputs{{"input_int_register_0"}}, Direction::toController));
    EXPECT_EQ(i.names, std::vector<std::string>{"input_int_register_0"});
    EXPECT_TRUE(std::holds_alternative<Start>(roundTrip(Start{}, Direction::toController)));
    EXPECT_TRUE(std::holds_alternative<Pause>(roundTrip(Pause{}, Direction::toController)));
    EXPECT_EQ(encode(Start{}), bytes({0, 3, 'S'}));
}

TEST(RtdeCodec, RepliesRoundTrip) {
    EXPECT_TRUE(
        std::get<ProtocolVersionReply>(roundTrip(ProtocolVersionReply{true}, Direction::toClient))
            .accepted);
    EXPECT_FALSE(
        std::get<ProtocolVersionReply>(roundTrip(ProtocolVersionReply{false}, Direction::toClient))
            .accepted);
    ControllerVersion cv{5, 15, 2, 12345};
    EXPECT_EQ(std::get<ControllerVersion>(roundTrip(cv, Direction::toClient)), cv);
    SetupOutputsReply so;
    so.recipeId = 3;
    so.types = {"DOUBLE", "NOT_FOUND"};
    auto so2 = std::get<SetupOutputsReply>(roundTrip(so, Direction::toClient));
    EXPECT_EQ(so2.recipeId, 3);
    EXPECT_EQ(so2.types, so.types);
    SetupInputsReply si;
    si.recipeId = 0;
    si.types = {"IN_USE"};
    EXPECT_EQ(encode(si)[2], 'I');
    auto si2 = std::get<SetupInputsReply>(roundTrip(si, Direction::toClient));
    EXPECT_EQ(si2.types, si.types);
    EXPECT_TRUE(std::get<StartReply>(roundTrip(StartReply{true}, Direction::toClient)).accepted);
    EXPECT_TRUE(std::get<PauseReply>(roundTrip(PauseReply{true}, Direction::toClient)).accepted);
}

TEST(RtdeCodec, DataAndTextBothDirections) {
    for (auto dir : {Direction::toController, Direction::toClient}) {
        auto d = std::get<DataPackage>(roundTrip(DataPackage{7, {1, 2, 3}}, dir));
        EXPECT_EQ(d.recipeId, 7);
        EXPECT_EQ(d.payload, bytes({1, 2, 3}));
        auto t = std::get<TextMessage>(
            roundTrip(TextMessage{"hello", "src", WarningLevel::warning}, dir));
        EXPECT_EQ(t.message, "hello");
        EXPECT_EQ(t.source, "src");
        EXPECT_EQ(t.level, WarningLevel::warning);
    }
    // Version 2 layout: length + message, length + source, level.
    EXPECT_EQ(encode(TextMessage{"ab", "c", WarningLevel::error}),
              bytes({0, 9, 'M', 2, 'a', 'b', 1, 'c', 1}));
    // Strings beyond 255 bytes are cut, not wrapped.
    auto t = std::get<TextMessage>(
        roundTrip(TextMessage{std::string(300, 'x'), "", WarningLevel::info}, Direction::toClient));
    EXPECT_EQ(t.message.size(), 255u);
}

TEST(RtdeCodec, EveryValueTypeRoundTrips) {
    std::vector<Value> values = {
        true,
        std::uint8_t{200},
        std::uint32_t{0xdeadbeef},
        std::uint64_t{0x0123456789abcdefULL},
        std::int32_t{-123456},
        -1.5e300,
        Vector3d{1.0, -2.0, 3.5},
        Vector6d{0.1, 0.2, 0.3, -0.4, 0.5, 6e-9},
        Vector6Int32{-1, 2, -3, 4, -5, 2147483647},
        Vector6Uint32{1, 2, 3, 4, 5, 4294967295u},
    };
    std::vector<Type> types;
    std::size_t total = 0;
    for (const Value& v : values) {
        types.push_back(typeOf(v));
        total += encodedSize(typeOf(v));
        EXPECT_EQ(parseTypeName(typeName(typeOf(v))), typeOf(v));
        EXPECT_EQ(typeOf(defaultValue(typeOf(v))), typeOf(v));
    }
    auto payload = encodeValues(values);
    EXPECT_EQ(payload.size(), total);
    auto decoded = decodeValues(types, payload);
    ASSERT_TRUE(std::holds_alternative<std::vector<Value>>(decoded));
    EXPECT_EQ(std::get<std::vector<Value>>(decoded), values);
    EXPECT_FALSE(parseTypeName("FLOAT").has_value());
}

TEST(RtdeCodec, ValuesAreBigEndian) {
    std::vector<Value> v = {std::uint32_t{0x01020304}, std::int32_t{-2}};
    EXPECT_EQ(encodeValues(v), bytes({1, 2, 3, 4, 0xff, 0xff, 0xff, 0xfe}));
    std::vector<Value> d = {1.0};
    EXPECT_EQ(encodeValues(d), bytes({0x3f, 0xf0, 0, 0, 0, 0, 0, 0}));
}

TEST(RtdeCodec, MalformedValuesAreErrors) {
    std::vector<Type> types = {Type::int32, Type::float64};
    EXPECT_TRUE(std::holds_alternative<DecodeError>(decodeValues(types, bytes({0, 0, 0, 1}))));
    std::vector<std::uint8_t> tooMany(13, 0);
    EXPECT_TRUE(std::holds_alternative<DecodeError>(decodeValues(types, tooMany)));
    std::vector<Type> b = {Type::boolean};
    EXPECT_TRUE(std::holds_alternative<DecodeError>(decodeValues(b, bytes({2}))));
}

void expectFrameError(const std::vector<std::uint8_t>& wire, Direction dir, const char* what) {
    auto f = decodeFrame(wire, dir);
    EXPECT_EQ(f.kind, FrameResult::Kind::error) << what;
}

TEST(RtdeCodec, MalformedFramesAreErrors) {
    expectFrameError(bytes({0, 2, 'V'}), Direction::toController, "size below header");
    expectFrameError(bytes({0, 0, 'V'}), Direction::toController, "size zero");
    expectFrameError(bytes({0xff, 0xff, 'U'}), Direction::toController, "oversize");
    expectFrameError(bytes({0x10, 0x01, 'U'}), Direction::toController, "4097 bytes");
    expectFrameError(bytes({0, 3, 'X'}), Direction::toController, "unknown type");
    expectFrameError(bytes({0, 4, 'V', 0}), Direction::toController, "truncated version");
    expectFrameError(bytes({0, 4, 'S', 0}), Direction::toController, "trailing byte");
    expectFrameError(bytes({0, 4, 'v', 1}), Direction::toController, "trailing byte");
    expectFrameError(bytes({0, 10, 'v', 0, 0, 0, 5, 0, 0, 0}), Direction::toClient,
                     "truncated controller version");
    expectFrameError(bytes({0, 10, 'O', 0, 0, 0, 0, 0, 0, 0}), Direction::toController,
                     "truncated frequency");
    expectFrameError(bytes({0, 3, 'U'}), Direction::toController, "data without recipe id");
    expectFrameError(bytes({0, 6, 'M', 5, 'a', 'b'}), Direction::toClient, "text too short");
    expectFrameError(bytes({0, 6, 'M', 0, 0, 9}), Direction::toClient, "bad warning level");
    // An error shows as soon as the header is there, without waiting for the payload.
    expectFrameError(bytes({0xff, 0xff, 'V'}), Direction::toController, "header only");
}

TEST(RtdeCodec, PartialFramesNeedMore) {
    auto wire = encode(SetupOutputs{125.0, {"actual_q"}});
    for (std::size_t n = 0; n < wire.size(); ++n) {
        auto f = decodeFrame(std::span(wire).first(n), Direction::toController);
        EXPECT_EQ(f.kind, FrameResult::Kind::needMore) << n;
    }
    wire.push_back(0);  // the start of the next package
    auto f = decodeFrame(wire, Direction::toController);
    ASSERT_EQ(f.kind, FrameResult::Kind::package);
    EXPECT_EQ(f.consumed, wire.size() - 1);
}

TEST(RtdeCodec, OversizedEncodeThrows) {
    SetupOutputs big{125.0, std::vector<std::string>(400, "output_double_register_10")};
    EXPECT_THROW(encode(big), std::length_error);
    std::vector<Value> values(600, Value{1.0});
    EXPECT_THROW(encodeValues(values), std::length_error);
}

TEST(RtdeCodec, Lists) {
    EXPECT_TRUE(splitList("").empty());
    EXPECT_EQ(splitList("a,b,,c"), (std::vector<std::string>{"a", "b", "", "c"}));
    std::vector<std::string> items = {"x", "y"};
    EXPECT_EQ(joinList(items), "x,y");
}

TEST(RtdeCatalogue, KnownNamesAndTypes) {
    struct Expect {
        const char* name;
        Type type;
        VariableKind kind;
    };
    const Expect expected[] = {
        {"timestamp", Type::float64, VariableKind::output},
        {"target_q", Type::vector6d, VariableKind::output},
        {"actual_q", Type::vector6d, VariableKind::output},
        {"actual_qd", Type::vector6d, VariableKind::output},
        {"actual_TCP_pose", Type::vector6d, VariableKind::output},
        {"actual_TCP_speed", Type::vector6d, VariableKind::output},
        {"actual_TCP_force", Type::vector6d, VariableKind::output},
        {"tcp_offset", Type::vector6d, VariableKind::output},
        {"robot_mode", Type::int32, VariableKind::output},
        {"safety_mode", Type::int32, VariableKind::output},
        {"runtime_state", Type::uint32, VariableKind::output},
        {"speed_scaling", Type::float64, VariableKind::output},
        {"actual_digital_input_bits", Type::uint64, VariableKind::output},
        {"joint_mode", Type::vector6int32, VariableKind::output},
        {"output_int_register_0", Type::int32, VariableKind::output},
        {"output_int_register_23", Type::int32, VariableKind::output},
        {"output_double_register_23", Type::float64, VariableKind::output},
        {"output_bit_register_64", Type::boolean, VariableKind::output},
        {"input_int_register_23", Type::int32, VariableKind::input},
        {"input_double_register_0", Type::float64, VariableKind::input},
        {"input_bit_registers0_to_31", Type::uint32, VariableKind::input},
        {"speed_slider_mask", Type::uint32, VariableKind::input},
        {"speed_slider_fraction", Type::float64, VariableKind::input},
        {"standard_digital_output_mask", Type::uint8, VariableKind::input},
        {"standard_digital_output", Type::uint8, VariableKind::input},
    };
    for (const Expect& e : expected) {
        auto v = findVariable(e.name, e.kind);
        ASSERT_TRUE(v.has_value()) << e.name;
        EXPECT_EQ(v->type, e.type) << e.name;
    }
    EXPECT_FALSE(findVariable("actual_q", VariableKind::input).has_value());
    EXPECT_FALSE(findVariable("input_int_register_0", VariableKind::output).has_value());
    EXPECT_FALSE(findVariable("no_such_variable", VariableKind::output).has_value());
    std::set<std::pair<std::string, VariableKind>> seen;
    for (const Variable& v : catalogue()) {
        EXPECT_TRUE(seen.emplace(v.name, v.kind).second) << "duplicate " << v.name;
    }
}

}  // namespace
}  // namespace pnp::rtde
