// Unit tests of apps/pnp/value_text: text <-> value conversions of every built-in type.
#include "value_text.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::cli {
namespace {

using json = Json;

Variant parse(std::string_view text, std::string_view type, const ParseOptions& o = {}) {
    auto t = parseTypeName(type);
    EXPECT_TRUE(t.has_value()) << type;
    return parseValue(text, t->first, t->second, o);
}

// text -> value -> JSON -> value must give the same value back.
void expectJsonRoundTrip(const Variant& v) {
    json j = toJson(v);
    Shape shape = v.isArray() ? Shape::Array : Shape::Scalar;
    Variant back = valueFromJson(j, v.type(), shape);
    EXPECT_EQ(back, v) << j.dump();
    // ... and through the text of the JSON (what `write` gets from the shell).
    if (v.type() != BuiltinType::String && v.type() != BuiltinType::XmlElement &&
        v.type() != BuiltinType::LocalizedText) {
        Variant again = parseValue(j.dump(), v.type(), shape);
        EXPECT_EQ(again, v) << j.dump();
    }
}

TEST(TypeName, BuiltinNamesAndArrays) {
    EXPECT_EQ(parseTypeName("Int32")->first, BuiltinType::Int32);
    EXPECT_EQ(parseTypeName("int32")->second, Shape::Auto);
    EXPECT_EQ(parseTypeName("Double[]")->second, Shape::Array);
    EXPECT_EQ(parseTypeName("bool")->first, BuiltinType::Boolean);
    EXPECT_EQ(parseTypeName("Structure")->first, BuiltinType::ExtensionObject);
    EXPECT_EQ(parseTypeName("BaseDataType")->first, BuiltinType::Variant);
    EXPECT_FALSE(parseTypeName("Int33"));
    EXPECT_FALSE(parseTypeName("Null"));
}

TEST(ValueText, ShapeOfValueRank) {
    EXPECT_EQ(shapeOfValueRank(-1), Shape::Scalar);
    EXPECT_EQ(shapeOfValueRank(1), Shape::Array);
    EXPECT_EQ(shapeOfValueRank(2), Shape::Array);
    EXPECT_EQ(shapeOfValueRank(-2), Shape::Auto);
    EXPECT_EQ(shapeOfValueRank(-3), Shape::Auto);
    EXPECT_EQ(shapeOfValueRank(0), Shape::Auto);
}

TEST(ValueText, Boolean) {
    EXPECT_EQ(parse("true", "Boolean"), Variant(true));
    EXPECT_EQ(parse("FALSE", "Boolean"), Variant(false));
    EXPECT_EQ(parse("1", "Boolean"), Variant(true));
    EXPECT_THROW(parse("yes", "Boolean"), ValueError);
    EXPECT_EQ(toText(Variant(true)), "true");
    EXPECT_EQ(toJson(Variant(false)), json(false));
    expectJsonRoundTrip(Variant(std::vector<Boolean>{true, false, true}));
}

TEST(ValueText, IntegersAreRangeChecked) {
    EXPECT_EQ(parse("-128", "SByte"), Variant(SByte{-128}));
    EXPECT_THROW(parse("-129", "SByte"), ValueError);
    EXPECT_THROW(parse("128", "SByte"), ValueError);
    EXPECT_EQ(parse("255", "Byte"), Variant(Byte{255}));
    EXPECT_THROW(parse("256", "Byte"), ValueError);
    EXPECT_THROW(parse("-1", "Byte"), ValueError);
    EXPECT_EQ(parse("-32768", "Int16"), Variant(Int16{-32768}));
    EXPECT_EQ(parse("65535", "UInt16"), Variant(UInt16{65535}));
    EXPECT_EQ(parse("-2147483648", "Int32"), Variant(Int32{-2147483647 - 1}));
    EXPECT_THROW(parse("2147483648", "Int32"), ValueError);
    EXPECT_EQ(parse("0x2A", "Int32"), Variant(Int32{42}));
    EXPECT_EQ(parse(" 42 ", "Int32"), Variant(Int32{42}));
    EXPECT_EQ(parse("4294967295", "UInt32"), Variant(UInt32{4294967295u}));
    EXPECT_EQ(parse("-9223372036854775808", "Int64"), Variant(std::numeric_limits<Int64>::min()));
    EXPECT_EQ(parse("18446744073709551615", "UInt64"), Variant(std::numeric_limits<UInt64>::max()));
    EXPECT_THROW(parse("18446744073709551616", "UInt64"), ValueError);
    EXPECT_THROW(parse("1.5", "Int32"), ValueError);
    EXPECT_THROW(parse("", "Int32"), ValueError);
    EXPECT_THROW(parse("--1", "Int32"), ValueError);
    EXPECT_THROW(parse("12abc", "Int32"), ValueError);
    EXPECT_EQ(toText(Variant(SByte{-42})), "-42");
    EXPECT_EQ(toText(Variant(Byte{200})), "200");
    // 64-bit values stay exact in JSON.
    EXPECT_EQ(toJson(Variant(std::numeric_limits<UInt64>::max())).dump(), "18446744073709551615");
    EXPECT_EQ(toJson(Variant(std::numeric_limits<Int64>::min())).dump(), "-9223372036854775808");
    expectJsonRoundTrip(Variant(std::vector<Int64>{-5, 0, std::numeric_limits<Int64>::max()}));
    expectJsonRoundTrip(Variant(std::vector<UInt64>{0, 1, std::numeric_limits<UInt64>::max()}));
    expectJsonRoundTrip(Variant(std::vector<SByte>{-128, 0, 127}));
}

TEST(ValueText, Arrays) {
    EXPECT_EQ(parse("[1,2,3]", "Int32[]"), Variant(std::vector<Int32>{1, 2, 3}));
    EXPECT_EQ(parse("[1, 2, 3]", "Int32"), Variant(std::vector<Int32>{1, 2, 3}));  // Auto
    EXPECT_EQ(parse("[]", "Double[]"), Variant(std::vector<Double>{}));
    EXPECT_EQ(parse("[\"0x10\", 5]", "Byte[]"), Variant(std::vector<Byte>{16, 5}));
    EXPECT_THROW(parse("[1,300]", "Byte[]"), ValueError);
    EXPECT_THROW(parse("1", "Int32[]"), ValueError);
    EXPECT_THROW(parse("[1,2", "Int32[]"), ValueError);
    EXPECT_EQ(toText(Variant(std::vector<Int32>{1, 2, 3})), "[1,2,3]");
    EXPECT_EQ(typeText(Variant(std::vector<Int32>{1, 2, 3})), "Int32[3]");
    Variant m(std::vector<Int32>{1, 2, 3, 4, 5, 6});
    m.setArrayDimensions({2, 3});
    EXPECT_EQ(typeText(m), "Int32[2x3]");
    EXPECT_EQ(typeText(Variant()), "null");
    // A String scalar may look like an array: Auto only takes real JSON arrays.
    EXPECT_EQ(parse("[not json", "String"), Variant(String("[not json")));
    EXPECT_EQ(parse("[\"a\",\"\"]", "String"), Variant(std::vector<String>{"a", ""}));
}

TEST(ValueText, FloatingPoint) {
    EXPECT_EQ(parse("3.5", "Float"), Variant(Float{3.5f}));
    EXPECT_EQ(parse("-1e300", "Double"), Variant(Double{-1e300}));
    EXPECT_EQ(parse("+2", "Double"), Variant(Double{2}));
    EXPECT_THROW(parse("1e39", "Float"), ValueError);
    EXPECT_THROW(parse("abc", "Double"), ValueError);
    EXPECT_TRUE(std::isnan(*parse("NaN", "Double").scalar<Double>()));
    EXPECT_EQ(*parse("-Infinity", "Float").scalar<Float>(),
              -std::numeric_limits<Float>::infinity());
    EXPECT_EQ(toText(Variant(Double{3.141592653589793})), "3.141592653589793");
    EXPECT_EQ(toText(Variant(Float{0.1f})), "0.1");
    EXPECT_EQ(toJson(Variant(Float{0.1f})).dump(), "0.1");
    EXPECT_EQ(toJson(Variant(Double{NAN})), json("NaN"));
    EXPECT_EQ(toJson(Variant(Double{-INFINITY})), json("-Infinity"));
    expectJsonRoundTrip(Variant(std::vector<Double>{1.5, -1e300, 6.02214076e23, INFINITY}));
    expectJsonRoundTrip(Variant(std::vector<Float>{-2.25f, 0.5f, 1024.75f, 0.1f}));
}

TEST(ValueText, Strings) {
    EXPECT_EQ(parse("h\xc3\xa9llo \xe2\x9c\x93 pnp", "String"),
              Variant(String("h\xc3\xa9llo \xe2\x9c\x93 pnp")));
    EXPECT_EQ(parse("", "String"), Variant(String()));
    EXPECT_EQ(parse("<a x=\"1\"/>", "XmlElement"), Variant(XmlElement{"<a x=\"1\"/>"}));
    EXPECT_EQ(toText(Variant(String("plain"))), "plain");
    EXPECT_EQ(toText(Variant(std::vector<String>{"a", ""})), "[\"a\",\"\"]");
    expectJsonRoundTrip(Variant(std::vector<String>{"a", "", "\xc3\xbc\"\\"}));
    expectJsonRoundTrip(Variant(std::vector<XmlElement>{{"<a/>"}, {"<b>x</b>"}}));
}

TEST(ValueText, DateTime) {
    DateTime t = *parseDateTime("2024-05-06T07:08:09.123Z");
    EXPECT_EQ(dateTimeText(t), "2024-05-06T07:08:09.123Z");
    EXPECT_EQ(parse("2024-05-06T09:08:09.123+02:00", "DateTime"), Variant(t));
    EXPECT_EQ(parse("2024-05-06T07:08:09.123", "DateTime"), Variant(t));
    EXPECT_EQ(dateTimeText(*parseDateTime("2024-05-06")), "2024-05-06T00:00:00Z");
    EXPECT_EQ(dateTimeText(*parseDateTime("2030-12-31 23:59:59.9999999Z")),
              "2030-12-31T23:59:59.9999999Z");
    EXPECT_EQ(parseDateTime("1601-01-01T00:00:00Z")->ticks, 0);
    EXPECT_EQ(dateTimeText(DateTime{0}), "1601-01-01T00:00:00Z");
    EXPECT_EQ(parseDateTime("1970-01-01T00:00:00Z")->ticks, DateTime::kUnixEpochTicks);
    auto now = parseDateTime("now");
    ASSERT_TRUE(now);
    EXPECT_LT(std::abs(now->ticks - DateTime::now().ticks), 10000000);
    EXPECT_FALSE(parseDateTime("2024-13-01"));
    EXPECT_FALSE(parseDateTime("2024-05-06T07:08:09Zjunk"));
    EXPECT_FALSE(parseDateTime("yesterday"));
    EXPECT_THROW(parse("06.05.2024", "DateTime"), ValueError);
    expectJsonRoundTrip(Variant(std::vector<DateTime>{*parseDateTime("2001-01-01T00:00:00Z"),
                                                      *parseDateTime("2030-12-31T23:59:59.999Z")}));
}

TEST(ValueText, Guid) {
    auto g = Guid::parse("72962B91-FA75-4AE6-8D28-B404DC7DAF63");
    EXPECT_EQ(parse("72962b91-fa75-4ae6-8d28-b404dc7daf63", "Guid"), Variant(*g));
    EXPECT_EQ(parse("{72962B91-FA75-4AE6-8D28-B404DC7DAF63}", "Guid"), Variant(*g));
    EXPECT_THROW(parse("72962B91", "Guid"), ValueError);
    EXPECT_EQ(toText(Variant(*g)), "72962B91-FA75-4AE6-8D28-B404DC7DAF63");
    expectJsonRoundTrip(Variant(std::vector<Guid>{Guid{}, *g}));
}

TEST(ValueText, ByteString) {
    const ByteString b(std::string("\x00\x01\x02\xfe\xff", 5));
    EXPECT_EQ(parse("0x000102feff", "ByteString"), Variant(b));
    EXPECT_EQ(parse("0x00:01:02:FE:FF", "ByteString"), Variant(b));
    EXPECT_EQ(parse("AAEC/v8=", "ByteString"), Variant(b));
    EXPECT_EQ(parse("", "ByteString"), Variant(ByteString()));
    EXPECT_THROW(parse("0x123", "ByteString"), ValueError);
    EXPECT_THROW(parse("not base64!", "ByteString"), ValueError);
    EXPECT_EQ(toText(Variant(b)), "0x000102feff");
    EXPECT_EQ(toJson(Variant(b)), json("AAEC/v8="));
    expectJsonRoundTrip(Variant(std::vector<ByteString>{ByteString("abc"), ByteString(),
                                                        ByteString(std::string("\0", 1))}));
}

TEST(ValueText, NodeIds) {
    EXPECT_EQ(parse("i=85", "NodeId"), Variant(NodeId(0, 85)));
    EXPECT_EQ(parse("ns=1;s=pnp.Scalar", "NodeId"), Variant(NodeId(1, "pnp.Scalar")));
    EXPECT_THROW(parse("nsu=urn:pnp:demo;s=Demo", "NodeId"), ValueError);  // no resolver
    ParseOptions o;
    o.namespaceIndex = [](std::string_view uri) -> UInt16 {
        if (uri != "urn:pnp:demo") throw ValueError("unknown namespace");
        return 2;
    };
    EXPECT_EQ(parse("nsu=urn:pnp:demo;s=Demo", "NodeId", o), Variant(NodeId(2, "Demo")));
    EXPECT_THROW(parse("bogus", "NodeId"), ValueError);
    ExpandedNodeId x(NodeId(0, 1234), "urn:pnp:other", 0);
    EXPECT_EQ(parse("nsu=urn:pnp:other;i=1234", "ExpandedNodeId"), Variant(x));
    EXPECT_EQ(toText(Variant(x)), "nsu=urn:pnp:other;i=1234");
    expectJsonRoundTrip(Variant(
        std::vector<NodeId>{NodeId(0, 2253), NodeId(1, "hello"),
                            NodeId(1, *Guid::parse("72962B91-FA75-4AE6-8D28-B404DC7DAF63")),
                            NodeId(1, ByteString(std::string("\x01\x02\x03"))), NodeId(3, 70000)}));
    expectJsonRoundTrip(Variant(std::vector<ExpandedNodeId>{
        ExpandedNodeId(NodeId(0, 85)), ExpandedNodeId(NodeId(1, "x.y"), "", 2), x}));
}

TEST(ValueText, StatusCode) {
    EXPECT_EQ(parse("BadOutOfRange", "StatusCode"), Variant(status::BadOutOfRange));
    EXPECT_EQ(parse("0x800A0000", "StatusCode"), Variant(status::BadTimeout));
    EXPECT_EQ(parse("0", "StatusCode"), Variant(status::Good));
    EXPECT_THROW(parse("NotAStatus", "StatusCode"), ValueError);
    EXPECT_EQ(toText(Variant(status::BadNodeIdUnknown)), "BadNodeIdUnknown");
    EXPECT_EQ(statusText(StatusCode{0x8FFF0000u}), "0x8FFF0000");
    EXPECT_EQ(statusText(StatusCode{status::Good.value | 0x400u}), "Good (0x00000400)");
    expectJsonRoundTrip(Variant(std::vector<StatusCode>{
        status::Good, status::UncertainInitialValue, status::BadTimeout, StatusCode{0x8FFF0000u}}));
}

TEST(ValueText, QualifiedNameAndLocalizedText) {
    EXPECT_EQ(parse("1:Qn", "QualifiedName"), Variant(QualifiedName{1, "Qn"}));
    EXPECT_EQ(parse("Qn", "QualifiedName"), Variant(QualifiedName{0, "Qn"}));
    EXPECT_EQ(toText(Variant(QualifiedName{1, "Qn"})), "1:Qn");
    EXPECT_EQ(parse("hello", "LocalizedText"), Variant(LocalizedText("", "hello")));
    EXPECT_EQ(parse("\"hello\"@en-US", "LocalizedText"), Variant(LocalizedText("en-US", "hello")));
    EXPECT_EQ(parse("{\"Locale\":\"de\",\"Text\":\"hallo\"}", "LocalizedText"),
              Variant(LocalizedText("de", "hallo")));
    EXPECT_EQ(toText(Variant(LocalizedText("en-US", "hello"))), "\"hello\"@en-US");
    EXPECT_EQ(toText(Variant(LocalizedText("", "no locale"))), "no locale");
    // What toText prints parses back.
    LocalizedText odd("en", "say \"hi\"@home");
    EXPECT_EQ(parse(toText(Variant(odd)), "LocalizedText"), Variant(odd));
    expectJsonRoundTrip(Variant(std::vector<QualifiedName>{{0, "A"}, {1, "B"}}));
    expectJsonRoundTrip(
        Variant(std::vector<LocalizedText>{LocalizedText("de", "hallo"), LocalizedText("", "x")}));
}

TEST(ValueText, ExtensionObjectIsDecodedWhenKnown) {
    Range r;
    r.low = -1.5;
    r.high = 99.25;
    Variant v(toExtensionObject(r));
    json j = toJson(v);
    EXPECT_EQ(j["TypeId"], "i=886");
    EXPECT_EQ(j["Type"], "Range");
    EXPECT_EQ(j["Body"]["Low"], -1.5);
    EXPECT_EQ(j["Body"]["High"], 99.25);
    EXPECT_EQ(toText(v), "Range {\"Low\":-1.5,\"High\":99.25}");
    // The raw form is accepted (and printed for unknown types).
    std::string raw = "{\"TypeId\":\"i=886\",\"Body\":\"" +
                      ByteString(std::get<ExtensionObject>(v.storage()).body).toBase64() + "\"}";
    EXPECT_EQ(parse(raw, "ExtensionObject"), v);
    ExtensionObject unknown;
    unknown.typeId = NodeId(2, 5001);
    unknown.encoding = ExtensionObject::Encoding::Binary;
    unknown.body = "\x01\x02";
    json u = toJson(Variant(unknown));
    EXPECT_EQ(u["TypeId"], "ns=2;i=5001");
    EXPECT_EQ(u["Body"], "AQI=");
    expectJsonRoundTrip(Variant(unknown));
    expectJsonRoundTrip(Variant(std::vector<ExtensionObject>{unknown, ExtensionObject{}}));
    // A decoded body cannot be encoded without the type's description (see Structures).
    EXPECT_THROW(parse(j.dump(), "ExtensionObject"), ValueError);
}

TEST(ValueText, DataValue) {
    DataValue dv(Variant(Double{1.25}));
    dv.status = status::UncertainLastUsableValue;
    dv.sourceTimestamp = *parseDateTime("2024-01-02T03:04:05.678Z");
    json j = toJson(Variant(dv));
    EXPECT_EQ(j["Value"]["Type"], "Double");
    EXPECT_EQ(j["Value"]["Body"], 1.25);
    EXPECT_EQ(j["Status"], "UncertainLastUsableValue");
    EXPECT_EQ(j["SourceTimestamp"], "2024-01-02T03:04:05.678Z");
    expectJsonRoundTrip(Variant(dv));
    DataValue s(Variant(String("dv")));
    s.status = status::BadNoData;
    s.serverPicoseconds = 7;
    expectJsonRoundTrip(Variant(std::vector<DataValue>{DataValue(Variant(Int32{7})), s, {}}));
    EXPECT_EQ(parse("{}", "DataValue"), Variant(DataValue{}));
    EXPECT_THROW(parse("{\"Valeu\":1}", "DataValue"), ValueError);
}

TEST(ValueText, VariantInference) {
    EXPECT_EQ(parse("2.5", "Variant"), Variant(Double{2.5}));
    EXPECT_EQ(parse("7", "BaseDataType"), Variant(Int32{7}));
    EXPECT_EQ(parse("5000000000", "Variant"), Variant(Int64{5000000000LL}));
    EXPECT_EQ(parse("true", "Variant"), Variant(true));
    EXPECT_EQ(parse("hello world", "Variant"), Variant(String("hello world")));
    EXPECT_EQ(parse("\"42\"", "Variant"), Variant(String("42")));
    EXPECT_EQ(parse("{\"Type\":\"Int16\",\"Body\":5}", "Variant"), Variant(Int16{5}));
    EXPECT_EQ(parse("{\"Type\":\"Byte\",\"Body\":[1,2]}", "Variant"),
              Variant(std::vector<Byte>{1, 2}));
    Variant mixed = parse("[1,\"two\",true]", "Variant[]");
    std::vector<Variant> expected{Variant(Int32{1}), Variant(String("two")), Variant(true)};
    EXPECT_EQ(mixed, Variant(expected));
    EXPECT_EQ(toJson(mixed).dump(),
              "[{\"Type\":\"Int32\",\"Body\":1},{\"Type\":\"String\",\"Body\":\"two\"},"
              "{\"Type\":\"Boolean\",\"Body\":true}]");
    expectJsonRoundTrip(mixed);
    Variant matrix(std::vector<Int32>{1, 2, 3, 4});
    matrix.setArrayDimensions({2, 2});
    expectJsonRoundTrip(Variant(std::vector<Variant>{matrix, Variant()}));
}

TEST(ValueText, DiagnosticInfo) {
    DiagnosticInfo d;
    d.symbolicId = 3;
    d.localizedText = 5;
    d.additionalInfo = "info";
    d.innerStatusCode = status::BadTimeout;
    DiagnosticInfo inner;
    inner.locale = 1;
    d.innerDiagnosticInfo = std::make_shared<const DiagnosticInfo>(inner);
    json j = toJson(Variant(d));
    EXPECT_EQ(j["SymbolicId"], 3);
    EXPECT_EQ(j["InnerStatusCode"], "BadTimeout");
    EXPECT_EQ(j["InnerDiagnosticInfo"]["Locale"], 1);
    expectJsonRoundTrip(Variant(d));
    expectJsonRoundTrip(Variant(std::vector<DiagnosticInfo>{DiagnosticInfo{}, d}));
    EXPECT_EQ(parse("{\"AdditionalInfo\":\"x\"}", "DiagnosticInfo"), Variant([] {
                  DiagnosticInfo x;
                  x.additionalInfo = "x";
                  return x;
              }()));
}

TEST(ValueText, ErrorMessagesNameTypeAndText) {
    try {
        parse("300", "Byte");
        FAIL() << "no exception";
    } catch (const ValueError& e) {
        EXPECT_NE(std::string(e.what()).find("\"300\""), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("Byte"), std::string::npos) << e.what();
    }
}

}  // namespace
}  // namespace pnp::cli

