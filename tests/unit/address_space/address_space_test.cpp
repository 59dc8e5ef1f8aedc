// Namespace 0 loading and the application API of the address space.
#include <chrono>
#include <fstream>
#include <regex>
#include <sstream>
#include <thread>

#include "test_util.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server::test {
namespace {

struct XmlNode {
    NodeId id;
    NodeClass cls;
};

// Every node of the official NodeSet2 file, read independently of the nodeset compiler.
std::vector<XmlNode> xmlNodes() {
    std::ifstream in(PNP_NS0_NODESET_XML);
    std::stringstream ss;
    ss << in.rdbuf();
    const std::string xml = ss.str();
    static const std::regex re(
        R"re(<UA(Object|Variable|Method|ObjectType|VariableType|ReferenceType|DataType|View) NodeId="([^"]+)")re");
    std::vector<XmlNode> out;
    for (auto it = std::sregex_iterator(xml.begin(), xml.end(), re); it != std::sregex_iterator();
         ++it) {
        const std::string kind = (*it)[1];
        NodeClass c = kind == "Object"          ? NodeClass::Object
                      : kind == "Variable"      ? NodeClass::Variable
                      : kind == "Method"        ? NodeClass::Method
                      : kind == "ObjectType"    ? NodeClass::ObjectType
                      : kind == "VariableType"  ? NodeClass::VariableType
                      : kind == "ReferenceType" ? NodeClass::ReferenceType
                      : kind == "DataType"      ? NodeClass::DataType
                                                : NodeClass::View;
        out.push_back({*NodeId::parse((*it)[2].str()), c});
    }
    return out;
}

TEST(Namespace0, LoadsEveryNodeOfTheNodeSet) {
    const auto t0 = std::chrono::steady_clock::now();
    AddressSpace space;
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    const auto nodes = xmlNodes();
    const auto stats = space.statistics();
    std::printf(
        "[ns0] %zu nodes (NodeSet2 file: %zu), %zu references, decoded in %.2f ms "
        "(constructor %.2f ms), model %.1f KiB\n",
        stats.nodes, nodes.size(), stats.references, stats.namespaceZeroLoadMs, ms,
        stats.bytesUsed / 1024.0);
    EXPECT_EQ(stats.nodes, nodes.size());
    EXPECT_GT(nodes.size(), 5000u);
    if (PNP_TIME_BUDGETS) {
        EXPECT_LT(stats.namespaceZeroLoadMs, 50.0);
    }
    for (const auto& n : nodes) {
        auto cls = space.nodeClass(n.id);
        ASSERT_TRUE(cls.has_value()) << n.id.toString();
        EXPECT_EQ(*cls, n.cls) << n.id.toString();
    }
}

TEST(Namespace0, ReferencesAreBrowsableInBothDirections) {
    AddressSpace space;
    ContinuationPointStore points;
    // The NodeSet lists Objects -Organizes-> Server only on the Server node (inverse).
    auto fwd = space.browse(browseDesc(ns0(ns0::ObjectsFolder)), 0, points);
    EXPECT_TRUE(hasTarget(fwd, ns0(ns0::Server)));
    auto inv = space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Inverse), 0, points);
    EXPECT_TRUE(hasTarget(inv, ns0(ns0::ObjectsFolder)));
    // HasSubtype: BaseObjectType -> FolderType and back.
    auto sub = space.browse(
        browseDesc(ns0(ns0::BaseObjectType), BrowseDirection::Forward, ns0(ns0::HasSubtype)), 0,
        points);
    EXPECT_TRUE(hasTarget(sub, ns0(ns0::FolderType)));
    auto super = space.browse(
        browseDesc(ns0(ns0::FolderType), BrowseDirection::Inverse, ns0(ns0::HasSubtype)), 0,
        points);
    ASSERT_EQ(super.references.size(), 1u);
    EXPECT_EQ(super.references[0].nodeId.nodeId, ns0(ns0::BaseObjectType));
}

TEST(Namespace0, NoReferenceIsListedTwice) {
    AddressSpace space;
    ContinuationPointStore points;
    auto r =
        space.browse(browseDesc(ns0(ns0::Server_ServerStatus), BrowseDirection::Both), 0, points);
    ASSERT_TRUE(r.statusCode.isGood());
    for (std::size_t i = 0; i < r.references.size(); ++i)
        for (std::size_t j = i + 1; j < r.references.size(); ++j)
            EXPECT_FALSE(r.references[i] == r.references[j]) << i << " " << j;
    // 6 components, 1 type definition, 1 parent.
    EXPECT_EQ(r.references.size(), 8u);
}

TEST(Namespace0, IsSubtypeOf) {
    AddressSpace space;
    EXPECT_TRUE(space.isSubtypeOf(ns0(ns0::UtcTime), ns0(ns0::DateTime)));
    EXPECT_TRUE(space.isSubtypeOf(ns0(ns0::Int32), ns0(ns0::Number)));
    EXPECT_TRUE(space.isSubtypeOf(ns0(ns0::HasComponent), ns0(ns0::HierarchicalReferences)));
    EXPECT_FALSE(space.isSubtypeOf(ns0(ns0::Double), ns0(ns0::Integer)));
    EXPECT_FALSE(space.isSubtypeOf(ns0(ns0::HasTypeDefinition), ns0(ns0::HierarchicalReferences)));
}

TEST(Namespace0, WithoutNamespaceZero) {
    AddressSpace::Options o;
    o.loadNamespaceZero = false;
    AddressSpace space(o);
    EXPECT_EQ(space.statistics().nodes, 0u);
    EXPECT_EQ(space.namespaceArray().size(), 2u);
}

using AppApi = AddressSpaceFixture;

TEST_F(AppApi, Namespaces) {
    EXPECT_EQ(ns, 2);
    EXPECT_EQ(space.addNamespace("urn:test"), 2);
    EXPECT_EQ(space.addNamespace("urn:other"), 3);
    EXPECT_EQ(space.namespaceIndex("urn:other"), std::optional<UInt16>(3));
    EXPECT_FALSE(space.namespaceIndex("urn:none").has_value());
    auto arr = space.namespaceArray();
    ASSERT_EQ(arr.size(), 4u);
    EXPECT_EQ(arr[0], "http://opcfoundation.org/UA/");
    EXPECT_EQ(arr[1], "urn:pnp:server");
    // Server.NamespaceArray is served live.
    auto v = space.readValue(ns0(ns0::Server_NamespaceArray));
    ASSERT_TRUE(v.value.has_value());
    ASSERT_NE(v.value->array<String>(), nullptr);
    EXPECT_EQ(*v.value->array<String>(), arr);
}

TEST_F(AppApi, AddObjectPicksReferenceTypeAndTypeDefinition) {
    NodeId folder = space.addFolder(ns0(ns0::ObjectsFolder), id("Cell"), name("Cell"));
    NodeId robot = space.addObject(folder, id("Robot"), name("Robot"));
    NodeId arm = space.addObject(robot, id("Arm"), name("Arm"));
    ContinuationPointStore points;
    auto r = space.browse(browseDesc(folder), 0, points);
    ASSERT_TRUE(hasTarget(r, robot));
    for (const auto& ref : r.references) {
        if (ref.nodeId.nodeId == robot) {
            EXPECT_EQ(ref.referenceTypeId, ns0(ns0::Organizes));
            EXPECT_EQ(ref.typeDefinition.nodeId, ns0(ns0::BaseObjectType));
            EXPECT_EQ(ref.browseName, name("Robot"));
            EXPECT_EQ(ref.displayName.text, "Robot");
        }
    }
    auto r2 = space.browse(browseDesc(robot), 0, points);
    for (const auto& ref : r2.references) {
        if (ref.nodeId.nodeId == arm) {
            EXPECT_EQ(ref.referenceTypeId, ns0(ns0::HasComponent));
        }
    }
    EXPECT_TRUE(hasTarget(r2, arm));
    auto path =
        std::vector<QualifiedName>{{0, "Objects"}, name("Cell"), name("Robot"), name("Arm")};
    EXPECT_EQ(space.resolvePath(ns0(ns0::RootFolder), path), std::optional<NodeId>(arm));
}

TEST_F(AppApi, FreshIdsAndErrors) {
    NodeId a = space.addObject(ns0(ns0::ObjectsFolder), NodeId(ns, UInt32{0}), name("A"));
    NodeId b = space.addObject(ns0(ns0::ObjectsFolder), NodeId(ns, UInt32{0}), name("B"));
    EXPECT_EQ(a.namespaceIndex(), ns);
    EXPECT_TRUE(a.isNumeric());
    EXPECT_NE(a, b);
    auto expectStatus = [](auto&& f, StatusCode s) {
        try {
            f();
            ADD_FAILURE() << "no exception";
        } catch (const AddressSpaceError& e) {
            EXPECT_EQ(e.status(), s) << e.what();
        }
    };
    expectStatus([&] { space.addObject(ns0(ns0::ObjectsFolder), a, name("Again")); },
                 status::BadNodeIdExists);
    expectStatus([&] { space.addObject(id("missing"), id("X"), name("X")); },
                 status::BadParentNodeIdInvalid);
    expectStatus(
        [&] {
            space.addObject(ns0(ns0::ObjectsFolder), id("X"), name("X"), {},
                            ns0(ns0::BaseDataVariableType));
        },
        status::BadTypeDefinitionInvalid);
    expectStatus(
        [&] {
            space.addObject(ns0(ns0::ObjectsFolder), id("X"), name("X"), {},
                            ns0(ns0::BaseObjectType), ns0(ns0::ObjectsFolder));
        },
        status::BadReferenceTypeIdInvalid);
    expectStatus([&] { space.addObject(ns0(ns0::ObjectsFolder), id("X"), QualifiedName{}); },
                 status::BadBrowseNameInvalid);
    VariableAttributes va;
    va.dataType = ns0(ns0::Int32);
    va.value = DataValue(Variant(3.5));
    expectStatus([&] { space.addVariable(ns0(ns0::ObjectsFolder), id("V"), name("V"), va); },
                 status::BadTypeMismatch);
    EXPECT_FALSE(space.contains(id("X")));
    EXPECT_FALSE(space.contains(id("V")));
}

TEST_F(AppApi, DeleteNodeRemovesReferencesAndChildren) {
    NodeId obj = space.addObject(ns0(ns0::ObjectsFolder), id("Obj"), name("Obj"));
    NodeId var = addVar("Obj.Var", ns0::Int32, Variant(Int32{1}));
    space.addReference(obj, ns0(ns0::HasComponent), var);
    NodeId prop = space.addProperty(obj, id("Obj.Prop"), name("Prop"), VariableAttributes{});
    const auto before = space.statistics();
    space.deleteNode(obj);
    EXPECT_FALSE(space.contains(obj));
    EXPECT_FALSE(space.contains(prop));  // aggregated child
    EXPECT_FALSE(space.contains(var));   // aggregated child (also organized by Objects)
    ContinuationPointStore points;
    auto r = space.browse(browseDesc(ns0(ns0::ObjectsFolder)), 0, points);
    EXPECT_FALSE(hasTarget(r, obj));
    EXPECT_FALSE(hasTarget(r, var));
    const auto after = space.statistics();
    EXPECT_EQ(after.nodes, before.nodes - 3);
    // Objects->Obj, Obj->type, Objects->Var, Var->type, Obj->Var, Obj->Prop, Prop->type.
    EXPECT_EQ(after.references, before.references - 7);
    // Deleting without children keeps them.
    NodeId o2 = space.addObject(ns0(ns0::ObjectsFolder), id("O2"), name("O2"));
    NodeId c2 = space.addObject(o2, id("O2.C"), name("C"));
    space.deleteNode(o2, false);
    EXPECT_TRUE(space.contains(c2));
    auto inv = space.browse(browseDesc(c2, BrowseDirection::Inverse), 0, points);
    EXPECT_FALSE(hasTarget(inv, o2));
    EXPECT_THROW(space.deleteNode(o2), AddressSpaceError);
}

TEST_F(AppApi, DeleteNamespaceZeroNode) {
    ContinuationPointStore points;
    space.deleteNode(ns0(ns0::Server_ServerStatus_State), false);
    EXPECT_FALSE(space.contains(ns0(ns0::Server_ServerStatus_State)));
    auto r = space.browse(browseDesc(ns0(ns0::Server_ServerStatus)), 0, points);
    EXPECT_FALSE(hasTarget(r, ns0(ns0::Server_ServerStatus_State)));
    EXPECT_TRUE(hasTarget(r, ns0(ns0::Server_ServerStatus_CurrentTime)));
}

TEST_F(AppApi, AddAndDeleteReferences) {
    NodeId a = space.addObject(ns0(ns0::ObjectsFolder), id("A"), name("A"));
    NodeId b = space.addObject(ns0(ns0::ObjectsFolder), id("B"), name("B"));
    space.addReference(a, ns0(ns0::HasEventSource), b);
    EXPECT_THROW(space.addReference(a, ns0(ns0::HasEventSource), b), AddressSpaceError);
    // Inverse form: b <-HasNotifier- a written from b's side.
    space.addReference(b, ns0(ns0::HasNotifier), a, false);
    ContinuationPointStore points;
    auto r =
        space.browse(browseDesc(a, BrowseDirection::Forward, ns0(ns0::HasEventSource)), 0, points);
    EXPECT_TRUE(hasTarget(r, b));  // HasNotifier is a subtype of HasEventSource
    EXPECT_EQ(r.references.size(), 2u);
    // A reference to a node of another server.
    ExpandedNodeId remote(NodeId(1, 42), "", 3);
    space.addReference(a, ns0(ns0::Organizes), remote);
    auto r2 = space.browse(browseDesc(a, BrowseDirection::Forward, ns0(ns0::Organizes)), 0, points);
    ASSERT_EQ(r2.references.size(), 1u);
    EXPECT_EQ(r2.references[0].nodeId, remote);
    EXPECT_TRUE(space.deleteReference(a, ns0(ns0::Organizes), remote));
    EXPECT_TRUE(space.deleteReference(a, ns0(ns0::HasEventSource), b));
    EXPECT_FALSE(space.deleteReference(a, ns0(ns0::HasEventSource), b));
    EXPECT_TRUE(space.deleteReference(b, ns0(ns0::HasNotifier), a, false));
    r = space.browse(browseDesc(a, BrowseDirection::Forward, ns0(ns0::HasEventSource)), 0, points);
    EXPECT_TRUE(r.references.empty());
}

TEST_F(AppApi, CustomTypesAndSubtypeClosure) {
    NodeId rt = space.addReferenceType(ns0(ns0::HasComponent), id("HasTool"), name("HasTool"),
                                       {{}, false, false, LocalizedText("", "ToolOf")});
    NodeId ot = space.addObjectType(ns0(ns0::BaseObjectType), id("RobotType"), name("RobotType"));
    NodeId robot = space.addObject(ns0(ns0::ObjectsFolder), id("R1"), name("R1"), {}, ot);
    NodeId tool =
        space.addObject(robot, id("R1.Tool"), name("Tool"), {}, ns0(ns0::BaseObjectType), rt);
    EXPECT_TRUE(space.isSubtypeOf(rt, ns0(ns0::HierarchicalReferences)));
    ContinuationPointStore points;
    // Browsing for HierarchicalReferences with subtypes finds the new reference type.
    auto r = space.browse(
        browseDesc(robot, BrowseDirection::Forward, ns0(ns0::HierarchicalReferences), true), 0,
        points);
    EXPECT_TRUE(hasTarget(r, tool));
    auto nosub = space.browse(
        browseDesc(robot, BrowseDirection::Forward, ns0(ns0::HasComponent), false), 0, points);
    EXPECT_FALSE(hasTarget(nosub, tool));
    EXPECT_EQ(
        space.readAttribute(rt, AttributeId::InverseName).value->scalar<LocalizedText>()->text,
        "ToolOf");
    NodeId vt =
        space.addVariableType(ns0(ns0::BaseDataVariableType), id("TempType"), name("TempType"));
    NodeId dt = space.addDataType(ns0(ns0::Structure), id("MyStruct"), name("MyStruct"));
    EXPECT_EQ(space.nodeClass(vt), std::optional<NodeClass>(NodeClass::VariableType));
    EXPECT_EQ(space.nodeClass(dt), std::optional<NodeClass>(NodeClass::DataType));
    EXPECT_TRUE(space.isSubtypeOf(dt, ns0(ns0::Structure)));
    // Deleting the reference type removes it from the closure.
    space.deleteNode(tool);
    space.deleteNode(rt);
    EXPECT_FALSE(space.isSubtypeOf(rt, ns0(ns0::HierarchicalReferences)));
}

TEST_F(AppApi, ConcurrentReadersAndWriter) {
    NodeId v = addVar("Counter", ns0::Int32, Variant(Int32{0}));
    std::atomic<bool> stop{false};
    std::thread writer([&] {
        for (Int32 i = 1; i <= 2000; ++i)
            ASSERT_TRUE(space.setValue(v, DataValue(Variant(i))).isGood());
        stop = true;
    });
    Int32 last = 0;
    ContinuationPointStore points;
    while (!stop) {
        auto dv = space.readValue(v);
        ASSERT_TRUE(dv.value && dv.value->scalar<Int32>());
        Int32 now = *dv.value->scalar<Int32>();
        EXPECT_GE(now, last);
        last = now;
        auto r = space.browse(browseDesc(ns0(ns0::Server)), 0, points);
        EXPECT_TRUE(r.statusCode.isGood());
    }
    writer.join();
    EXPECT_EQ(*space.readValue(v).value->scalar<Int32>(), 2000);
}

TEST_F(AppApi, RegisterNodesIsIdentity) {
    RegisterNodesRequest req;
    req.nodesToRegister = {ns0(ns0::Server), id("anything")};
    auto resp = space.registerNodes(req);
    EXPECT_EQ(resp.registeredNodeIds, req.nodesToRegister);
    EXPECT_EQ(space.registerNodes({}).responseHeader.serviceResult, status::BadNothingToDo);
    UnregisterNodesRequest ureq;
    ureq.nodesToUnregister = req.nodesToRegister;
    EXPECT_TRUE(space.unregisterNodes(ureq).responseHeader.serviceResult.isGood());
}

}  // namespace
}  // namespace pnp::ua::server::test

