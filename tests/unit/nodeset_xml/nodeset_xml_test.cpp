// NodeSet2 XML loader: a small test NodeSet (custom structures, enumeration, values),
// the dynamic structure codec, and errors on bad input.
#include "ua/server/nodeset_xml.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "ua/server/structure_codec.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {
namespace {

namespace fs = std::filesystem;

struct Loaded {
    AddressSpace space;
    UInt16 ns = 0;
    std::vector<NodeSetLoadReport> reports;
    Loaded() {
        reports = loadNodeSetXml(space, PNP_TEST_NODESET);
        ns = *space.namespaceIndex("urn:pnp:test:nodeset");
    }
    StructureLayoutLookup lookup() const {
        return [this](const NodeId& id) { return space.structureLayout(id); };
    }
};

TEST(NodeSetXml, LoadsTheTestNodeSetIntoItsOwnNamespace) {
    Loaded t;
    ASSERT_EQ(t.reports.size(), 1u);  // ns0 is already there (compiled in)
    EXPECT_EQ(t.reports[0].modelUri, "urn:pnp:test:nodeset");
    EXPECT_EQ(t.reports[0].nodes, 23u);
    EXPECT_TRUE(t.reports[0].warnings.empty());
    // The file's ns=1 is the server's next free index (1 is the server's own namespace).
    EXPECT_EQ(t.ns, 2);
    EXPECT_TRUE(isModelLoaded(t.space, "urn:pnp:test:nodeset"));
    EXPECT_TRUE(t.space.contains(NodeId(t.ns, 3002)));
    EXPECT_EQ(t.space.nodeClass(NodeId(t.ns, 1003)), NodeClass::ObjectType);
    // An inverse reference in the file is browsable from the other end (Objects folder).
    auto gripper = t.space.resolvePath(NodeId(0, ns0::ObjectsFolder),
                                       std::vector<QualifiedName>{{t.ns, "Gripper"}});
    ASSERT_TRUE(gripper);
    EXPECT_EQ(*gripper, NodeId(t.ns, "Cell.Gripper"));
    // Loading the same model again is a no-op.
    EXPECT_TRUE(loadNodeSetXml(t.space, PNP_TEST_NODESET).empty());
}

TEST(NodeSetXml, DataTypeDefinitionsIncludeInheritedFields) {
    Loaded t;
    Variant def = t.space.readAttribute(NodeId(t.ns, 3004), AttributeId::DataTypeDefinition)
                      .value.value_or(Variant());
    const auto* x = def.scalar<ExtensionObject>();
    ASSERT_NE(x, nullptr);
    auto sd = fromExtensionObject<StructureDefinition>(*x);
    ASSERT_TRUE(sd);
    ASSERT_EQ(sd->fields.size(), 9u);  // 8 of ToolData, then MaxLoad
    EXPECT_EQ(sd->fields[0].name, "Name");
    EXPECT_EQ(sd->fields[8].name, "MaxLoad");
    EXPECT_EQ(sd->baseDataType, NodeId(t.ns, 3002));
    EXPECT_EQ(sd->defaultEncodingId, NodeId(t.ns, 5004));
    EXPECT_EQ(sd->structureType, StructureType::StructureWithOptionalFields);

    Variant en = t.space.readAttribute(NodeId(t.ns, 3003), AttributeId::DataTypeDefinition)
                     .value.value_or(Variant());
    auto ed = fromExtensionObject<EnumDefinition>(*en.scalar<ExtensionObject>());
    ASSERT_TRUE(ed);
    ASSERT_EQ(ed->fields.size(), 3u);
    EXPECT_EQ(ed->fields[2].name, "Fault");
    EXPECT_EQ(ed->fields[2].value, 7);

    auto layout = t.space.structureLayout(NodeId(t.ns, 3005));
    ASSERT_TRUE(layout);
    EXPECT_EQ(layout->form, StructureLayout::Form::Union);
}

TEST(NodeSetXml, StructuredValueIsABinaryExtensionObjectThatDecodesDynamically) {
    Loaded t;
    DataValue dv = t.space.readValue(NodeId(t.ns, 6004));
    ASSERT_TRUE(dv.value);
    const auto* x = dv.value->scalar<ExtensionObject>();
    ASSERT_NE(x, nullptr);
    EXPECT_EQ(x->typeId, NodeId(t.ns, 5002));  // Default Binary, not the XML TypeId
    EXPECT_EQ(x->encoding, ExtensionObject::Encoding::Binary);

    auto layout = t.space.structureLayout(NodeId(t.ns, 3002));
    ASSERT_TRUE(layout);
    StructureValue v = decodeStructure(*layout, reinterpret_cast<const Byte*>(x->body.data()),
                                       x->body.size(), t.lookup());
    EXPECT_EQ(*v.field("Name")->scalar<String>(), "Gripper-7");
    EXPECT_EQ(*v.field("Mass")->scalar<Double>(), 1.25);
    EXPECT_EQ(*v.field("State")->scalar<Int32>(), 7);
    EXPECT_EQ(*v.field("Tags")->array<String>(), (std::vector<String>{"a", "b"}));
    EXPECT_TRUE(v.field("Comment")->isEmpty());  // optional, absent
    EXPECT_EQ(*v.field("Extra")->scalar<Int32>(), 42);

    auto point = t.space.structureLayout(NodeId(t.ns, 3001));
    ASSERT_TRUE(point);
    const auto* com = v.field("CenterOfMass")->scalar<ExtensionObject>();
    ASSERT_NE(com, nullptr);
    StructureValue c = decodeStructure(*point, reinterpret_cast<const Byte*>(com->body.data()),
                                       com->body.size(), t.lookup());
    EXPECT_EQ(*c.field("X")->scalar<Double>(), 0.5);
    EXPECT_EQ(*c.field("Y")->scalar<Double>(), -1.0);
    EXPECT_EQ(*c.field("Z")->scalar<Double>(), 25.0);
    const auto* wps = v.field("Waypoints")->array<ExtensionObject>();
    ASSERT_NE(wps, nullptr);
    ASSERT_EQ(wps->size(), 2u);
    StructureValue w1 =
        decodeStructure(*point, reinterpret_cast<const Byte*>((*wps)[1].body.data()),
                        (*wps)[1].body.size(), t.lookup());
    EXPECT_EQ(*w1.field("Z")->scalar<Double>(), 6.0);

    // The body is exactly what the codec encodes from the decoded fields (round trip), and
    // its bytes follow OPC 10000-6 §5.2.6: mask, String, Double, Point, ...
    EXPECT_EQ(encodeStructure(*layout, v, t.lookup()), x->body);
    EXPECT_EQ(static_cast<unsigned char>(x->body[0]), 0u);  // encoding mask: Comment absent
    v.fields.emplace_back("Comment", Variant(LocalizedText("en", "spare")));
    for (auto& f : v.fields)
        if (f.first == "Comment") f.second = Variant(LocalizedText("en", "spare"));
    std::string withComment = encodeStructure(*layout, v, t.lookup());
    EXPECT_EQ(static_cast<unsigned char>(withComment[0]), 1u);
    StructureValue back = decodeStructure(
        *layout, reinterpret_cast<const Byte*>(withComment.data()), withComment.size(), t.lookup());
    EXPECT_EQ(back.field("Comment")->scalar<LocalizedText>()->text, "spare");
}

TEST(NodeSetXml, UnionAndArrayOfStructuresValues) {
    Loaded t;
    DataValue dv = t.space.readValue(NodeId(t.ns, "Cell.Gripper.Target"));
    const auto* x = dv.value->scalar<ExtensionObject>();
    ASSERT_NE(x, nullptr);
    auto layout = t.space.structureLayout(NodeId(t.ns, 3005));
    StructureValue v = decodeStructure(*layout, reinterpret_cast<const Byte*>(x->body.data()),
                                       x->body.size(), t.lookup());
    EXPECT_TRUE(v.field("Position")->isEmpty());
    EXPECT_EQ(*v.field("Program")->scalar<String>(), "pick_and_place");
    EXPECT_EQ(x->body.substr(0, 4), std::string("\x02\x00\x00\x00", 4));  // switch field 2

    DataValue poses = t.space.readValue(NodeId(t.ns, 6010));
    const auto* arr = poses.value->array<ExtensionObject>();
    ASSERT_NE(arr, nullptr);
    ASSERT_EQ(arr->size(), 1u);
    EXPECT_EQ((*arr)[0].typeId, NodeId(t.ns, 5001));
    EXPECT_EQ((*arr)[0].body.size(), 24u);  // three Doubles
    // A written value of the custom type passes the type check.
    StatusCode ok = t.space.checkValue(*poses.value, NodeId(t.ns, 3001), 1);
    EXPECT_TRUE(ok.isGood()) << ok.toString();
}

TEST(NodeSetXml, WrittenStructuresMustDecodeByTheirDefinition) {
    Loaded t;
    const NodeId target(t.ns, "Cell.Gripper.Target");  // DataType Target (a union), writable
    auto layout = t.space.structureLayout(NodeId(t.ns, 3005));
    StructureValue v;
    v.fields.emplace_back("Program", Variant(String("weld")));
    ExtensionObject x;
    x.typeId = NodeId(t.ns, 5005);
    x.encoding = ExtensionObject::Encoding::Binary;
    x.body = encodeStructure(*layout, v, t.lookup());
    WriteValue w;
    w.nodeId = target;
    w.attributeId = static_cast<UInt32>(AttributeId::Value);
    w.value = DataValue(Variant(x));
    EXPECT_TRUE(t.space.write(w).isGood());
    x.body.resize(x.body.size() - 1);  // truncated String
    w.value = DataValue(Variant(x));
    EXPECT_EQ(t.space.write(w), status::BadTypeMismatch);
    x.body = std::string("\x07\x00\x00\x00", 4);  // union switch field beyond the fields
    w.value = DataValue(Variant(x));
    EXPECT_EQ(t.space.write(w), status::BadTypeMismatch);
    auto stored = t.space.readValue(target).value->scalar<ExtensionObject>()->body;
    StructureValue back = decodeStructure(*layout, reinterpret_cast<const Byte*>(stored.data()),
                                          stored.size(), t.lookup());
    EXPECT_EQ(*back.field("Program")->scalar<String>(), "weld");
}

TEST(NodeSetXml, CodecRejectsTruncatedBodiesAndWrongFieldTypes) {
    Loaded t;
    auto layout = t.space.structureLayout(NodeId(t.ns, 3002));
    const DataValue dv = t.space.readValue(NodeId(t.ns, 6004));
    const auto* x = dv.value->scalar<ExtensionObject>();
    std::string body = x->body;
    for (std::size_t cut : {std::size_t{0}, std::size_t{3}, body.size() / 2, body.size() - 1})
        EXPECT_THROW(
            decodeStructure(*layout, reinterpret_cast<const Byte*>(body.data()), cut, t.lookup()),
            DecodeError)
            << cut;
    StructureValue wrong;
    wrong.fields.emplace_back("Mass", Variant(String("heavy")));
    try {
        encodeStructure(*layout, wrong, t.lookup());
        FAIL() << "no error";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("Mass"), std::string::npos) << e.what();
    }
}

