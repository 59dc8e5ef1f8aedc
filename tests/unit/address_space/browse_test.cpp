// Browse, BrowseNext and TranslateBrowsePathsToNodeIds (OPC 10000-4 §5.8).
#include "test_util.hpp"
#include "ua/types/ns0_ids_methods.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server::test {
namespace {

using Browse = AddressSpaceFixture;

const ReferenceDescription* findRef(const BrowseResult& r, const NodeId& id) {
    for (const auto& ref : r.references)
        if (ref.nodeId.nodeId == id) return &ref;
    return nullptr;
}

TEST_F(Browse, ObjectsFolderListsServer) {
    ContinuationPointStore points;
    auto r = space.browse(browseDesc(ns0(ns0::ObjectsFolder), BrowseDirection::Forward,
                                     ns0(ns0::HierarchicalReferences), true),
                          0, points);
    ASSERT_TRUE(r.statusCode.isGood());
    const auto* server = findRef(r, ns0(ns0::Server));
    ASSERT_NE(server, nullptr);
    EXPECT_EQ(server->referenceTypeId, ns0(ns0::Organizes));
    EXPECT_TRUE(server->isForward);
    EXPECT_EQ(server->browseName, (QualifiedName{0, "Server"}));
    EXPECT_EQ(server->displayName.text, "Server");
    EXPECT_EQ(server->nodeClass, NodeClass::Object);
    EXPECT_EQ(server->typeDefinition.nodeId, ns0(ns0::ServerType));
    EXPECT_TRUE(r.continuationPoint.empty());
}

TEST_F(Browse, InverseAndBoth) {
    ContinuationPointStore points;
    auto inv = space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Inverse), 0, points);
    ASSERT_EQ(inv.references.size(), 1u);
    EXPECT_EQ(inv.references[0].nodeId.nodeId, ns0(ns0::ObjectsFolder));
    EXPECT_FALSE(inv.references[0].isForward);
    EXPECT_EQ(inv.references[0].referenceTypeId, ns0(ns0::Organizes));
    EXPECT_TRUE(inv.references[0].typeDefinition.nodeId == ns0(ns0::FolderType));
    auto fwd = space.browse(browseDesc(ns0(ns0::Server)), 0, points);
    auto both = space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Both), 0, points);
    EXPECT_EQ(both.references.size(), fwd.references.size() + inv.references.size());
    // A null referenceTypeId means all references.
    auto all =
        space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Both, NodeId()), 0, points);
    EXPECT_EQ(all.references.size(), both.references.size());
}

TEST_F(Browse, ReferenceTypeSubtypes) {
    ContinuationPointStore points;
    auto hier = space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Forward,
                                        ns0(ns0::HierarchicalReferences), true),
                             0, points);
    // Hierarchical includes HasComponent (ServerStatus) and HasProperty (NamespaceArray) but
    // not HasTypeDefinition.
    EXPECT_TRUE(hasTarget(hier, ns0(ns0::Server_ServerStatus)));
    EXPECT_TRUE(hasTarget(hier, ns0(ns0::Server_NamespaceArray)));
    EXPECT_FALSE(hasTarget(hier, ns0(ns0::ServerType)));
    for (const auto& ref : hier.references)
        EXPECT_TRUE(space.isSubtypeOf(ref.referenceTypeId, ns0(ns0::HierarchicalReferences)));
    auto exact = space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Forward,
                                         ns0(ns0::HierarchicalReferences), false),
                              0, points);
    EXPECT_TRUE(exact.statusCode.isGood());
    EXPECT_TRUE(exact.references.empty());
    auto props = space.browse(
        browseDesc(ns0(ns0::Server), BrowseDirection::Forward, ns0(ns0::HasProperty), false), 0,
        points);
    EXPECT_FALSE(props.references.empty());
    for (const auto& ref : props.references) {
        EXPECT_EQ(ref.referenceTypeId, ns0(ns0::HasProperty));
        EXPECT_EQ(ref.nodeClass, NodeClass::Variable);
        EXPECT_EQ(ref.typeDefinition.nodeId, ns0(ns0::PropertyType));
    }
    auto typeDef = space.browse(
        browseDesc(ns0(ns0::Server), BrowseDirection::Forward, ns0(ns0::HasTypeDefinition)), 0,
        points);
    ASSERT_EQ(typeDef.references.size(), 1u);
    EXPECT_EQ(typeDef.references[0].nodeClass, NodeClass::ObjectType);
    EXPECT_TRUE(typeDef.references[0].typeDefinition.nodeId.isNull());  // only Objects/Variables
}

