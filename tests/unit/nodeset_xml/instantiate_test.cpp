// AddressSpace::instantiate on types loaded from NodeSet2 XML (OPC 10000-3 §6.4): Mandatory
// children of the whole supertype chain and of implemented interfaces, Optional children on
// request, placeholders skipped, HasTypeDefinition set, ModellingRules not copied.
#include <gtest/gtest.h>

#include "ua/server/nodeset_xml.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {
namespace {

std::vector<ReferenceDescription> forward(const AddressSpace& s, const NodeId& id,
                                          std::uint32_t refType) {
    ContinuationPointStore points;
    BrowseDescription d;
    d.nodeId = id;
    d.browseDirection = BrowseDirection::Forward;
    d.referenceTypeId = NodeId(0, refType);
    d.includeSubtypes = true;
    d.resultMask = 63;
    return s.browse(d, 0, points).references;
}

struct Cell {
    AddressSpace space;
    UInt16 ns = 0;
    Cell() {
        loadNodeSetXml(space, PNP_TEST_NODESET);
        ns = *space.namespaceIndex("urn:pnp:test:nodeset");
    }
    std::optional<NodeId> child(const NodeId& from, std::vector<QualifiedName> path) const {
        return space.resolvePath(from, path);
    }
};

TEST(Instantiate, MandatoryChildrenOfSupertypesAndInterfaces) {
    Cell c;
    NodeId e = c.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(c.ns, 1003),
                                   NodeId(1, "EE1"), {c.ns, "EE1"});
    EXPECT_EQ(e, NodeId(1, "EE1"));
    EXPECT_EQ(c.space.nodeClass(e), NodeClass::Object);
    auto td = forward(c.space, e, ns0::HasTypeDefinition);
    ASSERT_EQ(td.size(), 1u);
    EXPECT_EQ(td[0].nodeId.nodeId, NodeId(c.ns, 1003));
    // Own Mandatory children, recursively (Fingers/Count), and the supertype's (Serial) ...
    auto tool = c.child(e, {{c.ns, "Tool"}});
    ASSERT_TRUE(tool);
    EXPECT_EQ(*tool, NodeId(1, "EE1.Tool"));
    auto count = c.child(e, {{c.ns, "Fingers"}, {c.ns, "Count"}});
    ASSERT_TRUE(count);
    EXPECT_EQ(c.space.readValue(*count).value, Variant(Int32(3)));
    auto serial = c.child(e, {{c.ns, "Serial"}});
    ASSERT_TRUE(serial);
    EXPECT_EQ(c.space.readValue(*serial).value, Variant(String("unknown")));
    // ... and the Mandatory child of the interface it implements (HasInterface).
    auto slots = c.child(e, {{c.ns, "ToolSlots"}});
    ASSERT_TRUE(slots);
    EXPECT_EQ(c.space.readValue(*slots).value, Variant(Int32(4)));
    // Optional children are not created unless asked for; placeholders never.
    EXPECT_FALSE(c.child(e, {{c.ns, "Location"}}));
    EXPECT_FALSE(c.child(e, {{c.ns, "Grip"}}));
    EXPECT_FALSE(c.child(e, {{c.ns, "<Tool>"}}));
    // The copies carry the structured value and no ModellingRule.
    EXPECT_EQ(c.space.readValue(*tool).value, c.space.readValue(NodeId(c.ns, 6004)).value);
    for (const NodeId& n : {*tool, *serial, *slots, *count})
        EXPECT_TRUE(forward(c.space, n, ns0::HasModellingRule).empty()) << n.toString();
    auto toolTd = forward(c.space, *tool, ns0::HasTypeDefinition);
    ASSERT_EQ(toolTd.size(), 1u);
    EXPECT_EQ(toolTd[0].nodeId.nodeId, NodeId(0, ns0::BaseDataVariableType));
}