namespace pnp::ua::server::test {
namespace {

// Not a benchmark (see bench/), just a visible order of magnitude for the hot paths.
TEST(Performance, ServicesAreCheap) {
    AddressSpace space;
    UInt16 ns = space.addNamespace("urn:perf");
    VariableAttributes va;
    va.dataType = NodeId(0, ns0::Double);
    va.accessLevel = access_level::CurrentRead | access_level::CurrentWrite;
    va.value = DataValue(Variant(1.0));
    NodeId v = space.addVariable(NodeId(0, ns0::ObjectsFolder), NodeId(ns, "v"),
                                 QualifiedName{ns, "v"}, va);
    auto time = [](int n, auto&& f) {
        auto t0 = std::chrono::steady_clock::now();
        for (int i = 0; i < n; ++i) f(i);
        return std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0)
                   .count() /
               n;
    };
    ReadRequest read;
    read.timestampsToReturn = TimestampsToReturn::Both;
    read.nodesToRead.push_back(readId(v, AttributeId::Value));
    double readNs = time(20000, [&](int) { ASSERT_EQ(space.read(read).results.size(), 1u); });
    WriteRequest write;
    write.nodesToWrite.push_back(writeValue(v, Variant(2.0)));
    double writeNs = time(20000, [&](int i) {
        write.nodesToWrite[0].value = DataValue(Variant(double(i)));
        ASSERT_TRUE(space.write(write).results[0].isGood());
    });
    ContinuationPointStore points;
    BrowseRequest browse;
    browse.nodesToBrowse.push_back(browseDesc(NodeId(0, ns0::Server), BrowseDirection::Both));
    std::size_t refs = 0;
    double browseNs =
        time(5000, [&](int) { refs = space.browse(browse, points).results[0].references.size(); });
    TranslateBrowsePathsToNodeIdsRequest tr;
    BrowsePath p;
    p.startingNode = NodeId(0, ns0::RootFolder);
    for (const char* n : {"Objects", "Server", "ServerStatus", "State"}) {
        RelativePathElement e;
        e.referenceTypeId = NodeId(0, ns0::HierarchicalReferences);
        e.includeSubtypes = true;
        e.targetName = QualifiedName{0, n};
        p.relativePath.elements.push_back(e);
    }
    tr.browsePaths.push_back(p);
    double translateNs = time(20000, [&](int) {
        ASSERT_TRUE(space.translateBrowsePaths(tr).results[0].statusCode.isGood());
    });
    std::printf(
        "[perf] read 1 value %.0f ns, write 1 value %.0f ns, browse Server (%zu refs) "
        "%.0f ns, translate 4-element path %.0f ns\n",
        readNs, writeNs, refs, browseNs, translateNs);
}

}  // namespace
}  // namespace pnp::ua::server::test