TEST_F(Browse, NodeClassMask) {
    ContinuationPointStore points;
    auto vars =
        space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Forward, ns0(ns0::References),
                                true, static_cast<UInt32>(NodeClass::Variable)),
                     0, points);
    ASSERT_FALSE(vars.references.empty());
    for (const auto& ref : vars.references) EXPECT_EQ(ref.nodeClass, NodeClass::Variable);
    auto methods =
        space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Forward, ns0(ns0::References),
                                true, static_cast<UInt32>(NodeClass::Method)),
                     0, points);
    EXPECT_TRUE(hasTarget(methods, ns0(ns0::Server_GetMonitoredItems)));
    for (const auto& ref : methods.references) EXPECT_EQ(ref.nodeClass, NodeClass::Method);
    auto mixed = space.browse(
        browseDesc(ns0(ns0::Server), BrowseDirection::Forward, ns0(ns0::References), true,
                   static_cast<UInt32>(NodeClass::Method) | static_cast<UInt32>(NodeClass::Object)),
        0, points);
    for (const auto& ref : mixed.references)
        EXPECT_TRUE(ref.nodeClass == NodeClass::Method || ref.nodeClass == NodeClass::Object ||
                    ref.nodeClass == NodeClass::ObjectType)
            << ref.nodeId.toString();
    EXPECT_FALSE(hasTarget(mixed, ns0(ns0::Server_ServerStatus)));
}

TEST_F(Browse, ResultMask) {
    ContinuationPointStore points;
    auto none = space.browse(browseDesc(ns0(ns0::ObjectsFolder), BrowseDirection::Forward,
                                        ns0(ns0::Organizes), true, 0, 0),
                             0, points);
    const auto* s = findRef(none, ns0(ns0::Server));
    ASSERT_NE(s, nullptr);
    EXPECT_TRUE(s->referenceTypeId.isNull());
    EXPECT_FALSE(s->isForward);
    EXPECT_TRUE(s->browseName.name.empty());
    EXPECT_TRUE(s->displayName.text.empty());
    EXPECT_EQ(s->nodeClass, NodeClass::Unspecified);
    EXPECT_TRUE(s->typeDefinition.nodeId.isNull());
    auto names = space.browse(browseDesc(ns0(ns0::ObjectsFolder), BrowseDirection::Forward,
                                         ns0(ns0::Organizes), true, 0, 8 | 2),
                              0, points);
    s = findRef(names, ns0(ns0::Server));
    ASSERT_NE(s, nullptr);
    EXPECT_EQ(s->browseName.name, "Server");
    EXPECT_TRUE(s->isForward);
    EXPECT_TRUE(s->displayName.text.empty());
    EXPECT_TRUE(s->referenceTypeId.isNull());
}

