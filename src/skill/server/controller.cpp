#include "skill/server/controller.hpp"

#include <algorithm>

#include "skill/server/runtime.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::skill::server {

using ua::NodeId;
using ua::QualifiedName;
namespace ns0 = ua::ns0;

// ---- SkillHandle --------------------------------------------------------------------------
const NodeId& SkillHandle::node() const { return runtime_->nodes().node; }
ProgramState SkillHandle::state() const { return runtime_->state(); }
bool SkillHandle::locked() const { return runtime_->locked(); }
std::uint64_t SkillHandle::runs() const { return runtime_->runs(); }

namespace {

struct Child {
    NodeId node;
    QualifiedName browseName;
};

// The local targets of a node's references of one type (and subtypes), through Browse.
std::vector<Child> referenced(const ua::server::AddressSpace& space, const NodeId& node,
                              ua::UInt32 referenceType,
                              ua::BrowseDirection direction = ua::BrowseDirection::Forward,
                              bool includeSubtypes = true) {
    ua::server::ContinuationPointStore points(1);
    ua::BrowseDescription d;
    d.nodeId = node;
    d.browseDirection = direction;
    d.referenceTypeId = NodeId(0, referenceType);
    d.includeSubtypes = includeSubtypes;
    d.resultMask = 0x3F;
    ua::BrowseResult r = space.browse(d, 0, points);
    std::vector<Child> out;
    for (const auto& ref : r.references)
        if (ref.nodeId.serverIndex == 0 && ref.nodeId.namespaceUri.empty())
            out.push_back({ref.nodeId.nodeId, ref.browseName});
    return out;
}

std::vector<Child> childrenOf(const ua::server::AddressSpace& space, const NodeId& node) {
    return referenced(space, node, ns0::HierarchicalReferences);
}

NodeId childByName(const ua::server::AddressSpace& space, const NodeId& node,
                   std::string_view name) {
    for (const Child& c : childrenOf(space, node))
        if (c.browseName.name == name) return c.node;
    return {};
}

std::string valueRankText(ua::Int32 r) {
    return r == -1 ? "scalar" : r == 1 ? "one-dimensional array" : "ValueRank " + std::to_string(r);
}

bool valueRankFits(ua::Int32 declared, ua::Int32 actual) {
    if (declared == actual) return true;
    if (actual == -2) return true;                             // Any
    if (actual == -3) return declared == -1 || declared == 1;  // ScalarOrOneDimension
    return false;
}

}  // namespace

// ---- SkillController ---------------------------------------------------------------------
SkillController::SkillController(ua::server::Server& server, SkillControllerOptions options)
    : server_(server), options_(std::move(options)) {
    auto& space = server_.addressSpace();
    if (options_.name.empty()) throw SkillError("a skill controller needs a name");
    const NodeId iface = resolve(space, types::ISkillControllerType);
    const ua::UInt16 base = iface.namespaceIndex();

    NodeId parent = options_.parent;
    if (parent.isNull()) {
        parent = NodeId(0, ns0::ObjectsFolder);
        if (auto di = space.namespaceIndex(kDiUri); di && space.contains(NodeId(*di, 5001)))
            parent = NodeId(*di, 5001);  // DI DeviceSet
    }
    const NodeId type =
        options_.type.uri.empty() ? NodeId(0, ns0::BaseObjectType) : resolve(space, options_.type);
    const NodeId id =
        options_.id.isNull() ? NodeId(options_.namespaceIndex, options_.name) : options_.id;
    ua::server::ObjectAttributes attributes;
    attributes.eventNotifier = 1;  // SubscribeToEvents: the skills' events come through it
    try {
        node_ = space.addObject(parent, id, QualifiedName(options_.namespaceIndex, options_.name),
                                attributes, type);
    } catch (const ua::server::AddressSpaceError& e) {
        throw SkillError("skill controller " + options_.name + ": " + e.what());
    }
    // The interface, unless the type implements it already (e.g. SkillMotionDeviceType).
    bool implements = false;
    for (NodeId t = type; !t.isNull() && !implements;) {
        for (const Child& i : referenced(space, t, ns0::HasInterface))
            if (i.node == iface) implements = true;
        auto up = referenced(space, t, ns0::HasSubtype, ua::BrowseDirection::Inverse, false);
        t = up.empty() ? NodeId() : up.front().node;
    }
    if (!implements) space.addReference(node_, NodeId(0, ns0::HasInterface), iface);

    NodeId name = childByName(space, node_, "Name");
    if (name.isNull()) {
        ua::server::VariableAttributes a;
        a.dataType = NodeId(0, ns0::LocalizedText);
        name = space.addProperty(node_, NodeId(options_.namespaceIndex, ua::UInt32{0}),
                                 QualifiedName(base, "Name"), a);
    }
    space.setValue(name, ua::DataValue(ua::Variant(ua::LocalizedText("", options_.name))));
    skills_ = childByName(space, node_, names::Skills);
    if (skills_.isNull())
        skills_ = space.addObject(node_, NodeId(options_.namespaceIndex, ua::UInt32{0}),
                                  QualifiedName(base, std::string(names::Skills)), {},
                                  NodeId(0, ns0::FolderType), NodeId(0, ns0::HasComponent));
}

SkillController::~SkillController() {
    for (auto& r : runtimes_) r->shutdown();
}