namespace pnp::ua::server::test {
namespace {

using Instantiation = AddressSpaceFixture;

TEST_F(Instantiation, NamespaceZeroObjectType) {
    NodeId srv = space.addObject(ns0(ns0::ObjectsFolder), id("MyServer"), name("MyServer"), {},
                                 ns0(ns0::ServerType));
    auto path = [&](std::vector<QualifiedName> p) { return space.resolvePath(srv, p); };
    // ServerType -> ServerStatus (ServerStatusType) -> BuildInfo (BuildInfoType) -> ProductName.
    auto product = path({{0, "ServerStatus"}, {0, "BuildInfo"}, {0, "ProductName"}});
    ASSERT_TRUE(product.has_value());
    EXPECT_EQ(*product, id("MyServer.ServerStatus.BuildInfo.ProductName"));
    auto current = path({{0, "ServerStatus"}, {0, "CurrentTime"}});
    ASSERT_TRUE(current.has_value());
    EXPECT_EQ(*space.readAttribute(*current, AttributeId::DataType).value->scalar<NodeId>(),
              ns0(ns0::UtcTime));
    EXPECT_TRUE(path({{0, "NamespaceArray"}}).has_value());
    EXPECT_TRUE(path({{0, "ServerCapabilities"}, {0, "MaxBrowseContinuationPoints"}}).has_value());
    // Copies carry their type definitions and modelling-rule-free instance references.
    ContinuationPointStore points;
    auto r = space.browse(browseDesc(*path({{0, "ServerStatus"}})), 0, points);
    EXPECT_TRUE(hasTarget(r, ns0(ns0::ServerStatusType)));
    EXPECT_FALSE(hasTarget(r, ns0(ns0::ModellingRule_Mandatory)));
    // Optional children are not created.
    EXPECT_FALSE(path({{0, "ServerRedundancy"}, {0, "RedundantServerArray"}}).has_value());
    // A copied method shares the arguments of its declaration.
    auto m = path({{0, "GetMonitoredItems"}});
    if (m) {
        CallRequest req;
        CallMethodRequest c;
        c.objectId = srv;
        c.methodId = *m;
        req.methodsToCall.push_back(c);
        EXPECT_EQ(space.callSync(req).results[0].statusCode, status::BadArgumentsMissing);
    }
}

TEST_F(Instantiation, CustomTypesAndMethodHandlers) {
    const NodeId mandatory = ns0(ns0::ModellingRule_Mandatory);
    NodeId device =
        space.addObjectType(ns0(ns0::BaseObjectType), id("DeviceType"), name("DeviceType"));
    VariableAttributes serial;
    serial.dataType = ns0(ns0::String);
    serial.value = DataValue(Variant(String("unknown")));
    NodeId serialDecl = space.addProperty(device, id("DeviceType.Serial"), name("Serial"), serial);
    space.addReference(serialDecl, ns0(ns0::HasModellingRule), mandatory);
    NodeId optional = space.addProperty(device, id("DeviceType.Note"), name("Note"), serial);
    space.addReference(optional, ns0(ns0::HasModellingRule), ns0(ns0::ModellingRule_Optional));
    std::vector<NodeId> resetOn;
    NodeId resetDecl = space.addMethod(
        device, id("DeviceType.Reset"), name("Reset"), {argument("hard", ns0::Boolean)}, {},
        makeMethodHandler([&](const MethodCallContext& c, auto&, auto&) {
            resetOn.push_back(c.objectId);
            return StatusCode{};
        }));
    space.addReference(resetDecl, ns0(ns0::HasModellingRule), mandatory);
    NodeId robotType = space.addObjectType(device, id("RobotType"), name("RobotType"));
    VariableAttributes axes;
    axes.dataType = ns0(ns0::UInt32);
    axes.value = DataValue(Variant(UInt32{6}));
    NodeId axesDecl = space.addVariable(robotType, id("RobotType.Axes"), name("Axes"), axes);
    space.addReference(axesDecl, ns0(ns0::HasModellingRule), mandatory);

    NodeId robot = space.addObject(ns0(ns0::ObjectsFolder), id("R1"), name("R1"), {}, robotType);
    EXPECT_TRUE(space.contains(id("R1.Serial")));
    EXPECT_TRUE(space.contains(id("R1.Axes")));
    EXPECT_TRUE(space.contains(id("R1.Reset")));
    EXPECT_TRUE(space.contains(id("R1.Reset.InputArguments")));
    EXPECT_FALSE(space.contains(id("R1.Note")));
    EXPECT_EQ(*space.readValue(id("R1.Axes")).value->scalar<UInt32>(), 6u);
    EXPECT_EQ(*space.readValue(id("R1.Serial")).value->scalar<String>(), "unknown");
    // Instance values are independent of the declaration's.
    EXPECT_TRUE(space.setValue(id("R1.Serial"), DataValue(Variant(String("SN-1")))).isGood());
    EXPECT_EQ(*space.readValue(serialDecl).value->scalar<String>(), "unknown");
    // The copied method uses the declaration's handler until the instance gets its own.
    CallRequest req;
    CallMethodRequest c;
    c.objectId = robot;
    c.methodId = id("R1.Reset");
    c.inputArguments = {Variant(true)};
    req.methodsToCall.push_back(c);
    EXPECT_TRUE(space.callSync(req).results[0].statusCode.isGood());
    EXPECT_EQ(resetOn, std::vector<NodeId>{robot});
    space.setMethodHandler(id("R1.Reset"), makeMethodHandler([](auto&, auto&, auto&) {
                               return status::BadInvalidState;
                           }));
    EXPECT_EQ(space.callSync(req).results[0].statusCode, status::BadInvalidState);
    // Opting out, and numeric ids.
    ObjectAttributes bare;
    bare.instantiateMandatory = false;
    NodeId r2 = space.addObject(ns0(ns0::ObjectsFolder), id("R2"), name("R2"), bare, robotType);
    EXPECT_FALSE(space.resolvePath(r2, std::vector<QualifiedName>{name("Serial")}).has_value());
    NodeId r3 =
        space.addObject(ns0(ns0::ObjectsFolder), NodeId(ns, UInt32{0}), name("R3"), {}, robotType);
    auto s3 = space.resolvePath(r3, std::vector<QualifiedName>{name("Serial")});
    ASSERT_TRUE(s3.has_value());
    EXPECT_TRUE(s3->isNumeric());
    EXPECT_EQ(s3->namespaceIndex(), ns);
    // Deleting an instance deletes its copies.
    space.deleteNode(robot);
    EXPECT_FALSE(space.contains(id("R1.Reset.InputArguments")));
    EXPECT_TRUE(space.contains(resetDecl));
}

}  // namespace
}  // namespace pnp::ua::server::test
