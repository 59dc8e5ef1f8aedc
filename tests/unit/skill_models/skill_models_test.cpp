// The skill model's NodeSet2 files (models/, contract: docs of issue 5): each loads with the
// models it requires and without warnings, every type has its fixed id, supertype and
// IsAbstract, and instantiating a concrete skill type gives the structure clients browse:
// the program state machine, Start..Reset, DI ParameterSet with every parameter (inherited
// and from interfaces, with DataType / ValueRank / AccessLevel), DI Lock, FinalResultData.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

#include "ua/server/nodeset_xml.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {
namespace {

namespace fs = std::filesystem;

const std::string kDi = "http://opcfoundation.org/UA/DI/";
const std::string kRobotics = "http://opcfoundation.org/UA/Robotics/";
const std::string kBase = "urn:pnp:ua:skills";
const std::string kRob = "urn:pnp:ua:skills:robotics";
const std::string kTool = "urn:pnp:ua:skills:toolchanger";
const std::string kComp = "urn:pnp:ua:skills:composite";
const std::string kDemo = "urn:pnp:ua:skills:demo";

const std::vector<std::string> kFiles = {
    "Pnp.Skills.NodeSet2.xml",
    "Pnp.Skills.Robotics.NodeSet2.xml",
    "Pnp.Skills.ToolChanger.NodeSet2.xml",
    "Pnp.Skills.Composite.NodeSet2.xml",
    "Pnp.Skills.Demo.NodeSet2.xml",
};

std::vector<fs::path> searchPath() {
    auto p = defaultNodeSetSearchPath();
    p.emplace_back(PNP_MODELS_DIR);
    return p;
}

std::vector<NodeSetLoadReport> load(AddressSpace& space, const std::string& file) {
    return loadNodeSetXml(space, fs::path(PNP_MODELS_DIR) / file, searchPath());
}

// Every skill model file loaded into one address space.
struct Models {
    AddressSpace space;
    UInt16 di = 0, base = 0, rob = 0, tool = 0, comp = 0, demo = 0;
    Models() {
        for (const auto& f : kFiles) load(space, f);
        di = *space.namespaceIndex(kDi);
        base = *space.namespaceIndex(kBase);
        rob = *space.namespaceIndex(kRob);
        tool = *space.namespaceIndex(kTool);
        comp = *space.namespaceIndex(kComp);
        demo = *space.namespaceIndex(kDemo);
    }
    UInt16 ns(const std::string& uri) const { return *space.namespaceIndex(uri); }
    std::optional<NodeId> child(const NodeId& from, const std::vector<QualifiedName>& p) const {
        return space.resolvePath(from, p);
    }
    Variant attr(const NodeId& n, AttributeId a) const {
        auto v = space.readAttribute(n, a).value;
        return v ? *v : Variant{};
    }
};

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

TEST(SkillModels, EachFileLoadsWithItsRequirementsAndNoWarnings) {
    for (const auto& file : kFiles) {
        SCOPED_TRACE(file);
        AddressSpace space;
        std::vector<NodeSetLoadReport> reports;
        ASSERT_NO_THROW(reports = load(space, file));
        ASSERT_FALSE(reports.empty());
        EXPECT_EQ(reports.back().file.filename(), file);
        for (const auto& r : reports) {
            EXPECT_TRUE(r.warnings.empty()) << r.file << ": " << r.warnings.front();
            EXPECT_GT(r.nodes, 0u) << r.file;
        }
        EXPECT_TRUE(isModelLoaded(space, kDi));
        EXPECT_TRUE(isModelLoaded(space, kBase));
        EXPECT_TRUE(isModelLoaded(space, reports.back().modelUri));
    }
    AddressSpace space;
    load(space, "Pnp.Skills.Robotics.NodeSet2.xml");
    EXPECT_TRUE(isModelLoaded(space, kRobotics));
}

struct TypeSpec {
    std::string uri;
    UInt32 id;
    std::string name;
    std::string superUri;  // empty: ns0
    UInt32 superId;
    bool isAbstract;
};

TEST(SkillModels, EveryContractTypeWithSupertypeAndIsAbstract) {
    Models m;
    const std::vector<TypeSpec> types = {
        {kBase, 3001, "SkillResultCode", "", 29, false},
        {kBase, 3002, "GripPointKind", "", 29, false},
        {kBase, 1001, "SkillType", "", ns0::ProgramStateMachineType, true},
        {kBase, 1002, "ISkillControllerType", "", ns0::BaseInterfaceType, true},
        {kBase, 1003, "SkillTransitionEventType", "", ns0::ProgramTransitionEventType, false},
        {kBase, 1004, "SkillFinalResultDataType", "", ns0::BaseObjectType, false},
        {kBase, 1010, "GripperSkillType", kBase, 1001, true},
        {kBase, 1011, "GraspGripperSkillType", kBase, 1010, false},
        {kBase, 1012, "ReleaseGripperSkillType", kBase, 1010, false},
        {kBase, 1013, "MoveGripperSkillType", kBase, 1010, false},
        {kBase, 1020, "IGripperType", "", ns0::BaseInterfaceType, true},
        {kBase, 1021, "GripPointType", "", ns0::BaseObjectType, false},
        {kBase, 1022, "ParallelGripPointType", kBase, 1021, false},
        {kBase, 1030, "IPowerOffDeviceType", "", ns0::BaseInterfaceType, true},
        {kRob, 1001, "MoveSkillType", kBase, 1001, true},
        {kRob, 1002, "PtpMoveSkillType", kRob, 1001, true},
        {kRob, 1003, "LinearMoveSkillType", kRob, 1001, true},
        {kRob, 1004, "ICartesianMoveSkillParameterType", "", ns0::BaseInterfaceType, true},
        {kRob, 1005, "IJointMoveSkillParameterType", "", ns0::BaseInterfaceType, true},
        {kRob, 1006, "CartesianPtpMoveSkillType", kRob, 1002, false},
        {kRob, 1007, "CartesianLinearMoveSkillType", kRob, 1003, false},
        {kRob, 1008, "JointPtpMoveSkillType", kRob, 1002, false},
        {kRob, 1009, "JointLinearMoveSkillType", kRob, 1003, false},
        {kRob, 1010, "CartesianLinearForceMoveSkillType", kRob, 1007, false},
        {kRob, 1011, "PositionStreamSkillType", kBase, 1001, false},
        {kRob, 1012, "SkillMotionDeviceType", kRobotics, 1004, false},
        {kTool, 1001, "DetachToolSkillType", kBase, 1001, false},
        {kTool, 1002, "AttachToolSkillType", kBase, 1001, false},
        {kTool, 1003, "ChangeToolSkillType", kBase, 1001, false},
        {kComp, 1001, "PickAndPlaceSkillType", kBase, 1001, false},
        {kComp, 1002, "ExecuteProcessSkillType", kBase, 1001, false},
        {kDemo, 1001, "DelaySkillType", kBase, 1001, false},
    };
    for (const auto& t : types) {
        SCOPED_TRACE(t.name);
        const NodeId id(m.ns(t.uri), t.id);
        ASSERT_TRUE(m.space.contains(id));
        EXPECT_EQ(m.attr(id, AttributeId::BrowseName), Variant(QualifiedName{m.ns(t.uri), t.name}));
        const NodeId super(t.superUri.empty() ? UInt16{0} : m.ns(t.superUri), t.superId);
        EXPECT_TRUE(m.space.isSubtypeOf(id, super));
        // the direct supertype
        ContinuationPointStore points;
        BrowseDescription d;
        d.nodeId = id;
        d.browseDirection = BrowseDirection::Inverse;
        d.referenceTypeId = NodeId(0, ns0::HasSubtype);
        d.resultMask = 63;
        auto refs = m.space.browse(d, 0, points).references;
        ASSERT_EQ(refs.size(), 1u);
        EXPECT_EQ(refs[0].nodeId.nodeId, super);
        EXPECT_EQ(m.attr(id, AttributeId::IsAbstract), Variant(Boolean(t.isAbstract)));
    }
    // Every skill type is a SkillType; the interfaces of the concrete move skills.
    EXPECT_TRUE(m.space.isSubtypeOf(NodeId(m.rob, 1010), NodeId(m.base, 1001)));
    auto ifs = forward(m.space, NodeId(m.rob, 1007), ns0::HasInterface);
    ASSERT_EQ(ifs.size(), 1u);
    EXPECT_EQ(ifs[0].nodeId.nodeId, NodeId(m.rob, 1004));
    ifs = forward(m.space, NodeId(m.rob, 1009), ns0::HasInterface);
    ASSERT_EQ(ifs.size(), 1u);
    EXPECT_EQ(ifs[0].nodeId.nodeId, NodeId(m.rob, 1005));
    ifs = forward(m.space, NodeId(m.rob, 1012), ns0::HasInterface);
    ASSERT_EQ(ifs.size(), 1u);
    EXPECT_EQ(ifs[0].nodeId.nodeId, NodeId(m.base, 1002));
    // The enumerations carry EnumStrings.
    auto es = m.child(NodeId(m.base, 3001), {{0, "EnumStrings"}});
    ASSERT_TRUE(es);
    const DataValue esValue = m.space.readValue(*es);
    ASSERT_TRUE(esValue.value);
    const auto* strings = esValue.value->array<LocalizedText>();
    ASSERT_TRUE(strings);
    ASSERT_EQ(strings->size(), 4u);
    EXPECT_EQ((*strings)[0].text, "None");
    EXPECT_EQ((*strings)[3].text, "Aborted");
    EXPECT_TRUE(m.child(NodeId(m.base, 3002), {{0, "EnumStrings"}}));
}

struct Param {
    std::string uri;  // the BrowseName's namespace
    std::string name;
    UInt32 dataType;  // ns0
    Int32 valueRank = -1;
    Byte accessLevel = 3;
    std::vector<UInt32> arrayDimensions = {};
    bool optional = false;
};

struct SkillSpec {
    std::string uri;
    UInt32 id;
    std::vector<Param> params;
    bool cartesianResult = false;
};

std::vector<SkillSpec> concreteSkills() {
    const UInt32 d = ns0::Double, s = ns0::String, f = ns0::ThreeDFrame;
    const Param toolFrame{kRob, "ToolFrame", s};
    const Param ptpVel{kRob, "MaxVelocity", d, 1}, ptpAcc{kRob, "MaxAcceleration", d, 1};
    const Param linVel{kRob, "MaxVelocity", d, 1, 3, {6}};
    const Param linAcc{kRob, "MaxAcceleration", d, 1, 3, {6}};
    const Param target{kRob, "TargetPosition", f}, bounds{kRob, "AxisBounds", ns0::Range, 1};
    const Param joints{kRob, "TargetJointPosition", d, 1};
    const Param moveEndpoint{kTool, "MoveSkillControllerEndpoint", s, -1, 1};
    return {
        {kBase, 1011, {{kBase, "Force", d, -1, 3, {}, true}}},
        {kBase, 1012, {{kBase, "Force", d, -1, 3, {}, true}}},
        {kBase, 1013, {{kBase, "Width", d}, {kBase, "Force", d}}},
        {kRob, 1006, {toolFrame, ptpVel, ptpAcc, target, bounds}, true},
        {kRob, 1007, {toolFrame, linVel, linAcc, target, bounds}, true},
        {kRob, 1008, {toolFrame, ptpVel, ptpAcc, joints}},
        {kRob, 1009, {toolFrame, linVel, linAcc, joints}},
        {kRob,
         1010,
         {toolFrame, linVel, linAcc, target, bounds, {kRob, "MaxForce", ns0::ThreeDVector}},
         true},
        {kRob, 1011, {joints}},
        {kTool, 1001, {{kTool, "ToolPosition", f}, moveEndpoint}},
        {kTool, 1002, {{kTool, "ToolPosition", f}, {kTool, "ToolAppUri", s}, moveEndpoint}},
        {kTool, 1003, {{kTool, "ToolPosition", f}, {kTool, "ToolAppUri", s}, moveEndpoint}},
        {kComp,
         1001,
         {{kComp, "ObjectId", s},
          {kComp, "ToolSkillControllerEndpoint", s},
          {kComp, "MoveSkillControllerEndpoint", s},
          {kComp, "PlacePosition", f},
          {kComp, "SkillStep", s, -1, 1}}},
        {kComp, 1002, {{kComp, "ProcessIri", s}}},
        {kDemo, 1001, {{kDemo, "DurationMs", d}, {kDemo, "FailWith", s, -1, 3, {}, true}}},
    };
}

TEST(SkillModels, InstantiatedSkillsHaveTheContractedStructure) {
    Models m;
    UInt32 n = 0;
    for (const auto& spec : concreteSkills()) {
        const NodeId type(m.ns(spec.uri), spec.id);
        SCOPED_TRACE(m.attr(type, AttributeId::BrowseName).toString());
        InstantiateOptions o;
        for (const auto& p : spec.params)
            if (p.optional) o.optionalChildren.push_back({m.ns(p.uri), p.name});
        const std::string skillName = "Skill" + std::to_string(++n);
        const NodeId skill = m.space.instantiate(NodeId(0, ns0::ObjectsFolder), type,
                                                 NodeId(1, skillName), {1, skillName}, o);
        auto td = forward(m.space, skill, ns0::HasTypeDefinition);
        ASSERT_EQ(td.size(), 1u);
        EXPECT_EQ(td[0].nodeId.nodeId, type);
        // ProgramStateMachineType and SkillType
        for (const char* c : {"CurrentState", "LastTransition", "Start", "Suspend", "Resume",
                              "Halt", "Reset", "MaxInstanceCount", "FinalResultData"})
            EXPECT_TRUE(m.child(skill, {{0, c}})) << c;
        for (const char* c : {"Start", "Suspend", "Resume", "Halt", "Reset"})
            EXPECT_EQ(m.space.nodeClass(*m.child(skill, {{0, c}})), NodeClass::Method) << c;
        auto name = m.child(skill, {{m.base, "Name"}});
        ASSERT_TRUE(name);
        EXPECT_EQ(m.attr(*name, AttributeId::DataType), Variant(NodeId(0, ns0::String)));
        // DI Lock with its methods
        auto lock = m.child(skill, {{m.di, "Lock"}});
        ASSERT_TRUE(lock);
        for (const char* c : {"InitLock", "ExitLock", "RenewLock", "BreakLock"})
            EXPECT_TRUE(m.child(*lock, {{m.di, c}})) << c;
        EXPECT_TRUE(m.child(*lock, {{m.di, "InitLock"}, {0, "InputArguments"}}));
        // FinalResultData
        auto result = m.child(skill, {{0, "FinalResultData"}, {m.base, "Result"}});
        ASSERT_TRUE(result);
        EXPECT_EQ(m.attr(*result, AttributeId::DataType), Variant(NodeId(m.base, 3001)));
        EXPECT_EQ(m.attr(*result, AttributeId::AccessLevel), Variant(Byte(1)));
        auto message = m.child(skill, {{0, "FinalResultData"}, {m.base, "Message"}});
        ASSERT_TRUE(message);
        EXPECT_EQ(m.attr(*message, AttributeId::DataType), Variant(NodeId(0, ns0::String)));
        auto exceeded = m.child(skill, {{0, "FinalResultData"}, {m.rob, "ForcesExceeded"}});
        auto forcesMax = m.child(skill, {{0, "FinalResultData"}, {m.rob, "ForcesMax"}});
        EXPECT_EQ(bool(exceeded), spec.cartesianResult);
        EXPECT_EQ(bool(forcesMax), spec.cartesianResult);
        if (spec.cartesianResult && exceeded && forcesMax) {
            EXPECT_EQ(m.attr(*exceeded, AttributeId::DataType), Variant(NodeId(0, ns0::Boolean)));
            EXPECT_EQ(m.attr(*forcesMax, AttributeId::DataType),
                      Variant(NodeId(0, ns0::ThreeDVector)));
            EXPECT_EQ(m.attr(*forcesMax, AttributeId::AccessLevel), Variant(Byte(1)));
        }
        // DI ParameterSet: exactly the parameters of the contract
        auto ps = m.child(skill, {{m.di, "ParameterSet"}});
        ASSERT_TRUE(ps);
        EXPECT_EQ(forward(m.space, *ps, ns0::HasComponent).size(), spec.params.size());
        for (const auto& p : spec.params) {
            SCOPED_TRACE(p.name);
            auto v = m.child(*ps, {{m.ns(p.uri), p.name}});
            ASSERT_TRUE(v);
            EXPECT_EQ(m.space.nodeClass(*v), NodeClass::Variable);
            EXPECT_EQ(m.attr(*v, AttributeId::DataType), Variant(NodeId(0, p.dataType)));
            EXPECT_EQ(m.attr(*v, AttributeId::ValueRank), Variant(Int32(p.valueRank)));
            EXPECT_EQ(m.attr(*v, AttributeId::AccessLevel), Variant(Byte(p.accessLevel)));
            const Variant dims = m.attr(*v, AttributeId::ArrayDimensions);
            const auto* a = dims.array<UInt32>();
            if (p.arrayDimensions.empty())
                EXPECT_TRUE(dims.isEmpty() || (a != nullptr && a->empty())) << dims.toString();
            else
                EXPECT_TRUE(a != nullptr && *a == p.arrayDimensions) << dims.toString();
            auto vtd = forward(m.space, *v, ns0::HasTypeDefinition);
            ASSERT_EQ(vtd.size(), 1u);
            EXPECT_EQ(vtd[0].nodeId.nodeId, NodeId(0, ns0::BaseDataVariableType));
        }
    }
}

TEST(SkillModels, OptionalParametersOnlyOnRequest) {
    Models m;
    NodeId s = m.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(m.demo, 1001),
                                   NodeId(1, "Delay"), {1, "Delay"});
    EXPECT_TRUE(m.child(s, {{m.di, "ParameterSet"}, {m.demo, "DurationMs"}}));
    EXPECT_FALSE(m.child(s, {{m.di, "ParameterSet"}, {m.demo, "FailWith"}}));
    NodeId g = m.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(m.base, 1011),
                                   NodeId(1, "Grasp"), {1, "Grasp"});
    EXPECT_TRUE(m.child(g, {{m.di, "ParameterSet"}}));
    EXPECT_FALSE(m.child(g, {{m.di, "ParameterSet"}, {m.base, "Force"}}));
}