// ---- structures given as JSON ------------------------------------------------------------
namespace pnp::cli {
namespace {

using json = Json;

StructureField field(std::string name, NodeId dataType, Int32 valueRank = -1,
                     bool optional = false) {
    StructureField f;
    f.name = std::move(name);
    f.dataType = std::move(dataType);
    f.valueRank = valueRank;
    f.isOptional = optional;
    return f;
}

// A hand-written catalog with the definitions a server would return.
class FakeCatalog : public TypeCatalog {
  public:
    int describeCalls = 0;

    DataTypeDescription describe(const NodeId& t) override {
        ++describeCalls;
        DataTypeDescription d;
        auto structure = [&](UInt32 encoding, StructureType type,
                             std::vector<StructureField> fields, UInt16 ns = 0) {
            StructureDefinition s;
            s.defaultEncodingId = NodeId(ns, encoding);
            s.baseDataType = NodeId(0, 22);
            s.structureType = type;
            s.fields = std::move(fields);
            d.builtin = BuiltinType::ExtensionObject;
            d.structure = std::move(s);
        };
        if (t.namespaceIndex() == 1) {
            if (t.numeric() == 5000)  // a union
                structure(5001, StructureType::Union,
                          {field("Number", NodeId(0, 6)), field("Text", NodeId(0, 12))}, 1);
            if (t.numeric() == 6000)  // optional fields
                structure(6001, StructureType::StructureWithOptionalFields,
                          {field("Id", NodeId(0, 7)), field("Note", NodeId(0, 12), -1, true),
                           field("Values", NodeId(0, 11), 1, true)},
                          1);
            return d;
        }
        switch (t.numeric()) {
            case 884:  // Range
                structure(886, StructureType::Structure,
                          {field("Low", NodeId(0, 11)), field("High", NodeId(0, 11))});
                break;
            case 338:  // BuildInfo
                structure(
                    340, StructureType::Structure,
                    {field("ProductUri", NodeId(0, 12)), field("ManufacturerName", NodeId(0, 12)),
                     field("ProductName", NodeId(0, 12)), field("SoftwareVersion", NodeId(0, 12)),
                     field("BuildNumber", NodeId(0, 12)), field("BuildDate", NodeId(0, 294))});
                break;
            case 862:  // ServerStatusDataType
                structure(864, StructureType::Structure,
                          {field("StartTime", NodeId(0, 294)), field("CurrentTime", NodeId(0, 294)),
                           field("State", NodeId(0, 852)), field("BuildInfo", NodeId(0, 338)),
                           field("SecondsTillShutdown", NodeId(0, 7)),
                           field("ShutdownReason", NodeId(0, 21))});
                break;
            case 852: {  // ServerState
                d.builtin = BuiltinType::Int32;
                EnumDefinition e;
                for (auto [v, n] :
                     {std::pair<Int64, const char*>{0, "Running"}, {1, "Failed"}, {7, "Unknown"}}) {
                    EnumField f;
                    f.value = v;
                    f.name = n;
                    e.fields.push_back(f);
                }
                d.enumeration = e;
                break;
            }
            case 294:
                d.builtin = BuiltinType::DateTime;
                break;  // UtcTime
            default:
                d.builtin = static_cast<BuiltinType>(t.numeric());
        }
        return d;
    }
    NodeId dataTypeOfEncoding(const NodeId& e) override {
        if (e == NodeId(1, 5001)) return NodeId(1, 5000);
        if (e == NodeId(1, 6001)) return NodeId(1, 6000);
        return {};
    }
};

Variant parseWith(TypeCatalog& c, std::string_view text) {
    ParseOptions o;
    o.types = &c;
    return parseValue(text, BuiltinType::ExtensionObject, Shape::Auto, o);
}

TEST(Structures, DecodedJsonIsEncodedBack) {
    FakeCatalog cat;
    Range r;
    r.low = -1.5;
    r.high = 99.25;
    Variant v(toExtensionObject(r));
    EXPECT_EQ(parseWith(cat, toJson(v).dump()), v);
    EXPECT_EQ(parseWith(cat, "{\"Type\":\"Range\",\"Body\":{\"Low\":-1.5,\"High\":99.25}}"), v);
    EXPECT_EQ(parseWith(cat, "{\"TypeId\":\"i=886\",\"Body\":{\"high\":99.25,\"low\":-1.5}}"), v);
    // Missing fields take their default.
    Range low;
    low.low = 1;
    EXPECT_EQ(parseWith(cat, "{\"Type\":\"Range\",\"Body\":{\"Low\":1}}"),
              Variant(toExtensionObject(low)));
    // Arrays of structures.
    Variant arr(std::vector<ExtensionObject>{toExtensionObject(r), toExtensionObject(low)});
    EXPECT_EQ(parseWith(cat, toJson(arr).dump()), arr);
}

TEST(Structures, NestedStructuresAndEnumerationNames) {
    FakeCatalog cat;
    ServerStatusDataType s;
    s.startTime = *parseDateTime("2024-01-02T03:04:05.678Z");
    s.currentTime = DateTime::now();
    s.state = ServerState::Unknown;
    s.buildInfo.productUri = "urn:pnp";
    s.buildInfo.productName = "pnp";
    s.buildInfo.buildDate = s.startTime;
    s.secondsTillShutdown = 7;
    s.shutdownReason = LocalizedText("en", "maintenance");
    Variant v(toExtensionObject(s));
    json j = toJson(v);
    EXPECT_EQ(j["Body"]["State"], "Unknown") << j.dump();  // enumerations print by name
    EXPECT_EQ(parseWith(cat, j.dump()), v) << j.dump();
    // By number too.
    j["Body"]["State"] = 7;
    EXPECT_EQ(parseWith(cat, j.dump()), v);
}

TEST(Structures, UnionsAndOptionalFields) {
    FakeCatalog cat;
    auto body = [&](std::string_view text) {
        Variant v = parseWith(cat, text);
        return std::get<ExtensionObject>(v.storage()).body;
    };
    EXPECT_EQ(body("{\"TypeId\":\"ns=1;i=5001\",\"Body\":{\"Text\":\"x\"}}"),
              std::string("\x02\0\0\0\x01\0\0\0x", 9));
    EXPECT_EQ(body("{\"TypeId\":\"ns=1;i=5001\",\"Body\":{}}"), std::string("\0\0\0\0", 4));
    EXPECT_THROW(body("{\"TypeId\":\"ns=1;i=5001\",\"Body\":{\"Text\":\"x\",\"Number\":1}}"),
                 ValueError);
    // Optional fields: mask bit 0 = Note, bit 1 = Values.
    EXPECT_EQ(body("{\"TypeId\":\"ns=1;i=6001\",\"Body\":{\"Id\":5}}"),
              std::string("\0\0\0\0\x05\0\0\0", 8));
    EXPECT_EQ(body("{\"TypeId\":\"ns=1;i=6001\",\"Body\":{\"Id\":5,\"Values\":[]}}"),
              std::string("\x02\0\0\0\x05\0\0\0\0\0\0\0", 12));
}

TEST(Structures, Errors) {
    FakeCatalog cat;
    // Without a catalog a decoded body cannot be encoded.
    EXPECT_THROW(parseValue("{\"Type\":\"Range\",\"Body\":{\"Low\":1}}",
                            BuiltinType::ExtensionObject, Shape::Scalar),
                 ValueError);
    EXPECT_THROW(parseWith(cat, "{\"Type\":\"Range\",\"Body\":{\"Lo\":1}}"), ValueError);
    EXPECT_THROW(parseWith(cat, "{\"Type\":\"Range\",\"Body\":{\"Low\":\"x\"}}"), ValueError);
    EXPECT_THROW(parseWith(cat, "{\"Type\":\"NoSuchType\",\"Body\":{}}"), ValueError);
    EXPECT_THROW(parseWith(cat, "{\"TypeId\":\"ns=1;i=999\",\"Body\":{}}"), ValueError);
    EXPECT_THROW(parseWith(cat, "{\"TypeId\":\"i=864\",\"Body\":{\"State\":\"Dancing\"}}"),
                 ValueError);
}

}  // namespace
}  // namespace pnp::cli