TEST_F(Browse, Errors) {
    ContinuationPointStore points;
    EXPECT_EQ(space.browse(browseDesc(id("nope")), 0, points).statusCode, status::BadNodeIdUnknown);
    EXPECT_EQ(
        space
            .browse(browseDesc(ns0(ns0::Server), BrowseDirection::Forward, ns0(ns0::ObjectsFolder)),
                    0, points)
            .statusCode,
        status::BadReferenceTypeIdInvalid);
    EXPECT_EQ(
        space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Forward, id("nope")), 0, points)
            .statusCode,
        status::BadReferenceTypeIdInvalid);
    EXPECT_EQ(space.browse(browseDesc(ns0(ns0::Server), static_cast<BrowseDirection>(3)), 0, points)
                  .statusCode,
              status::BadBrowseDirectionInvalid);
    BrowseRequest empty;
    EXPECT_EQ(space.browse(empty, points).responseHeader.serviceResult, status::BadNothingToDo);
    BrowseRequest withView;
    withView.view.viewId = ns0(ns0::Server);
    withView.nodesToBrowse.push_back(browseDesc(ns0(ns0::Server)));
    EXPECT_EQ(space.browse(withView, points).responseHeader.serviceResult,
              status::BadViewIdUnknown);
    // A batch reports per node.
    BrowseRequest batch;
    batch.nodesToBrowse = {browseDesc(ns0(ns0::Server)), browseDesc(id("nope"))};
    auto resp = space.browse(batch, points);
    ASSERT_EQ(resp.results.size(), 2u);
    EXPECT_TRUE(resp.results[0].statusCode.isGood());
    EXPECT_EQ(resp.results[1].statusCode, status::BadNodeIdUnknown);
}

TEST_F(Browse, BrowseAView) {
    NodeId view = space.addView(ns0(ns0::ViewsFolder), id("CellView"), name("CellView"));
    ContinuationPointStore points;
    BrowseRequest req;
    req.view.viewId = view;
    req.nodesToBrowse.push_back(browseDesc(ns0(ns0::ViewsFolder)));
    auto resp = space.browse(req, points);
    ASSERT_TRUE(resp.responseHeader.serviceResult.isGood());
    ASSERT_EQ(resp.results.size(), 1u);
    EXPECT_TRUE(hasTarget(resp.results[0], view));
}

TEST_F(Browse, ContinuationPointsWalkAllReferences) {
    ContinuationPointStore points(4);
    auto full = space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Both), 0, points);
    ASSERT_GT(full.references.size(), 5u);
    BrowseRequest req;
    req.requestedMaxReferencesPerNode = 1;
    req.nodesToBrowse.push_back(browseDesc(ns0(ns0::Server), BrowseDirection::Both));
    auto resp = space.browse(req, points);
    ASSERT_EQ(resp.results.size(), 1u);
    std::vector<ReferenceDescription> collected = resp.results[0].references;
    ASSERT_EQ(collected.size(), 1u);
    ByteString cp = resp.results[0].continuationPoint;
    ASSERT_FALSE(cp.empty());
    EXPECT_EQ(points.size(), 1u);
    int rounds = 0;
    while (!cp.empty()) {
        BrowseNextRequest next;
        next.continuationPoints.push_back(cp);
        auto nr = space.browseNext(next, points);
        ASSERT_EQ(nr.results.size(), 1u);
        ASSERT_TRUE(nr.results[0].statusCode.isGood());
        ASSERT_EQ(nr.results[0].references.size(), 1u);
        collected.push_back(nr.results[0].references[0]);
        // The used continuation point is gone.
        BrowseNextRequest again;
        again.continuationPoints.push_back(cp);
        if (nr.results[0].continuationPoint != cp) {
            EXPECT_EQ(space.browseNext(again, points).results[0].statusCode,
                      status::BadContinuationPointInvalid);
        }
        cp = nr.results[0].continuationPoint;
        ASSERT_LT(++rounds, 1000);
    }
    EXPECT_EQ(points.size(), 0u);  // released at the end
    EXPECT_EQ(collected, full.references);
}