TEST(SkillModels, AbstractSkillTypesCannotBeInstantiated) {
    Models m;
    for (const NodeId& t : {NodeId(m.base, 1001), NodeId(m.base, 1010), NodeId(m.rob, 1001),
                            NodeId(m.rob, 1002), NodeId(m.rob, 1003)})
        EXPECT_THROW(
            m.space.instantiate(NodeId(0, ns0::ObjectsFolder), t, NodeId(1, "X"), {1, "X"}),
            AddressSpaceError)
            << t.toString();
}

TEST(SkillModels, SkillControllerInterfaceGivesSkillsAndName) {
    Models m;
    // A device type of the application implementing ISkillControllerType ...
    NodeId type = m.space.addObjectType(NodeId(0, ns0::BaseObjectType), NodeId(1, "CellType"),
                                        {1, "CellType"});
    m.space.addReference(type, NodeId(0, ns0::HasInterface), NodeId(m.base, 1002));
    NodeId cell =
        m.space.instantiate(NodeId(0, ns0::ObjectsFolder), type, NodeId(1, "Cell"), {1, "Cell"});
    auto name = m.child(cell, {{m.base, "Name"}});
    ASSERT_TRUE(name);
    EXPECT_EQ(m.attr(*name, AttributeId::DataType), Variant(NodeId(0, ns0::LocalizedText)));
    auto skills = m.child(cell, {{m.base, "Skills"}});
    ASSERT_TRUE(skills);
    auto folderTd = forward(m.space, *skills, ns0::HasTypeDefinition);
    ASSERT_EQ(folderTd.size(), 1u);
    EXPECT_EQ(folderTd[0].nodeId.nodeId, NodeId(0, ns0::FolderType));
    EXPECT_FALSE(m.child(*skills, {{m.base, "Skill_<No>"}}));
    // ... and the placeholder in the interface.
    auto placeholder = m.child(NodeId(m.base, 1002), {{m.base, "Skills"}, {m.base, "Skill_<No>"}});
    ASSERT_TRUE(placeholder);
    auto rule = forward(m.space, *placeholder, ns0::HasModellingRule);
    ASSERT_EQ(rule.size(), 1u);
    EXPECT_EQ(rule[0].nodeId.nodeId, NodeId(0, 11508));

    // SkillMotionDeviceType: a Robotics MotionDevice that is a skill controller.
    const UInt16 robotics = m.ns(kRobotics);
    NodeId arm = m.space.instantiate(NodeId(0, ns0::ObjectsFolder), NodeId(m.rob, 1012),
                                     NodeId(1, "Arm"), {1, "Arm"});
    EXPECT_TRUE(m.child(arm, {{m.base, "Name"}}));
    EXPECT_TRUE(m.child(arm, {{m.base, "Skills"}}));
    EXPECT_TRUE(m.child(arm, {{robotics, "Axes"}}));
    auto world = m.child(arm, {{m.rob, "WorldToRobotBase"}});
    ASSERT_TRUE(world);
    EXPECT_EQ(m.attr(*world, AttributeId::DataType), Variant(NodeId(0, ns0::ThreeDFrame)));
    EXPECT_FALSE(m.child(arm, {{m.rob, "SetTool"}}));  // Optional
    auto setTool = m.child(NodeId(m.rob, 1012), {{m.rob, "SetTool"}, {0, "InputArguments"}});
    ASSERT_TRUE(setTool);
    const DataValue argsValue = m.space.readValue(*setTool);
    ASSERT_TRUE(argsValue.value);
    const auto* args = argsValue.value->array<ExtensionObject>();
    ASSERT_TRUE(args);
    EXPECT_EQ(args->size(), 2u);
}