// ---- errors ----------------------------------------------------------------------------
class NodeSetXmlErrors : public ::testing::Test {
  protected:
    fs::path write(const std::string& name, const std::string& text) {
        fs::path dir =
            fs::temp_directory_path() / ("pnp_nodeset_test_" + std::to_string(::getpid()));
        fs::create_directories(dir);
        fs::path p = dir / name;
        std::ofstream(p) << text;
        return p;
    }
    static std::string nodeset(const std::string& body, const std::string& extraModel = "") {
        return R"(<?xml version="1.0"?>
<UANodeSet xmlns="http://opcfoundation.org/UA/2011/03/UANodeSet.xsd">
  <NamespaceUris><Uri>urn:bad</Uri></NamespaceUris>
  <Models><Model ModelUri="urn:bad"><RequiredModel ModelUri="http://opcfoundation.org/UA/"/>)" +
               extraModel + R"(</Model></Models>
  <Aliases><Alias Alias="HasComponent">i=47</Alias></Aliases>
)" + body + "\n</UANodeSet>\n";
    }
    std::string errorOf(const fs::path& file) {
        AddressSpace space;
        try {
            loadNodeSetXml(space, file, {file.parent_path()});
        } catch (const NodeSetError& e) {
            return e.what();
        }
        return "no error";
    }
    void TearDown() override {
        std::error_code ec;
        fs::remove_all(
            fs::temp_directory_path() / ("pnp_nodeset_test_" + std::to_string(::getpid())), ec);
    }
};

