// Read and Write (OPC 10000-4 §5.10), attributes of every node class, IndexRange, type checks.
#include <thread>

#include "test_util.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types.hpp"

namespace pnp::ua::server::test {
namespace {

using Read = AddressSpaceFixture;

template <class T>
T scalarOf(const DataValue& dv) {
    EXPECT_TRUE(dv.statusOrGood().isGood()) << dv.statusOrGood().toString();
    EXPECT_TRUE(dv.value.has_value());
    if (!dv.value) return T{};
    const T* p = dv.value->scalar<T>();
    EXPECT_NE(p, nullptr) << dv.value->toString();
    return p ? *p : T{};
}

StatusCode statusOf(const DataValue& dv) { return dv.statusOrGood(); }

// Every attribute id (1..27) read on one node: the ones listed are Good, the rest
// Bad_AttributeIdInvalid.
void expectAttributeSet(const AddressSpace& space, const NodeId& id,
                        std::vector<AttributeId> valid) {
    for (UInt32 a = 0; a <= 28; ++a) {
        DataValue dv = space.readAttribute(id, static_cast<AttributeId>(a));
        bool expected =
            std::find(valid.begin(), valid.end(), static_cast<AttributeId>(a)) != valid.end();
        if (expected)
            EXPECT_TRUE(statusOf(dv).isGood())
                << id.toString() << " attribute " << a << ": " << statusOf(dv).toString();
        else
            EXPECT_EQ(statusOf(dv), status::BadAttributeIdInvalid)
                << id.toString() << " attribute " << a;
    }
}

const std::vector<AttributeId> kBase = {AttributeId::NodeId,       AttributeId::NodeClass,
                                        AttributeId::BrowseName,   AttributeId::DisplayName,
                                        AttributeId::Description,  AttributeId::WriteMask,
                                        AttributeId::UserWriteMask};

std::vector<AttributeId> with(std::vector<AttributeId> extra) {
    auto v = kBase;
    v.insert(v.end(), extra.begin(), extra.end());
    return v;
}

TEST_F(Read, VariableAttributes) {
    const NodeId state = ns0(ns0::Server_ServerStatus_State);
    expectAttributeSet(space, state,
                       with({AttributeId::Value, AttributeId::DataType, AttributeId::ValueRank,
                             AttributeId::ArrayDimensions, AttributeId::AccessLevel,
                             AttributeId::UserAccessLevel, AttributeId::MinimumSamplingInterval,
                             AttributeId::Historizing, AttributeId::AccessLevelEx}));
    EXPECT_EQ(scalarOf<NodeId>(space.readAttribute(state, AttributeId::NodeId)), state);
    EXPECT_EQ(scalarOf<Int32>(space.readAttribute(state, AttributeId::NodeClass)),
              static_cast<Int32>(NodeClass::Variable));
    EXPECT_EQ(scalarOf<QualifiedName>(space.readAttribute(state, AttributeId::BrowseName)),
              (QualifiedName{0, "State"}));
    EXPECT_EQ(scalarOf<LocalizedText>(space.readAttribute(state, AttributeId::DisplayName)).text,
              "State");
    EXPECT_EQ(scalarOf<NodeId>(space.readAttribute(state, AttributeId::DataType)),
              ns0(ns0::ServerState));
    EXPECT_EQ(scalarOf<Int32>(space.readAttribute(state, AttributeId::ValueRank)), -1);
    EXPECT_EQ(scalarOf<Byte>(space.readAttribute(state, AttributeId::AccessLevel)),
              access_level::CurrentRead);
    EXPECT_EQ(scalarOf<Byte>(space.readAttribute(state, AttributeId::UserAccessLevel)),
              access_level::CurrentRead);
    EXPECT_EQ(scalarOf<UInt32>(space.readAttribute(state, AttributeId::AccessLevelEx)), 1u);
    EXPECT_EQ(scalarOf<Double>(space.readAttribute(state, AttributeId::MinimumSamplingInterval)),
              0.0);
    EXPECT_FALSE(scalarOf<Boolean>(space.readAttribute(state, AttributeId::Historizing)));
    EXPECT_EQ(scalarOf<UInt32>(space.readAttribute(state, AttributeId::WriteMask)), 0u);
    auto dims =
        space.readAttribute(ns0(ns0::ServerState_EnumStrings), AttributeId::ArrayDimensions);
    ASSERT_NE(dims.value->array<UInt32>(), nullptr);
    EXPECT_EQ(*dims.value->array<UInt32>(), std::vector<UInt32>{8});
    // Variables with values from the NodeSet.
    auto enumStrings = space.readAttribute(ns0(ns0::ServerState_EnumStrings), AttributeId::Value);
    ASSERT_TRUE(statusOf(enumStrings).isGood());
    const auto* texts = enumStrings.value->array<LocalizedText>();
    ASSERT_NE(texts, nullptr);
    ASSERT_EQ(texts->size(), 8u);
    EXPECT_EQ((*texts)[0].text, "Running");
    EXPECT_EQ((*texts)[7].text, "Unknown");
}

TEST_F(Read, NamespaceZeroStructureValues) {
    // InputArguments of Server.GetMonitoredItems: one Argument "SubscriptionId" (UInt32).
    auto args =
        space.readAttribute(ns0(ns0::Server_GetMonitoredItems_InputArguments), AttributeId::Value);
    ASSERT_TRUE(statusOf(args).isGood());
    const auto* objs = args.value->array<ExtensionObject>();
    ASSERT_NE(objs, nullptr);
    ASSERT_EQ(objs->size(), 1u);
    auto a = fromExtensionObject<Argument>((*objs)[0]);
    ASSERT_TRUE(a.has_value());
    EXPECT_EQ(a->name, "SubscriptionId");
    EXPECT_EQ(a->dataType, ns0(ns0::UInt32));
    EXPECT_EQ(a->valueRank, -1);
    // EnumValues: EnumValueType.
    auto ev = space.readAttribute(ns0(ns0::NamingRuleType_EnumValues), AttributeId::Value);
    const auto* evs = ev.value->array<ExtensionObject>();
    ASSERT_NE(evs, nullptr);
    ASSERT_EQ(evs->size(), 3u);
    auto e0 = fromExtensionObject<EnumValueType>((*evs)[0]);
    ASSERT_TRUE(e0.has_value());
    EXPECT_EQ(e0->value, 1);
    EXPECT_EQ(e0->displayName.text, "Mandatory");
    // EUInformation.
    auto eu = space.readAttribute(ns0(ns0::IIeeeBaseEthernetPortType_Speed_EngineeringUnits),
                                  AttributeId::Value);
    const auto* euo = eu.value->scalar<ExtensionObject>();
    ASSERT_NE(euo, nullptr);
    auto info = fromExtensionObject<EUInformation>(*euo);
    ASSERT_TRUE(info.has_value());
    EXPECT_EQ(info->namespaceUri, "http://www.opcfoundation.org/UA/units/un/cefact");
    EXPECT_EQ(info->unitId, 4534832);
    EXPECT_EQ(info->displayName.text, "Mbit/s");
    EXPECT_EQ(info->displayName.locale, "en");
}

// Every Value and DataTypeDefinition of namespace 0 decodes, and every ExtensionObject in
// them re-encodes byte for byte with the generated codecs (cross-checks the nodeset compiler's
// encoder against the C++ codecs).
TEST_F(Read, EveryNamespaceZeroValueDecodes) {
    std::size_t values = 0, objects = 0, definitions = 0;
    auto checkObject = [&](const ExtensionObject& x) {
        ++objects;
        ASSERT_EQ(x.encoding, ExtensionObject::Encoding::Binary);
        const auto* codec = findCodecByEncodingId(x.typeId.numeric());
        ASSERT_NE(codec, nullptr) << x.typeId.toString();
        Buffer out;
        BinaryEncoder e(out);
        BinaryDecoder d(reinterpret_cast<const Byte*>(x.body.data()), x.body.size());
        codec->reencode(d, e);
        EXPECT_EQ(d.remaining(), 0u) << codec->name;
        EXPECT_EQ(std::string(out.begin(), out.end()), x.body) << codec->name;
    };
    for (std::uint32_t i = 0; i < 40000; ++i) {
        auto cls = space.nodeClass(ns0(i));
        if (!cls) continue;
        if (*cls == NodeClass::Variable || *cls == NodeClass::VariableType) {
            if (i == ns0::Server_NamespaceArray) continue;
            auto dv = space.readAttribute(ns0(i), AttributeId::Value);
            ASSERT_TRUE(statusOf(dv).isGood()) << i;
            if (!dv.value || dv.value->isEmpty()) continue;
            ++values;
            if (const auto* x = dv.value->scalar<ExtensionObject>()) checkObject(*x);
            if (const auto* xs = dv.value->array<ExtensionObject>())
                for (const auto& x : *xs) checkObject(x);
            // The value fits the variable's own DataType / ValueRank.
            auto dt = scalarOf<NodeId>(space.readAttribute(ns0(i), AttributeId::DataType));
            auto rank = scalarOf<Int32>(space.readAttribute(ns0(i), AttributeId::ValueRank));
            EXPECT_TRUE(space.checkValue(*dv.value, dt, rank).isGood())
                << i << " " << dv.value->toString().substr(0, 80);
        } else if (*cls == NodeClass::DataType) {
            auto dv = space.readAttribute(ns0(i), AttributeId::DataTypeDefinition);
            if (statusOf(dv) == status::BadAttributeIdInvalid) continue;
            ++definitions;
            ASSERT_TRUE(dv.value && dv.value->scalar<ExtensionObject>()) << i;
            checkObject(*dv.value->scalar<ExtensionObject>());
        }
    }
    std::printf("[ns0] %zu values, %zu ExtensionObjects, %zu DataTypeDefinitions checked\n", values,
                objects, definitions);
    EXPECT_GT(values, 1200u);
    EXPECT_GT(objects, 1100u);
    EXPECT_GT(definitions, 240u);
}

TEST_F(Read, ObjectAttributes) {
    expectAttributeSet(space, ns0(ns0::Server), with({AttributeId::EventNotifier}));
    EXPECT_EQ(scalarOf<Byte>(space.readAttribute(ns0(ns0::Server), AttributeId::EventNotifier)), 1);
    EXPECT_EQ(scalarOf<Int32>(space.readAttribute(ns0(ns0::Server), AttributeId::NodeClass)), 1);
}

TEST_F(Read, MethodAttributes) {
    const NodeId m = ns0(ns0::Server_GetMonitoredItems);
    expectAttributeSet(space, m, with({AttributeId::Executable, AttributeId::UserExecutable}));
    EXPECT_TRUE(scalarOf<Boolean>(space.readAttribute(m, AttributeId::Executable)));
    EXPECT_TRUE(scalarOf<Boolean>(space.readAttribute(m, AttributeId::UserExecutable)));
}

TEST_F(Read, ObjectTypeAttributes) {
    expectAttributeSet(space, ns0(ns0::ServerType), with({AttributeId::IsAbstract}));
    EXPECT_FALSE(
        scalarOf<Boolean>(space.readAttribute(ns0(ns0::ServerType), AttributeId::IsAbstract)));
    EXPECT_TRUE(
        scalarOf<Boolean>(space.readAttribute(ns0(ns0::BaseEventType), AttributeId::IsAbstract)));
}

TEST_F(Read, VariableTypeAttributes) {
    const NodeId vt = ns0(ns0::BaseDataVariableType);
    expectAttributeSet(space, vt,
                       with({AttributeId::IsAbstract, AttributeId::Value, AttributeId::DataType,
                             AttributeId::ValueRank, AttributeId::ArrayDimensions}));
    EXPECT_EQ(scalarOf<NodeId>(space.readAttribute(vt, AttributeId::DataType)),
              ns0(ns0::BaseDataType));
    EXPECT_EQ(scalarOf<Int32>(space.readAttribute(vt, AttributeId::ValueRank)), -2);
    auto v = space.readAttribute(vt, AttributeId::Value);
    EXPECT_TRUE(statusOf(v).isGood());
    EXPECT_TRUE(v.value->isEmpty());
}

TEST_F(Read, ReferenceTypeAttributes) {
    const NodeId org = ns0(ns0::Organizes);
    expectAttributeSet(
        space, org,
        with({AttributeId::IsAbstract, AttributeId::Symmetric, AttributeId::InverseName}));
    EXPECT_EQ(scalarOf<LocalizedText>(space.readAttribute(org, AttributeId::InverseName)).text,
              "OrganizedBy");
    EXPECT_FALSE(scalarOf<Boolean>(space.readAttribute(org, AttributeId::Symmetric)));
    EXPECT_TRUE(
        scalarOf<Boolean>(space.readAttribute(ns0(ns0::References), AttributeId::IsAbstract)));
    EXPECT_TRUE(
        scalarOf<Boolean>(space.readAttribute(ns0(ns0::References), AttributeId::Symmetric)));
}

TEST_F(Read, DataTypeAttributesAndDefinitions) {
    const NodeId arg = ns0(ns0::Argument);
    expectAttributeSet(space, arg,
                       with({AttributeId::IsAbstract, AttributeId::DataTypeDefinition}));
    auto def = space.readAttribute(arg, AttributeId::DataTypeDefinition);
    auto sd = fromExtensionObject<StructureDefinition>(scalarOf<ExtensionObject>(def));
    ASSERT_TRUE(sd.has_value());
    EXPECT_EQ(sd->defaultEncodingId, ns0(ns0::Argument_Encoding_DefaultBinary));
    EXPECT_EQ(sd->baseDataType, ns0(ns0::Structure));
    EXPECT_EQ(sd->structureType, StructureType::Structure);
    ASSERT_EQ(sd->fields.size(), 5u);
    EXPECT_EQ(sd->fields[0].name, "Name");
    EXPECT_EQ(sd->fields[0].dataType, ns0(ns0::String));
    EXPECT_EQ(sd->fields[3].name, "ArrayDimensions");
    EXPECT_EQ(sd->fields[3].valueRank, 1);
    // Subtype: the definition starts with the inherited fields.
    auto ef = fromExtensionObject<StructureDefinition>(scalarOf<ExtensionObject>(
        space.readAttribute(ns0(ns0::EnumField), AttributeId::DataTypeDefinition)));
    ASSERT_TRUE(ef.has_value());
    ASSERT_EQ(ef->fields.size(), 4u);
    EXPECT_EQ(ef->fields[0].name, "Value");
    EXPECT_EQ(ef->fields[3].name, "Name");
    EXPECT_EQ(ef->baseDataType, ns0(ns0::EnumValueType));
    // Optional fields.
    auto lr = fromExtensionObject<StructureDefinition>(scalarOf<ExtensionObject>(
        space.readAttribute(ns0(ns0::LogRecord), AttributeId::DataTypeDefinition)));
    ASSERT_TRUE(lr.has_value());
    EXPECT_EQ(lr->structureType, StructureType::StructureWithOptionalFields);
    // Enumeration.
    auto ed = fromExtensionObject<EnumDefinition>(scalarOf<ExtensionObject>(
        space.readAttribute(ns0(ns0::ServerState), AttributeId::DataTypeDefinition)));
    ASSERT_TRUE(ed.has_value());
    ASSERT_EQ(ed->fields.size(), 8u);
    EXPECT_EQ(ed->fields[1].name, "Failed");
    EXPECT_EQ(ed->fields[1].value, 1);
    // Built-in and abstract types have no definition.
    EXPECT_EQ(statusOf(space.readAttribute(ns0(ns0::Int32), AttributeId::DataTypeDefinition)),
              status::BadAttributeIdInvalid);
    EXPECT_TRUE(scalarOf<Boolean>(space.readAttribute(ns0(ns0::Number), AttributeId::IsAbstract)));
}

TEST_F(Read, ViewAttributes) {
    ViewAttributes va;
    va.containsNoLoops = true;
    va.eventNotifier = 1;
    va.description = LocalizedText("en", "A view");
    NodeId view = space.addView(ns0(ns0::ViewsFolder), id("View"), name("View"), va);
    expectAttributeSet(space, view,
                       with({AttributeId::ContainsNoLoops, AttributeId::EventNotifier}));
    EXPECT_TRUE(scalarOf<Boolean>(space.readAttribute(view, AttributeId::ContainsNoLoops)));
    EXPECT_EQ(scalarOf<Byte>(space.readAttribute(view, AttributeId::EventNotifier)), 1);
    EXPECT_EQ(scalarOf<LocalizedText>(space.readAttribute(view, AttributeId::Description)),
              LocalizedText("en", "A view"));
    EXPECT_EQ(scalarOf<Int32>(space.readAttribute(view, AttributeId::NodeClass)), 128);
}

TEST_F(Read, ServiceLevelChecks) {
    ReadRequest req;
    EXPECT_EQ(space.read(req).responseHeader.serviceResult, status::BadNothingToDo);
    req.nodesToRead.push_back(readId(ns0(ns0::Server), AttributeId::BrowseName));
    req.timestampsToReturn = static_cast<TimestampsToReturn>(4);
    EXPECT_EQ(space.read(req).responseHeader.serviceResult, status::BadTimestampsToReturnInvalid);
    req.timestampsToReturn = static_cast<TimestampsToReturn>(-1);
    EXPECT_EQ(space.read(req).responseHeader.serviceResult, status::BadTimestampsToReturnInvalid);
    req.timestampsToReturn = TimestampsToReturn::Neither;
    req.maxAge = -1;
    EXPECT_EQ(space.read(req).responseHeader.serviceResult, status::BadMaxAgeInvalid);
    req.maxAge = 5000;  // accepted: values are always current
    req.nodesToRead.push_back(readId(id("nope"), AttributeId::Value));
    req.nodesToRead.push_back(readId(ns0(ns0::Server), static_cast<AttributeId>(0)));
    req.nodesToRead.push_back(readId(ns0(ns0::Server), static_cast<AttributeId>(99)));
    req.nodesToRead.push_back(readId(ns0(ns0::Server), AttributeId::RolePermissions));
    auto resp = space.read(req);
    ASSERT_TRUE(resp.responseHeader.serviceResult.isGood());
    ASSERT_EQ(resp.results.size(), 5u);
    EXPECT_EQ(scalarOf<QualifiedName>(resp.results[0]).name, "Server");
    EXPECT_EQ(statusOf(resp.results[1]), status::BadNodeIdUnknown);
    EXPECT_EQ(statusOf(resp.results[2]), status::BadAttributeIdInvalid);
    EXPECT_EQ(statusOf(resp.results[3]), status::BadAttributeIdInvalid);
    EXPECT_EQ(statusOf(resp.results[4]), status::BadAttributeIdInvalid);
}

TEST_F(Read, TimestampsToReturn) {
    NodeId v = addVar("T", ns0::Int32, Variant(Int32{7}));
    auto item = readId(v, AttributeId::Value);
    auto neither = space.read(item, TimestampsToReturn::Neither);
    EXPECT_FALSE(neither.sourceTimestamp || neither.serverTimestamp);
    auto source = space.read(item, TimestampsToReturn::Source);
    EXPECT_TRUE(source.sourceTimestamp && !source.serverTimestamp);
    auto server = space.read(item, TimestampsToReturn::Server);
    EXPECT_TRUE(!server.sourceTimestamp && server.serverTimestamp);
    auto both = space.read(item, TimestampsToReturn::Both);
    EXPECT_TRUE(both.sourceTimestamp && both.serverTimestamp);
    EXPECT_LE(both.sourceTimestamp->ticks, both.serverTimestamp->ticks);
    // Non-Value attributes carry no source timestamp.
    auto name = space.read(readId(v, AttributeId::BrowseName), TimestampsToReturn::Both);
    EXPECT_TRUE(!name.sourceTimestamp && name.serverTimestamp);
    EXPECT_EQ(space.read(item, static_cast<TimestampsToReturn>(9)).statusOrGood(),
              status::BadTimestampsToReturnInvalid);
}

TEST_F(Read, AccessLevelAndEncoding) {
    NodeId hidden = addVar("Hidden", ns0::Int32, Variant(Int32{1}), -1, 0);
    EXPECT_EQ(statusOf(space.readAttribute(hidden, AttributeId::Value)), status::BadNotReadable);
    EXPECT_TRUE(statusOf(space.readAttribute(hidden, AttributeId::DataType)).isGood());
    NodeId i32 = addVar("I32", ns0::Int32, Variant(Int32{1}));
    auto enc = [&](const NodeId& n, AttributeId a, QualifiedName e) {
        ReadValueId r = readId(n, a);
        r.dataEncoding = std::move(e);
        return statusOf(space.read(r));
    };
    const QualifiedName binary{0, "Default Binary"};
    EXPECT_EQ(enc(i32, AttributeId::Value, binary), status::BadDataEncodingInvalid);
    EXPECT_EQ(enc(i32, AttributeId::DisplayName, binary), status::BadDataEncodingInvalid);
    EXPECT_EQ(enc(ns0(ns0::Server_ServerStatus), AttributeId::Value, binary), StatusCode{});
    EXPECT_EQ(
        enc(ns0(ns0::Server_ServerStatus), AttributeId::Value, QualifiedName{0, "Default XML"}),
        status::BadDataEncodingUnsupported);
    EXPECT_EQ(enc(ns0(ns0::Server_ServerStatus), AttributeId::Value, QualifiedName{0, "Foo"}),
              status::BadDataEncodingInvalid);
    EXPECT_EQ(
        enc(ns0(ns0::Server_ServerStatus), AttributeId::Value, QualifiedName{2, "Default Binary"}),
        status::BadDataEncodingInvalid);
}

TEST_F(Read, IndexRange) {
    NodeId arr = addVar("Arr", ns0::Int32, Variant(std::vector<Int32>{10, 11, 12, 13, 14}), 1);
    auto rd = [&](const NodeId& n, const char* range) {
        return space.read(readId(n, AttributeId::Value, range));
    };
    auto a1 = rd(arr, "1");
    ASSERT_TRUE(statusOf(a1).isGood());
    EXPECT_EQ(*a1.value->array<Int32>(), (std::vector<Int32>{11}));
    EXPECT_EQ(*rd(arr, "2:4").value->array<Int32>(), (std::vector<Int32>{12, 13, 14}));
    EXPECT_EQ(*rd(arr, "3:9").value->array<Int32>(), (std::vector<Int32>{13, 14}));  // partial
    EXPECT_EQ(statusOf(rd(arr, "5")), status::BadIndexRangeNoData);
    EXPECT_EQ(statusOf(rd(arr, "5:7")), status::BadIndexRangeNoData);
    EXPECT_EQ(statusOf(rd(arr, "1,1")), status::BadIndexRangeNoData);  // not a matrix
    for (const char* bad : {"a", "4:2", "2:2", "-1", "1:", ":3", " 1", "1;2", "1,", "1:2:3"})
        EXPECT_EQ(statusOf(rd(arr, bad)), status::BadIndexRangeInvalid) << bad;
    // Strings and ByteStrings are arrays of bytes.
    NodeId str = addVar("Str", ns0::String, Variant(String("abcdef")));
    EXPECT_EQ(scalarOf<String>(rd(str, "1:3")), "bcd");
    EXPECT_EQ(scalarOf<String>(rd(str, "4:10")), "ef");
    EXPECT_EQ(statusOf(rd(str, "6")), status::BadIndexRangeNoData);
    NodeId bs = addVar("Bs", ns0::ByteString, Variant(ByteString(std::string("\x01\x02\x03", 3))));
    EXPECT_EQ(scalarOf<ByteString>(rd(bs, "2")).view(), std::string("\x03", 1));
    // A scalar of another type has no index.
    NodeId scalar = addVar("Scalar", ns0::Int32, Variant(Int32{5}));
    EXPECT_EQ(statusOf(rd(scalar, "0")), status::BadIndexRangeNoData);
    // Arrays of strings: the second dimension indexes the characters.
    NodeId strs =
        addVar("Strs", ns0::String, Variant(std::vector<String>{"alpha", "beta", "gamma"}), 1);
    EXPECT_EQ(*rd(strs, "0:1,1:2").value->array<String>(), (std::vector<String>{"lp", "et"}));
    EXPECT_EQ(*rd(strs, "1:2").value->array<String>(), (std::vector<String>{"beta", "gamma"}));
    // Matrix 3x4: "1:2,0:1" is a 2x2 block.
    Variant m(std::vector<Int32>{0, 1, 2, 3, 10, 11, 12, 13, 20, 21, 22, 23});
    m.setArrayDimensions({3, 4});
    NodeId mat = addVar("Mat", ns0::Int32, m, 2);
    auto block = rd(mat, "1:2,0:1");
    ASSERT_TRUE(statusOf(block).isGood());
    EXPECT_EQ(*block.value->array<Int32>(), (std::vector<Int32>{10, 11, 20, 21}));
    EXPECT_EQ(block.value->arrayDimensions(), (std::vector<Int32>{2, 2}));
    EXPECT_EQ(*rd(mat, "2,3").value->array<Int32>(), (std::vector<Int32>{23}));
    EXPECT_EQ(*rd(mat, "0,2:9").value->array<Int32>(), (std::vector<Int32>{2, 3}));
    EXPECT_EQ(statusOf(rd(mat, "1")), status::BadIndexRangeNoData);
    EXPECT_EQ(statusOf(rd(mat, "3,0")), status::BadIndexRangeNoData);
    // Non-Value array attributes take ranges too; scalar attributes do not.
    auto dims =
        space.read(readId(ns0(ns0::ServerState_EnumStrings), AttributeId::ArrayDimensions, "0"));
    EXPECT_EQ(*dims.value->array<UInt32>(), std::vector<UInt32>{8});
    EXPECT_EQ(statusOf(space.read(readId(arr, AttributeId::BrowseName, "0"))),
              status::BadIndexRangeNoData);
    // Ranges apply to values served by a callback as well.
    EXPECT_EQ(*space.read(readId(ns0(ns0::Server_NamespaceArray), AttributeId::Value, "2"))
                   .value->array<String>(),
              std::vector<String>{"urn:test"});
}

// ---- Write ------------------------------------------------------------------------------------
using Write = AddressSpaceFixture;

TEST_F(Write, TypeChecks) {
    NodeId i32 = addVar("I32", ns0::Int32, Variant(Int32{1}));
    EXPECT_TRUE(space.write(writeValue(i32, Variant(Int32{42}))).isGood());
    EXPECT_EQ(*space.readValue(i32).value->scalar<Int32>(), 42);
    EXPECT_EQ(space.write(writeValue(i32, Variant(42.0))), status::BadTypeMismatch);
    EXPECT_EQ(space.write(writeValue(i32, Variant(Int64{42}))), status::BadTypeMismatch);
    EXPECT_EQ(space.write(writeValue(i32, Variant(std::vector<Int32>{1, 2}))),
              status::BadTypeMismatch);                           // scalar rank
    EXPECT_EQ(*space.readValue(i32).value->scalar<Int32>(), 42);  // unchanged
    // Subtypes of built-in types take the built-in type.
    NodeId utc = addVar("Utc", ns0::UtcTime, Variant(DateTime::now()));
    EXPECT_TRUE(space.write(writeValue(utc, Variant(DateTime{123}))).isGood());
    EXPECT_EQ(space.write(writeValue(utc, Variant(Int64{123}))), status::BadTypeMismatch);
    NodeId dur = addVar("Duration", ns0::Duration, Variant(1.5));
    EXPECT_TRUE(space.write(writeValue(dur, Variant(2.5))).isGood());
    EXPECT_EQ(space.write(writeValue(dur, Variant(2.5f))), status::BadTypeMismatch);
    // Abstract types take their subtypes.
    NodeId num = addVar("Num", ns0::Number, Variant(Int32{1}));
    EXPECT_TRUE(space.write(writeValue(num, Variant(3.25))).isGood());
    EXPECT_TRUE(space.write(writeValue(num, Variant(UInt16{3}))).isGood());
    EXPECT_EQ(space.write(writeValue(num, Variant(String("3")))), status::BadTypeMismatch);
    NodeId integer = addVar("Integer", ns0::Integer, Variant(Int32{1}));
    EXPECT_TRUE(space.write(writeValue(integer, Variant(Int64{1}))).isGood());
    EXPECT_EQ(space.write(writeValue(integer, Variant(1.0))), status::BadTypeMismatch);
    EXPECT_EQ(space.write(writeValue(integer, Variant(UInt32{1}))), status::BadTypeMismatch);
    // Enumerations are Int32.
    NodeId st = addVar("State", ns0::ServerState, Variant(Int32{0}));
    EXPECT_TRUE(space.write(writeValue(st, Variant(Int32{2}))).isGood());
    EXPECT_EQ(space.write(writeValue(st, Variant(UInt32{2}))), status::BadTypeMismatch);
    // Structures: the ExtensionObject's encoding must belong to the DataType or a subtype.
    NodeId argVar = addVar("Arg", ns0::Argument, Variant(toExtensionObject(Argument{})));
    EXPECT_TRUE(
        space.write(writeValue(argVar, Variant(toExtensionObject(argument("x", ns0::Int32)))))
            .isGood());
    EXPECT_EQ(space.write(writeValue(argVar, Variant(toExtensionObject(EUInformation{})))),
              status::BadTypeMismatch);
    NodeId anyStruct = addVar("AnyStruct", ns0::Structure, Variant(toExtensionObject(Argument{})));
    EXPECT_TRUE(
        space.write(writeValue(anyStruct, Variant(toExtensionObject(EUInformation{})))).isGood());
    EXPECT_EQ(space.write(writeValue(anyStruct, Variant(Int32{1}))), status::BadTypeMismatch);
    // BaseDataType with ValueRank Any takes anything.
    NodeId any = addVar("Any", ns0::BaseDataType, Variant(), -2);
    EXPECT_TRUE(space.write(writeValue(any, Variant(String("x")))).isGood());
    EXPECT_TRUE(space.write(writeValue(any, Variant(std::vector<Double>{1, 2}))).isGood());
    // A null value is accepted (the variable then has no value).
    EXPECT_TRUE(space.write(writeValue(i32, Variant())).isGood());
}

TEST_F(Write, ValueRankAndArrayDimensions) {
    NodeId one = addVar("One", ns0::Double, Variant(std::vector<Double>{1, 2}), 1, 3, {3});
    EXPECT_TRUE(space.write(writeValue(one, Variant(std::vector<Double>{1, 2, 3}))).isGood());
    EXPECT_EQ(space.write(writeValue(one, Variant(std::vector<Double>{1, 2, 3, 4}))),
              status::BadTypeMismatch);  // longer than ArrayDimensions
    EXPECT_EQ(space.write(writeValue(one, Variant(1.0))), status::BadTypeMismatch);
    Variant m(std::vector<Double>{1, 2, 3, 4});
    m.setArrayDimensions({2, 2});
    EXPECT_EQ(space.write(writeValue(one, m)), status::BadTypeMismatch);
    NodeId two = addVar("Two", ns0::Double, m, 2);
    EXPECT_TRUE(space.write(writeValue(two, m)).isGood());
    EXPECT_EQ(space.write(writeValue(two, Variant(std::vector<Double>{1, 2}))),
              status::BadTypeMismatch);
    NodeId scalarOrOne = addVar("SOO", ns0::Double, Variant(1.0), -3);
    EXPECT_TRUE(space.write(writeValue(scalarOrOne, Variant(2.0))).isGood());
    EXPECT_TRUE(space.write(writeValue(scalarOrOne, Variant(std::vector<Double>{1}))).isGood());
    EXPECT_EQ(space.write(writeValue(scalarOrOne, m)), status::BadTypeMismatch);
    NodeId oneOrMore = addVar("OOM", ns0::Double, Variant(std::vector<Double>{}), 0);
    EXPECT_TRUE(space.write(writeValue(oneOrMore, m)).isGood());
    EXPECT_EQ(space.write(writeValue(oneOrMore, Variant(1.0))), status::BadTypeMismatch);
}

TEST_F(Write, IndexRange) {
    NodeId arr = addVar("Arr", ns0::Int32, Variant(std::vector<Int32>{0, 1, 2, 3, 4}), 1);
    EXPECT_TRUE(space.write(writeValue(arr, Variant(std::vector<Int32>{20, 30}), "2:3")).isGood());
    EXPECT_EQ(*space.readValue(arr).value->array<Int32>(), (std::vector<Int32>{0, 1, 20, 30, 4}));
    EXPECT_TRUE(space.write(writeValue(arr, Variant(std::vector<Int32>{9}), "0")).isGood());
    EXPECT_EQ(*space.readValue(arr).value->array<Int32>(), (std::vector<Int32>{9, 1, 20, 30, 4}));
    EXPECT_EQ(space.write(writeValue(arr, Variant(std::vector<Int32>{1, 2, 3}), "0:1")),
              status::BadIndexRangeNoData);  // size mismatch
    EXPECT_EQ(space.write(writeValue(arr, Variant(std::vector<Int32>{1, 2}), "4:5")),
              status::BadIndexRangeNoData);  // out of bounds
    EXPECT_EQ(space.write(writeValue(arr, Variant(std::vector<Int32>{1}), "x")),
              status::BadIndexRangeInvalid);
    EXPECT_EQ(space.write(writeValue(arr, Variant(std::vector<Double>{1}), "0")),
              status::BadTypeMismatch);
    EXPECT_EQ(*space.readValue(arr).value->array<Int32>(), (std::vector<Int32>{9, 1, 20, 30, 4}));
    // Matrix block and string bytes.
    Variant m(std::vector<Int32>{0, 1, 2, 3, 4, 5});
    m.setArrayDimensions({2, 3});
    NodeId mat = addVar("Mat", ns0::Int32, m, 2);
    EXPECT_TRUE(space.write(writeValue(mat, Variant(std::vector<Int32>{7, 8}), "0:1,2")).isGood());
    EXPECT_EQ(*space.readValue(mat).value->array<Int32>(), (std::vector<Int32>{0, 1, 7, 3, 4, 8}));
    NodeId str = addVar("Str", ns0::String, Variant(String("hello")));
    EXPECT_TRUE(space.write(writeValue(str, Variant(String("EL")), "1:2")).isGood());
    EXPECT_EQ(*space.readValue(str).value->scalar<String>(), "hELlo");
}

TEST_F(Write, AccessChecks) {
    NodeId ro = addVar("RO", ns0::Int32, Variant(Int32{1}), -1, access_level::CurrentRead);
    EXPECT_EQ(space.write(writeValue(ro, Variant(Int32{2}))), status::BadNotWritable);
    // Not writable attributes, write mask.
    EXPECT_EQ(space.writeAttribute(ro, AttributeId::DisplayName, Variant(LocalizedText("", "x"))),
              status::BadNotWritable);
    EXPECT_EQ(space.writeAttribute(ro, AttributeId::NodeId, Variant(NodeId(2, 5))),
              status::BadNotWritable);
    EXPECT_EQ(space.writeAttribute(ro, AttributeId::EventNotifier, Variant(Byte{1})),
              status::BadAttributeIdInvalid);
    EXPECT_EQ(space.writeAttribute(ns0(ns0::Server), AttributeId::Value, Variant(Int32{1})),
              status::BadAttributeIdInvalid);
    EXPECT_EQ(space.write(writeValue(id("nope"), Variant(Int32{1}))), status::BadNodeIdUnknown);
    VariableAttributes va;
    va.dataType = ns0(ns0::Int32);
    va.writeMask = write_mask::DisplayName | write_mask::Description;
    va.accessLevel = access_level::CurrentRead | access_level::CurrentWrite;
    NodeId w = space.addVariable(ns0(ns0::ObjectsFolder), id("W"), name("W"), va);
    EXPECT_TRUE(
        space.writeAttribute(w, AttributeId::DisplayName, Variant(LocalizedText("de", "Wert")))
            .isGood());
    EXPECT_EQ(*space.readAttribute(w, AttributeId::DisplayName).value->scalar<LocalizedText>(),
              LocalizedText("de", "Wert"));
    EXPECT_EQ(space.writeAttribute(w, AttributeId::Description, Variant(String("no"))),
              status::BadTypeMismatch);
    EXPECT_EQ(space.writeAttribute(w, AttributeId::BrowseName, Variant(QualifiedName{2, "x"})),
              status::BadNotWritable);
    // Status and timestamps need StatusWrite / TimestampWrite.
    WriteValue withStatus = writeValue(w, Variant(Int32{5}));
    withStatus.value.status = status::BadOutOfService;
    EXPECT_EQ(space.write(withStatus), status::BadWriteNotSupported);
    WriteValue withTs = writeValue(w, Variant(Int32{5}));
    withTs.value.sourceTimestamp = DateTime{1000};
    EXPECT_EQ(space.write(withTs), status::BadWriteNotSupported);
    WriteValue withServerTs = writeValue(w, Variant(Int32{5}));
    withServerTs.value.serverTimestamp = DateTime{1000};
    EXPECT_EQ(space.write(withServerTs), status::BadWriteNotSupported);
    NodeId full = addVar("Full", ns0::Int32, Variant(Int32{0}), -1,
                         access_level::CurrentRead | access_level::CurrentWrite |
                             access_level::StatusWrite | access_level::TimestampWrite);
    withStatus.nodeId = full;
    withStatus.value.sourceTimestamp = DateTime{1000};
    EXPECT_TRUE(space.write(withStatus).isGood());
    auto back = space.readValue(full);
    EXPECT_EQ(back.statusOrGood(), status::BadOutOfService);
    EXPECT_EQ(back.sourceTimestamp->ticks, 1000);
    // The Write service reports per item.
    WriteRequest req;
    EXPECT_EQ(space.write(req).responseHeader.serviceResult, status::BadNothingToDo);
    req.nodesToWrite = {writeValue(full, Variant(Int32{1})), writeValue(ro, Variant(Int32{1}))};
    auto resp = space.write(req);
    ASSERT_EQ(resp.results.size(), 2u);
    EXPECT_TRUE(resp.results[0].isGood());
    EXPECT_EQ(resp.results[1], status::BadNotWritable);
    // Namespace-0 variables are read-only.
    EXPECT_EQ(space.write(writeValue(ns0(ns0::Server_ServerStatus_State), Variant(Int32{0}))),
              status::BadNotWritable);
}

TEST_F(Write, ValueCallbacks) {
    NodeId v = addVar("Cb", ns0::Int32, Variant(Int32{0}));
    std::vector<Int32> seen;
    space.setValueCallback(v, ValueCallbacks{{}, [&](const NodeId& n, const DataValue& dv) {
                                                 EXPECT_EQ(n, v);
                                                 Int32 x = *dv.value->scalar<Int32>();
                                                 seen.push_back(x);
                                                 return x < 0 ? status::BadOutOfRange
                                                              : StatusCode{};
                                             }});
    EXPECT_TRUE(space.write(writeValue(v, Variant(Int32{5}))).isGood());
    EXPECT_EQ(space.write(writeValue(v, Variant(Int32{-1}))), status::BadOutOfRange);
    EXPECT_EQ(space.write(writeValue(v, Variant(1.0))),
              status::BadTypeMismatch);  // before callback
    EXPECT_EQ(seen, (std::vector<Int32>{5, -1}));
    EXPECT_EQ(*space.readValue(v).value->scalar<Int32>(), 5);  // stored (no read callback)
    // Read callback: live value, the stored one is ignored.
    int reads = 0;
    Int32 live = 100;
    space.setValueCallback(v, ValueCallbacks{[&](const NodeId&) {
                                                 ++reads;
                                                 // Re-entrance: callbacks run without the lock.
                                                 EXPECT_TRUE(space.contains(v));
                                                 return DataValue(Variant(live));
                                             },
                                             [&](const NodeId&, const DataValue& dv) {
                                                 live = *dv.value->scalar<Int32>();
                                                 return StatusCode{};
                                             }});
    EXPECT_EQ(*space.readValue(v).value->scalar<Int32>(), 100);
    EXPECT_TRUE(space.write(writeValue(v, Variant(Int32{7}))).isGood());
    EXPECT_EQ(live, 7);
    EXPECT_EQ(*space.readValue(v).value->scalar<Int32>(), 7);
    EXPECT_EQ(reads, 2);
    // Read-only callback: not writable.
    space.setValueCallback(
        v, ValueCallbacks{[](const NodeId&) { return DataValue(Variant(Int32{1})); }, {}});
    EXPECT_EQ(space.write(writeValue(v, Variant(Int32{2}))), status::BadNotWritable);
    // IndexRange write through callbacks merges into the current value.
    std::vector<Int32> backing{1, 2, 3};
    NodeId arr = addVar("CbArr", ns0::Int32, Variant(std::vector<Int32>{}), 1);
    space.setValueCallback(
        arr, ValueCallbacks{[&](const NodeId&) { return DataValue(Variant(backing)); },
                            [&](const NodeId&, const DataValue& dv) {
                                backing = *dv.value->array<Int32>();
                                return StatusCode{};
                            }});
    EXPECT_TRUE(space.write(writeValue(arr, Variant(std::vector<Int32>{9}), "1")).isGood());
    EXPECT_EQ(backing, (std::vector<Int32>{1, 9, 3}));
    // Removing the callbacks returns to the stored value.
    space.setValueCallback(arr, {});
    EXPECT_TRUE(space.readValue(arr).value->array<Int32>()->empty());
}

TEST_F(Write, SetValueFromApplicationThread) {
    NodeId v = addVar("Live", ns0::Double, Variant(0.0), -1, access_level::CurrentRead);
    std::thread app([&] {
        for (int i = 1; i <= 100; ++i)
            EXPECT_TRUE(space.setValue(v, DataValue(Variant(i * 1.0))).isGood());
    });
    app.join();
    EXPECT_EQ(*space.readValue(v).value->scalar<Double>(), 100.0);
    EXPECT_EQ(space.setValue(v, DataValue(Variant(Int32{1}))), status::BadTypeMismatch);
    EXPECT_EQ(space.setValue(id("nope"), DataValue(Variant(1.0))), status::BadNodeIdUnknown);
    EXPECT_EQ(space.setValue(ns0(ns0::Server), DataValue(Variant(1.0))),
              status::BadNodeClassInvalid);
    // Namespace-0 variables are set by the application the same way.
    EXPECT_TRUE(
        space.setValue(ns0(ns0::Server_ServerStatus_State), DataValue(Variant(Int32{0}))).isGood());
    EXPECT_EQ(*space.readValue(ns0(ns0::Server_ServerStatus_State)).value->scalar<Int32>(), 0);
    EXPECT_EQ(space.setValue(ns0(ns0::Server_ServerStatus_CurrentTime), DataValue(Variant(1.0))),
              status::BadTypeMismatch);
}

TEST_F(Write, VariableGroupWritesAndReadsAsOneChangeAndFollowsStructuralChanges) {
    NodeId a = addVar("GroupA", ns0::Int32, Variant(Int32{0}));
    NodeId b = addVar("GroupB", ns0::String, Variant(String("x")));
    NodeId m =
        space.addMethod(ns0(ns0::ObjectsFolder), id("GroupM"), name("GroupM"), {}, {},
                        makeMethodHandler([](const MethodCallContext&, const std::vector<Variant>&,
                                             std::vector<Variant>&) { return StatusCode{}; }));
    AddressSpace::VariableGroup group({a, b, id("GroupMissing"), m});
    EXPECT_TRUE(space
                    .setValues(group,
                               {{0, DataValue(Variant(Int32{7}))},
                                {1, DataValue(Variant(String("seven")))}},
                               {{3, false}})
                    .isGood());
    auto values = space.readValues(group);
    ASSERT_EQ(values.size(), 4u);
    EXPECT_EQ(*values[0].value->scalar<Int32>(), 7);
    EXPECT_EQ(*values[1].value->scalar<String>(), "seven");
    EXPECT_EQ(values[2].statusOrGood(), status::BadNodeIdUnknown);
    EXPECT_FALSE(*space.readAttribute(m, AttributeId::Executable).value->scalar<Boolean>());
    // Checked as setValue: the bad one is skipped, the others written, the first bad returned.
    EXPECT_EQ(space.setValues(group, {{0, DataValue(Variant(String("no")))},
                                      {1, DataValue(Variant(String("eight")))},
                                      {2, DataValue(Variant(Int32{1}))},
                                      {9, DataValue(Variant(Int32{1}))}}),
              status::BadTypeMismatch);
    values = space.readValues(group);
    EXPECT_EQ(*values[0].value->scalar<Int32>(), 7);
    EXPECT_EQ(*values[1].value->scalar<String>(), "eight");
    // A node deleted and another added in its place (a structural change): the group looks
    // its nodes up again instead of writing through a stale index.
    space.deleteNode(a);
    EXPECT_EQ(space.setValues(group, {{0, DataValue(Variant(Int32{8}))}}),
              status::BadNodeIdUnknown);
    addVar("GroupA", ns0::Int32, Variant(Int32{0}));
    EXPECT_TRUE(space.setValues(group, {{0, DataValue(Variant(Int32{9}))}}).isGood());
    EXPECT_EQ(*space.readValue(a).value->scalar<Int32>(), 9);
    EXPECT_EQ(*space.readValues(group)[0].value->scalar<Int32>(), 9);
    // Executable back on through the group.
    EXPECT_TRUE(space.setValues(group, {}, {{3, true}}).isGood());
    EXPECT_TRUE(*space.readAttribute(m, AttributeId::Executable).value->scalar<Boolean>());
}

}  // namespace
}  // namespace pnp::ua::server::test