TEST(SkillModels, GripperAndPowerOffInterfaces) {
    Models m;
    NodeId type = m.space.addObjectType(NodeId(0, ns0::BaseObjectType), NodeId(1, "GripperType"),
                                        {1, "GripperType"});
    m.space.addReference(type, NodeId(0, ns0::HasInterface), NodeId(m.base, 1020));
    m.space.addReference(type, NodeId(0, ns0::HasInterface), NodeId(m.base, 1030));
    NodeId g = m.space.instantiate(NodeId(0, ns0::ObjectsFolder), type, NodeId(1, "Gripper"),
                                   {1, "Gripper"});
    auto points = m.child(g, {{m.base, "GripPoints"}});
    ASSERT_TRUE(points);
    auto power = m.child(g, {{m.base, "PowerOffDevice"}});
    ASSERT_TRUE(power);
    EXPECT_TRUE(m.child(*power, {{0, "InputArguments"}}));
    NodeId p =
        m.space.instantiate(*points, NodeId(m.base, 1022), NodeId(1, "GP1"), {1, "GripPoint_1"});
    auto kind = m.child(p, {{m.base, "Type"}});
    ASSERT_TRUE(kind);
    EXPECT_EQ(m.attr(*kind, AttributeId::DataType), Variant(NodeId(m.base, 3002)));
    auto offset = m.child(p, {{m.base, "Offset"}});
    ASSERT_TRUE(offset);
    EXPECT_EQ(m.attr(*offset, AttributeId::DataType), Variant(NodeId(0, ns0::ThreeDFrame)));
    auto span = m.child(p, {{m.base, "Span"}});
    ASSERT_TRUE(span);
    EXPECT_EQ(m.attr(*span, AttributeId::DataType), Variant(NodeId(0, ns0::Range)));
}

}  // namespace
}  // namespace pnp::ua::server