TEST_F(Browse, ContinuationPointLimitsAndRelease) {
    ContinuationPointStore points(1);
    BrowseRequest req;
    req.requestedMaxReferencesPerNode = 2;
    req.nodesToBrowse = {browseDesc(ns0(ns0::Server)), browseDesc(ns0(ns0::ServerType))};
    auto resp = space.browse(req, points);
    ASSERT_EQ(resp.results.size(), 2u);
    EXPECT_TRUE(resp.results[0].statusCode.isGood());
    EXPECT_EQ(resp.results[0].references.size(), 2u);
    EXPECT_FALSE(resp.results[0].continuationPoint.empty());
    EXPECT_EQ(resp.results[1].statusCode, status::BadNoContinuationPoints);
    EXPECT_TRUE(resp.results[1].references.empty());
    // Release frees the slot.
    BrowseNextRequest release;
    release.releaseContinuationPoints = true;
    release.continuationPoints.push_back(resp.results[0].continuationPoint);
    auto rel = space.browseNext(release, points);
    ASSERT_EQ(rel.results.size(), 1u);
    EXPECT_TRUE(rel.results[0].statusCode.isGood());
    EXPECT_TRUE(rel.results[0].references.empty());
    EXPECT_EQ(points.size(), 0u);
    // Released points are invalid; unknown ones too.
    EXPECT_EQ(space.browseNext(release, points).results[0].statusCode,
              status::BadContinuationPointInvalid);
    BrowseNextRequest bogus;
    bogus.continuationPoints.push_back(ByteString(std::string("xyz")));
    EXPECT_EQ(space.browseNext(bogus, points).results[0].statusCode,
              status::BadContinuationPointInvalid);
    EXPECT_EQ(space.browseNext(BrowseNextRequest{}, points).responseHeader.serviceResult,
              status::BadNothingToDo);
    // Exactly max references: no continuation point.
    ContinuationPointStore p2;
    auto inv = space.browse(browseDesc(ns0(ns0::Server), BrowseDirection::Inverse), 1, p2);
    EXPECT_EQ(inv.references.size(), 1u);
    EXPECT_TRUE(inv.continuationPoint.empty());
    EXPECT_EQ(p2.size(), 0u);
}

TEST_F(Browse, ServerLimitOnReferencesPerNode) {
    AddressSpace::Options o;
    o.maxReferencesPerNode = 3;
    AddressSpace limited(o);
    ContinuationPointStore points;
    auto r = limited.browse(browseDesc(ns0(ns0::Server)), 0, points);
    EXPECT_EQ(r.references.size(), 3u);
    EXPECT_FALSE(r.continuationPoint.empty());
}

// ---- TranslateBrowsePathsToNodeIds ----------------------------------------------------------
RelativePathElement element(const char* name, std::uint32_t refType = ns0::HierarchicalReferences,
                            bool inverse = false, bool subtypes = true, UInt16 ns = 0) {
    RelativePathElement e;
    e.referenceTypeId = NodeId(0, refType);
    e.isInverse = inverse;
    e.includeSubtypes = subtypes;
    e.targetName = QualifiedName{ns, name};
    return e;
}

BrowsePath path(const NodeId& start, std::vector<RelativePathElement> elements) {
    BrowsePath p;
    p.startingNode = start;
    p.relativePath.elements = std::move(elements);
    return p;
}

using Translate = AddressSpaceFixture;

TEST_F(Translate, ObjectsServerServerStatusState) {
    auto r = space.translateBrowsePath(
        path(ns0(ns0::RootFolder),
             {element("Objects"), element("Server"), element("ServerStatus"), element("State")}));
    ASSERT_TRUE(r.statusCode.isGood()) << r.statusCode.toString();
    ASSERT_EQ(r.targets.size(), 1u);
    EXPECT_EQ(r.targets[0].targetId.nodeId, ns0(ns0::Server_ServerStatus_State));
    EXPECT_EQ(r.targets[0].remainingPathIndex, 0xFFFFFFFFu);
    // With exact reference types: Organizes, Organizes, HasComponent, HasComponent.
    auto exact = space.translateBrowsePath(
        path(ns0(ns0::RootFolder), {element("Objects", ns0::Organizes, false, false),
                                    element("Server", ns0::Organizes, false, false),
                                    element("ServerStatus", ns0::HasComponent, false, false),
                                    element("State", ns0::HasComponent, false, false)}));
    ASSERT_TRUE(exact.statusCode.isGood());
    EXPECT_EQ(exact.targets[0].targetId.nodeId, ns0(ns0::Server_ServerStatus_State));
    // Aggregates ('.' in the text syntax) finds properties.
    auto prop = space.translateBrowsePath(
        path(ns0(ns0::Server), {element("NamespaceArray", ns0::Aggregates)}));
    ASSERT_TRUE(prop.statusCode.isGood());
    EXPECT_EQ(prop.targets[0].targetId.nodeId, ns0(ns0::Server_NamespaceArray));
}