TEST_F(NodeSetXmlErrors, MalformedXmlNamesTheFileAndOffset) {
    auto f = write("malformed.xml", nodeset("<UAObject NodeId=\"ns=1;i=1\" BrowseName=\"1:A\">"));
    std::string e = errorOf(f);
    EXPECT_NE(e.find("malformed.xml"), std::string::npos) << e;
    EXPECT_NE(e.find("malformed XML"), std::string::npos) << e;
}

TEST_F(NodeSetXmlErrors, UnknownAliasNamesTheNode) {
    auto f = write("alias.xml", nodeset(R"(<UAObject NodeId="ns=1;i=7" BrowseName="1:A">
    <References><Reference ReferenceType="NoSuchAlias">i=85</Reference></References></UAObject>)"));
    std::string e = errorOf(f);
    EXPECT_NE(e.find("alias.xml"), std::string::npos) << e;
    EXPECT_NE(e.find("ns=1;i=7"), std::string::npos) << e;
    EXPECT_NE(e.find("NoSuchAlias"), std::string::npos) << e;
}

TEST_F(NodeSetXmlErrors, MissingRequiredModelIsNamed) {
    auto f = write("missing.xml", nodeset("", R"(<RequiredModel ModelUri="urn:not:there"/>)"));
    std::string e = errorOf(f);
    EXPECT_NE(e.find("urn:not:there"), std::string::npos) << e;
    EXPECT_NE(e.find("missing.xml"), std::string::npos) << e;
}

TEST_F(NodeSetXmlErrors, BadValuesNameTheNode) {
    auto f =
        write("value.xml", nodeset(R"(<UAVariable NodeId="ns=1;i=9" BrowseName="1:V" DataType="i=6">
    <Value><Int32 xmlns="http://opcfoundation.org/UA/2008/02/Types.xsd">twelve</Int32></Value></UAVariable>)"));
    std::string e = errorOf(f);
    EXPECT_NE(e.find("ns=1;i=9"), std::string::npos) << e;
    EXPECT_NE(e.find("twelve"), std::string::npos) << e;

    auto g =
        write("eo.xml", nodeset(R"(<UAVariable NodeId="ns=1;i=10" BrowseName="1:V" DataType="i=22">
    <Value><ExtensionObject xmlns="http://opcfoundation.org/UA/2008/02/Types.xsd"><TypeId><Identifier>ns=1;i=999</Identifier></TypeId><Body><X/></Body></ExtensionObject></Value></UAVariable>)"));
    e = errorOf(g);
    EXPECT_NE(e.find("ns=1;i=10"), std::string::npos) << e;
    EXPECT_NE(e.find("unknown"), std::string::npos) << e;
}

TEST_F(NodeSetXmlErrors, AFailedFileLeavesNoNodesBehind) {
    // The error is in the values (pass 3): nodes and references exist by then.
    auto f = write("late.xml", nodeset(R"(<UAObject NodeId="ns=1;i=20" BrowseName="1:Cell">
    <References><Reference ReferenceType="i=35" IsForward="false">i=85</Reference></References></UAObject>
  <UAVariable NodeId="ns=1;i=21" BrowseName="1:V" DataType="i=6">
    <References><Reference ReferenceType="HasComponent" IsForward="false">ns=1;i=20</Reference></References>
    <Value><Int32 xmlns="http://opcfoundation.org/UA/2008/02/Types.xsd">x</Int32></Value></UAVariable>)"));
    AddressSpace space;
    const auto before = space.statistics();
    const auto namespacesBefore = space.namespaceArray();
    EXPECT_THROW(loadNodeSetXml(space, f, {f.parent_path()}), NodeSetError);
    const auto after = space.statistics();
    EXPECT_EQ(after.nodes, before.nodes);
    EXPECT_EQ(after.references, before.references);
    EXPECT_EQ(space.namespaceArray(), namespacesBefore) << "the file's namespace stays";
    EXPECT_FALSE(
        space.resolvePath(NodeId(0, ns0::ObjectsFolder), std::vector<QualifiedName>{{2, "Cell"}}));
    EXPECT_FALSE(isModelLoaded(space, "urn:bad"));
    // A bad attribute of the second node: the first one goes again too.
    auto g = write("attr.xml", nodeset(R"(<UAObject NodeId="ns=1;i=30" BrowseName="1:A"/>
  <UAObject NodeId="ns=1;i=31" BrowseName="1:B" EventNotifier="lots"/>)"));
    try {
        loadNodeSetXml(space, g, {g.parent_path()});
        ADD_FAILURE() << "no error";
    } catch (const NodeSetError& e) {
        EXPECT_NE(std::string(e.what()).find("ns=1;i=31"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("EventNotifier"), std::string::npos) << e.what();
    }
    EXPECT_EQ(space.statistics().nodes, before.nodes);
    // The address space is still usable: a good file loads into it.
    EXPECT_EQ(loadNodeSetXml(space, PNP_TEST_NODESET).size(), 1u);
}

TEST_F(NodeSetXmlErrors, DuplicateNodeIdAndMissingBrowseName) {
    auto f = write("dup.xml", nodeset(R"(<UAObject NodeId="i=85" BrowseName="Objects"/>)"));
    std::string e = errorOf(f);
    EXPECT_NE(e.find("i=85"), std::string::npos) << e;
    EXPECT_NE(e.find("already exists"), std::string::npos) << e;
    auto g = write("nobn.xml", nodeset(R"(<UAObject NodeId="ns=1;i=3"/>)"));
    e = errorOf(g);
    EXPECT_NE(e.find("no BrowseName"), std::string::npos) << e;
}

TEST_F(NodeSetXmlErrors, AFileWithoutModelsIsFoundByItsFirstNamespace) {
    // No <Models> (older files): the model is named by its first namespace URI.
    write("old.xml", R"(<?xml version="1.0"?>
<UANodeSet xmlns="http://opcfoundation.org/UA/2011/03/UANodeSet.xsd">
  <NamespaceUris><Uri>urn:old</Uri></NamespaceUris>
  <UAObjectType NodeId="ns=1;i=1" BrowseName="1:OldType">
    <References><Reference ReferenceType="i=45" IsForward="false">i=58</Reference></References>
  </UAObjectType>
</UANodeSet>)");
    auto f = write("new.xml", R"(<?xml version="1.0"?>
<UANodeSet xmlns="http://opcfoundation.org/UA/2011/03/UANodeSet.xsd">
  <NamespaceUris><Uri>urn:new</Uri><Uri>urn:old</Uri></NamespaceUris>
  <Models><Model ModelUri="urn:new"><RequiredModel ModelUri="urn:old"/></Model></Models>
  <UAObjectType NodeId="ns=1;i=1" BrowseName="1:NewType">
    <References><Reference ReferenceType="i=45" IsForward="false">ns=2;i=1</Reference></References>
  </UAObjectType>
</UANodeSet>)");
    AddressSpace space;
    auto reports = loadNodeSetXml(space, f, {f.parent_path()});
    ASSERT_EQ(reports.size(), 2u);
    EXPECT_EQ(reports[0].modelUri, "urn:old");
    const UInt16 oldNs = *space.namespaceIndex("urn:old");
    const UInt16 newNs = *space.namespaceIndex("urn:new");
    EXPECT_TRUE(space.isSubtypeOf(NodeId(newNs, 1), NodeId(oldNs, 1)));
}

TEST_F(NodeSetXmlErrors, DeeplyNestedValueIsBounded) {
    std::string deep;
    for (int i = 0; i < 200; ++i) deep += "<ListOfVariant><Variant>";
    for (int i = 0; i < 200; ++i) deep += "</Variant></ListOfVariant>";
    auto f =
        write("deep.xml", nodeset(R"(<UAVariable NodeId="ns=1;i=11" BrowseName="1:V"><Value>)" +
                                  deep + "</Value></UAVariable>"));
    std::string e = errorOf(f);
    EXPECT_NE(e.find("nested too deeply"), std::string::npos) << e;
}

}  // namespace
}  // namespace pnp::ua::server

namespace pnp::ua::server {
namespace {

// The dynamic codec, driven by ns0's DataTypeDefinitions, reads and writes exactly the bytes
// of the generated codecs (nested structures, arrays of structures, optional fields).
template <class T>
void expectSameAsGenerated(const AddressSpace& space, const T& value) {
    const ExtensionObject x = toExtensionObject(value);
    auto layout = space.structureLayout(NodeId(0, DataTypeInfo<T>::dataTypeId));
    ASSERT_TRUE(layout) << DataTypeInfo<T>::name;
    EXPECT_EQ(layout->binaryEncoding, x.typeId);
    StructureLayoutLookup lookup = [&](const NodeId& id) { return space.structureLayout(id); };
    StructureValue v = decodeStructure(*layout, reinterpret_cast<const Byte*>(x.body.data()),
                                       x.body.size(), lookup);
    EXPECT_EQ(encodeStructure(*layout, v, lookup), x.body) << DataTypeInfo<T>::name;
}

TEST(StructureCodec, MatchesTheGeneratedCodecsOfNamespaceZero) {
    AddressSpace space;
    Argument a;
    a.name = "speed";
    a.dataType = NodeId(0, ns0::Double);
    a.valueRank = 1;
    a.arrayDimensions = {3};
    a.description = LocalizedText("en", "mm/s");
    expectSameAsGenerated(space, a);
    expectSameAsGenerated(space, Range{-1.5, 2.5});
    EUInformation eu;
    eu.namespaceUri = "http://www.opcfoundation.org/UA/units/un/cefact";
    eu.unitId = 4403766;
    eu.displayName = LocalizedText("", "mm");
    expectSameAsGenerated(space, eu);
    StructureDefinition sd;
    sd.defaultEncodingId = NodeId(2, 5001);
    sd.baseDataType = NodeId(0, ns0::Structure);
    sd.structureType = StructureType::StructureWithOptionalFields;
    sd.fields.resize(2);
    sd.fields[0].name = "X";
    sd.fields[0].dataType = NodeId(0, ns0::Double);
    sd.fields[1].name = "Tags";
    sd.fields[1].valueRank = 1;
    sd.fields[1].arrayDimensions = {0};
    sd.fields[1].isOptional = true;
    expectSameAsGenerated(space, sd);  // an array of nested structures
    BuildInfo b;
    b.productUri = "urn:pnp";
    b.softwareVersion = "1.0";
    b.buildDate = DateTime{133000000000000000};
    expectSameAsGenerated(space, b);  // DateTime, Strings
}

}  // namespace
}  // namespace pnp::ua::server