TEST(Instantiate, OptionalChildrenOnRequest) {
    Cell c;
    InstantiateOptions o;
    o.optionalChildren = {{c.ns, "Location"}, {c.ns, "Grip"}};
    o.displayName = LocalizedText("en", "Left gripper");
    NodeId e = c.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(c.ns, 1003),
                                   NodeId(1, UInt32(0)), {c.ns, "EE2"}, o);
    EXPECT_TRUE(c.child(e, {{c.ns, "Location"}}));
    auto grip = c.child(e, {{c.ns, "Grip"}});
    ASSERT_TRUE(grip);
    EXPECT_EQ(c.space.readValue(*grip).value, Variant(Int32(1)));
    EXPECT_EQ(c.space.readAttribute(*grip, AttributeId::DataType).value,
              Variant(NodeId(c.ns, 3003)));
    EXPECT_FALSE(c.child(e, {{c.ns, "<Tool>"}}));
    EXPECT_EQ(c.space.readAttribute(e, AttributeId::DisplayName).value,
              Variant(LocalizedText("en", "Left gripper")));
}

TEST(Instantiate, VariableTypesAndErrors) {
    Cell c;
    // A VariableType instance takes DataType / ValueRank from the type (AnalogItemType:
    // Mandatory EURange).
    NodeId v = c.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(0, ns0::AnalogItemType),
                                   NodeId(1, "Temp"), {1, "Temp"});
    EXPECT_EQ(c.space.nodeClass(v), NodeClass::Variable);
    EXPECT_TRUE(c.child(v, {{0, "EURange"}}));
    EXPECT_EQ(c.space.readAttribute(v, AttributeId::DataType).value,
              Variant(NodeId(0, ns0::Number)));
    // Abstract types and non-types cannot be instantiated.
    EXPECT_THROW(c.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(c.ns, 1002),
                                     NodeId(1, "X"), {1, "X"}),
                 AddressSpaceError);
    EXPECT_THROW(c.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(0, ns0::ObjectsFolder),
                                     NodeId(1, "Y"), {1, "Y"}),
                 AddressSpaceError);
}

TEST(Instantiate, RoboticsMotionDeviceSystem) {
    AddressSpace space;
    loadNodeSetXml(space, std::filesystem::path(PNP_NODESET_DIR) / "Opc.Ua.Robotics.NodeSet2.xml");
    const UInt16 rob = *space.namespaceIndex("http://opcfoundation.org/UA/Robotics/");
    const UInt16 di = *space.namespaceIndex("http://opcfoundation.org/UA/DI/");
    NodeId sys = space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(rob, 1002),
                                   NodeId(1, "Robot1"), {1, "Robot1"});
    // MotionDeviceSystemType's Mandatory folders; their placeholders stay uninstantiated.
    auto md = space.resolvePath(sys, std::vector<QualifiedName>{{rob, "MotionDevices"}});
    ASSERT_TRUE(md);
    EXPECT_TRUE(space.resolvePath(sys, std::vector<QualifiedName>{{rob, "Controllers"}}));
    EXPECT_FALSE(
        space.resolvePath(*md, std::vector<QualifiedName>{{rob, "<MotionDeviceIdentifier>"}}));
    // A MotionDevice below it: Mandatory children from MotionDeviceType and DI's ComponentType.
    NodeId arm = space.instantiate(*md, NodeId(rob, 1004), NodeId(1, "Robot1.Arm"), {1, "Arm"});
    EXPECT_TRUE(space.resolvePath(arm, std::vector<QualifiedName>{{rob, "Axes"}}));
    EXPECT_TRUE(space.resolvePath(arm, std::vector<QualifiedName>{{rob, "PowerTrains"}}));
    auto category =
        space.resolvePath(arm, std::vector<QualifiedName>{{rob, "MotionDeviceCategory"}});
    ASSERT_TRUE(category);
    EXPECT_EQ(space.readAttribute(*category, AttributeId::DataType).value,
              Variant(NodeId(rob, 18193)));
    (void)di;
}

}  // namespace
}  // namespace pnp::ua::server