TEST_F(Translate, InverseAndMultipleTargets) {
    auto up = space.translateBrowsePath(
        path(ns0(ns0::Server_ServerStatus_State), {element("ServerStatus", ns0::HasComponent, true),
                                                   element("Server", ns0::HasComponent, true)}));
    ASSERT_TRUE(up.statusCode.isGood());
    EXPECT_EQ(up.targets[0].targetId.nodeId, ns0(ns0::Server));
    // Two children with one BrowseName.
    NodeId a = space.addObject(ns0(ns0::ObjectsFolder), id("A"), name("A"));
    NodeId x1 = space.addObject(a, id("X1"), name("X"));
    NodeId x2 =
        space.addObject(a, id("X2"), name("X"), {}, ns0(ns0::BaseObjectType), ns0(ns0::Organizes));
    auto r = space.translateBrowsePath(path(
        ns0(ns0::ObjectsFolder), {element("A", ns0::HierarchicalReferences, false, true, ns),
                                  element("X", ns0::HierarchicalReferences, false, true, ns)}));
    ASSERT_TRUE(r.statusCode.isGood());
    ASSERT_EQ(r.targets.size(), 2u);
    EXPECT_TRUE((r.targets[0].targetId.nodeId == x1 && r.targets[1].targetId.nodeId == x2) ||
                (r.targets[0].targetId.nodeId == x2 && r.targets[1].targetId.nodeId == x1));
}

TEST_F(Translate, Errors) {
    auto noMatch = space.translateBrowsePath(
        path(ns0(ns0::RootFolder), {element("Objects"), element("NoSuchChild")}));
    EXPECT_EQ(noMatch.statusCode, status::BadNoMatch);
    EXPECT_TRUE(noMatch.targets.empty());
    // Namespace of the BrowseName matters.
    EXPECT_EQ(space
                  .translateBrowsePath(path(ns0(ns0::RootFolder),
                                            {element("Objects", ns0::Organizes, false, true, 1)}))
                  .statusCode,
              status::BadNoMatch);
    // Wrong reference type.
    EXPECT_EQ(space
                  .translateBrowsePath(path(ns0(ns0::RootFolder),
                                            {element("Objects", ns0::HasComponent, false, true)}))
                  .statusCode,
              status::BadNoMatch);
    EXPECT_EQ(space.translateBrowsePath(path(ns0(ns0::RootFolder), {element("")})).statusCode,
              status::BadBrowseNameInvalid);
    EXPECT_EQ(
        space.translateBrowsePath(path(ns0(ns0::RootFolder), {element(""), element("Server")}))
            .statusCode,
        status::BadBrowseNameInvalid);
    EXPECT_EQ(space.translateBrowsePath(path(ns0(ns0::RootFolder), {})).statusCode,
              status::BadNothingToDo);
    EXPECT_EQ(space.translateBrowsePath(path(id("nope"), {element("Objects")})).statusCode,
              status::BadNodeIdUnknown);
    EXPECT_EQ(space.translateBrowsePaths({}).responseHeader.serviceResult, status::BadNothingToDo);
    TranslateBrowsePathsToNodeIdsRequest req;
    req.browsePaths = {path(ns0(ns0::RootFolder), {element("Objects")}),
                       path(ns0(ns0::RootFolder), {element("Nope")})};
    auto resp = space.translateBrowsePaths(req);
    ASSERT_EQ(resp.results.size(), 2u);
    EXPECT_TRUE(resp.results[0].statusCode.isGood());
    EXPECT_EQ(resp.results[1].statusCode, status::BadNoMatch);
}

}  // namespace
}  // namespace pnp::ua::server::test