std::vector<SkillHandle> SkillController::skills() const {
    std::vector<SkillHandle> out;
    for (const auto& r : runtimes_) out.emplace_back(r);
    return out;
}

SkillHandle SkillController::add(const std::string& name, std::shared_ptr<Skill> skill) {
    if (!skill) throw SkillError("skill " + name + ": no implementation");
    auto& space = server_.addressSpace();
    const std::string what = "skill " + name + " (" + std::string(skill->type().name) + ")";
    const NodeId type = resolve(space, skill->type());
    const NodeId skillType = resolve(space, types::SkillType);
    if (!space.isSubtypeOf(type, skillType))
        throw SkillError(what + ": the type is not a SkillType");
    const auto di = space.namespaceIndex(kDiUri);
    if (!di) throw SkillError(what + ": the DI model is not loaded");

    // Optional parameters the C++ skill declares are created on the instance; their BrowseName
    // is in the namespace of whichever model declares them.
    ua::server::InstantiateOptions options;
    options.displayName = ua::LocalizedText("", name);
    options.referenceType = NodeId(0, ns0::HasComponent);
    options.eventNotifier = 1;
    std::vector<ua::UInt16> modelNamespaces;
    for (std::string_view uri : {kBaseUri, kRoboticsUri, kToolChangerUri, kCompositeUri, kDemoUri})
        if (auto ns = space.namespaceIndex(uri)) modelNamespaces.push_back(*ns);
    for (const auto& p : skill->parameters())
        if (p.optional)
            for (ua::UInt16 ns : modelNamespaces) options.optionalChildren.emplace_back(ns, p.name);

    const std::string idText =
        (node_.idType() == ua::IdType::String ? node_.string() : options_.name) + "." + name;
    SkillNodes nodes;
    try {
        nodes.node = space.instantiate(skills_, type, NodeId(options_.namespaceIndex, idText),
                                       QualifiedName(options_.namespaceIndex, name), options);
    } catch (const ua::server::AddressSpaceError& e) {
        throw SkillError(what + ": " + e.what());
    }
    space.addReference(node_, NodeId(0, ns0::HasNotifier), nodes.node);
    auto fail = [&](const std::string& problem) {
        space.deleteNode(nodes.node);
        throw SkillError(what + ": " + problem);
    };

    // The declared parameters against the type's ParameterSet.
    const NodeId parameterSet = childByName(space, nodes.node, names::ParameterSet);
    if (parameterSet.isNull()) fail("no ParameterSet");
    const auto present = childrenOf(space, parameterSet);
    for (const auto& p : skill->parameters()) {
        auto it = std::find_if(present.begin(), present.end(),
                               [&](const Child& c) { return c.browseName.name == p.name; });
        if (it == present.end())
            fail("parameter " + p.name + " is not in the ParameterSet of " +
                 std::string(skill->type().name));
        const ua::DataValue dt = space.readAttribute(it->node, ua::AttributeId::DataType);
        const ua::DataValue vr = space.readAttribute(it->node, ua::AttributeId::ValueRank);
        const NodeId* actualType = dt.value ? dt.value->scalar<NodeId>() : nullptr;
        const ua::Int32* actualRank = vr.value ? vr.value->scalar<ua::Int32>() : nullptr;
        if (actualType == nullptr || *actualType != p.dataType)
            fail("parameter " + p.name + " is declared as " + p.dataType.toString() +
                 " in C++ but has the DataType " +
                 (actualType ? actualType->toString() : std::string("?")) + " in the model");
        if (actualRank == nullptr || !valueRankFits(p.valueRank, *actualRank))
            fail("parameter " + p.name + " is declared as a " + valueRankText(p.valueRank) +
                 " in C++ but is a " + valueRankText(actualRank ? *actualRank : -99) +
                 " in the model");
        const ua::DataValue current = space.readValue(it->node);
        if ((!current.value || current.value->isEmpty()) && !p.defaultValue.isEmpty())
            space.setValue(it->node, ua::DataValue(p.defaultValue));
        nodes.parameters.push_back(it->node);
    }
    nodes.skillStep = childByName(space, parameterSet, names::SkillStep);
    nodes.lock = childByName(space, nodes.node, names::Lock);
    if (nodes.lock.isNull()) fail("no DI Lock");
    const NodeId finalResult = childByName(space, nodes.node, names::FinalResultData);
    if (!finalResult.isNull())
        for (const Child& c : childrenOf(space, finalResult)) {
            if (c.browseName.name == names::Result)
                nodes.result = c.node;
            else if (c.browseName.name == names::Message)
                nodes.message = c.node;
            else
                nodes.results[c.browseName.name] = c.node;
        }
    if (NodeId n = childByName(space, nodes.node, "Name"); !n.isNull())
        space.setValue(n, ua::DataValue(ua::Variant(ua::String(name))));
    if (NodeId n = childByName(space, nodes.node, "MaxInstanceCount"); !n.isNull())
        space.setValue(n, ua::DataValue(ua::Variant(ua::UInt32{1})));
    nodes.eventType = resolve(space, types::SkillTransitionEventType);

    std::shared_ptr<SkillRuntime> runtime;
    try {
        runtime = std::make_shared<SkillRuntime>(server_, std::move(skill), nodes,
                                                 options_.maxInactiveLockTime);
        runtime->bind();
    } catch (const std::exception& e) {
        fail(e.what());
    }
    runtimes_.push_back(runtime);
    return SkillHandle(runtime);
}

}  // namespace pnp::skill::server
