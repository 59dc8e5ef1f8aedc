// View Service Set (OPC 10000-4 §5.8): Browse, BrowseNext, TranslateBrowsePathsToNodeIds.
#include <algorithm>

#include "ua/server/address_space_impl.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

namespace {

// BrowseResultMask bits (OPC 10000-4 §5.8.2.2).
constexpr UInt32 kMaskReferenceType = 1;
constexpr UInt32 kMaskIsForward = 2;
constexpr UInt32 kMaskNodeClass = 4;
constexpr UInt32 kMaskBrowseName = 8;
constexpr UInt32 kMaskDisplayName = 16;
constexpr UInt32 kMaskTypeDefinition = 32;

bool validDirection(BrowseDirection d) {
    auto v = static_cast<Int32>(d);
    return v >= 0 && v <= 2;
}

}  // namespace

bool AddressSpace::Impl::referenceMatches(const Ref& r, BrowseDirection dir, std::uint16_t type,
                                          bool includeSubtypes, UInt32 nodeClassMask) const {
    if (dir == BrowseDirection::Forward && !r.isForward()) return false;
    if (dir == BrowseDirection::Inverse && r.isForward()) return false;
    if (type != kNoRefType && !refTypeMatches(r.type, type, includeSubtypes)) return false;
    if (nodeClassMask != 0 && !r.isExternal() &&
        (nodeClassMask & static_cast<UInt32>(nodes[r.target].nodeClass)) == 0)
        return false;
    return true;
}

ReferenceDescription AddressSpace::Impl::describe(const Ref& r, UInt32 mask) const {
    ReferenceDescription d;
    d.nodeId = targetIdOf(r);
    if (mask & kMaskReferenceType) d.referenceTypeId = idOf(refTypes[r.type]);
    if (mask & kMaskIsForward) d.isForward = r.isForward();
    if (r.isExternal()) return d;
    const Node& t = nodes[r.target];
    if (mask & kMaskNodeClass) d.nodeClass = toNodeClass(t.nodeClass);
    if (mask & kMaskBrowseName) d.browseName = browseNameOf(t);
    if (mask & kMaskDisplayName) d.displayName = displayNameOf(t);
    if ((mask & kMaskTypeDefinition) &&
        (t.nodeClass == NodeClassBits::Object || t.nodeClass == NodeClassBits::Variable)) {
        NodeIndex td = typeDefinitionOf(r.target);
        if (td != kNoNode) d.typeDefinition = idOf(td);
    }
    return d;
}

namespace {

// Browses one node from reference position `start` (the lock is held).
// Whether the session may see node i (Browse permission); always for local calls.
bool visible(const AddressSpace::Impl& s, NodeIndex i, const SessionIdentity* user) {
    return !s.checksPermissions(user) || (s.userPermissions(i, user) & permission::Browse) != 0;
}

BrowseResult browseFrom(const AddressSpace::Impl& s, const BrowseDescription& desc,
                        UInt32 maxReferences, std::uint32_t start, bool& wantPoint,
                        std::uint32_t& resume, const SessionIdentity* user) {
    BrowseResult result;
    wantPoint = false;
    NodeIndex i = s.find(desc.nodeId);
    // A node the session may not browse does not exist for it (reveals nothing).
    if (i == kNoNode || !visible(s, i, user)) {
        result.statusCode = status::BadNodeIdUnknown;
        return result;
    }
    if (!validDirection(desc.browseDirection)) {
        result.statusCode = status::BadBrowseDirectionInvalid;
        return result;
    }
    std::uint16_t type = kNoRefType;
    if (!desc.referenceTypeId.isNull()) {
        type = s.refTypeIndexOf(s.find(desc.referenceTypeId));
        if (type == kNoRefType) {
            result.statusCode = status::BadReferenceTypeIdInvalid;
            return result;
        }
    }
    const RefList& refs = s.nodes[i].refs;
    const bool filter = s.checksPermissions(user);
    for (std::uint32_t pos = start; pos < refs.size(); ++pos) {
        const Ref& r = refs[pos];
        if (!s.referenceMatches(r, desc.browseDirection, type, desc.includeSubtypes,
                                desc.nodeClassMask))
            continue;
        if (filter && !r.isExternal() && !visible(s, r.target, user)) continue;
        if (maxReferences != 0 && result.references.size() == maxReferences) {
            wantPoint = true;
            resume = pos;
            return result;
        }
        if (result.references.empty())
            result.references.reserve(std::min<std::size_t>(
                maxReferences ? maxReferences : refs.size() - pos, refs.size() - pos));
        result.references.push_back(s.describe(r, desc.resultMask));
    }
    return result;
}

}  // namespace

BrowseResult AddressSpace::browse(const BrowseDescription& description, UInt32 maxReferences,
                                  ContinuationPointStore& points) const {
    BrowseRequest request;
    request.requestedMaxReferencesPerNode = maxReferences;
    request.nodesToBrowse.push_back(description);
    BrowseResponse response = browse(request, points);
    if (response.results.empty()) {
        BrowseResult r;
        r.statusCode = response.responseHeader.serviceResult;
        return r;
    }
    return std::move(response.results.front());
}

BrowseResponse AddressSpace::browse(const BrowseRequest& request, ContinuationPointStore& points,
                                    const SessionIdentity* user) const {
    BrowseResponse response;
    if (request.nodesToBrowse.empty()) {
        response.responseHeader.serviceResult = status::BadNothingToDo;
        return response;
    }
    std::shared_lock lock(impl_->mutex);
    const Impl& s = *impl_;
    if (!request.view.viewId.isNull()) {
        NodeIndex v = s.find(request.view.viewId);
        if (v == kNoNode || s.nodes[v].nodeClass != NodeClassBits::View) {
            response.responseHeader.serviceResult = status::BadViewIdUnknown;
            return response;
        }
    }
    UInt32 maxRefs = request.requestedMaxReferencesPerNode;
    if (s.options.maxReferencesPerNode != 0 &&
        (maxRefs == 0 || maxRefs > s.options.maxReferencesPerNode))
        maxRefs = s.options.maxReferencesPerNode;
    response.results.reserve(request.nodesToBrowse.size());
    for (const auto& desc : request.nodesToBrowse) {
        bool wantPoint = false;
        std::uint32_t resume = 0;
        BrowseResult r = browseFrom(s, desc, maxRefs, 0, wantPoint, resume, user);
        if (wantPoint) {
            if (points.full()) {
                r.references.clear();
                r.statusCode = status::BadNoContinuationPoints;
            } else {
                ContinuationPointStore::Point p;
                p.description = desc;
                p.maxReferences = maxRefs;
                p.position = resume;
                r.continuationPoint = points.add(std::move(p));
            }
        }
        response.results.push_back(std::move(r));
    }
    return response;
}

BrowseNextResponse AddressSpace::browseNext(const BrowseNextRequest& request,
                                            ContinuationPointStore& points,
                                            const SessionIdentity* user) const {
    BrowseNextResponse response;
    if (request.continuationPoints.empty()) {
        response.responseHeader.serviceResult = status::BadNothingToDo;
        return response;
    }
    std::shared_lock lock(impl_->mutex);
    const Impl& s = *impl_;
    response.results.reserve(request.continuationPoints.size());
    for (const auto& cp : request.continuationPoints) {
        BrowseResult r;
        ContinuationPointStore::Point* p = points.find(cp);
        if (p == nullptr) {
            r.statusCode = status::BadContinuationPointInvalid;
            response.results.push_back(std::move(r));
            continue;
        }
        ContinuationPointStore::Point point = points.take(p);
        if (!request.releaseContinuationPoints) {
            bool wantPoint = false;
            std::uint32_t resume = 0;
            r = browseFrom(s, point.description, point.maxReferences, point.position, wantPoint,
                           resume, user);
            if (wantPoint) {
                point.position = resume;
                r.continuationPoint = points.add(std::move(point));  // a slot was just freed
            }
        }
        response.results.push_back(std::move(r));
    }
    return response;
}

// ---- TranslateBrowsePathsToNodeIds ----------------------------------------------------------
BrowsePathResult AddressSpace::translateBrowsePath(const BrowsePath& path) const {
    TranslateBrowsePathsToNodeIdsRequest request;
    request.browsePaths.push_back(path);
    auto response = translateBrowsePaths(request);
    return std::move(response.results.front());
}

TranslateBrowsePathsToNodeIdsResponse AddressSpace::translateBrowsePaths(
    const TranslateBrowsePathsToNodeIdsRequest& request, const SessionIdentity* user) const {
    TranslateBrowsePathsToNodeIdsResponse response;
    if (request.browsePaths.empty()) {
        response.responseHeader.serviceResult = status::BadNothingToDo;
        return response;
    }
    std::shared_lock lock(impl_->mutex);
    const Impl& s = *impl_;
    response.results.reserve(request.browsePaths.size());
    std::vector<NodeIndex> current, next;
    for (const auto& path : request.browsePaths) {
        BrowsePathResult result;
        const auto& elements = path.relativePath.elements;
        NodeIndex start = s.find(path.startingNode);
        if (start == kNoNode || !visible(s, start, user)) {
            result.statusCode = status::BadNodeIdUnknown;
        } else if (elements.empty()) {
            result.statusCode = status::BadNothingToDo;
        } else if (std::any_of(elements.begin(), elements.end(), [](const RelativePathElement& e) {
                       return e.targetName.name.empty();
                   })) {
            result.statusCode = status::BadBrowseNameInvalid;
        } else {
            current.assign(1, start);
            for (const auto& e : elements) {
                next.clear();
                std::uint16_t type = kNoRefType;
                if (!e.referenceTypeId.isNull()) {
                    type = s.refTypeIndexOf(s.find(e.referenceTypeId));
                    if (type == kNoRefType) {
                        current.clear();
                        break;
                    }
                }
                const BrowseDirection dir =
                    e.isInverse ? BrowseDirection::Inverse : BrowseDirection::Forward;
                for (NodeIndex n : current) {
                    for (const Ref& r : s.nodes[n].refs) {
                        if (r.isExternal() ||
                            !s.referenceMatches(r, dir, type, e.includeSubtypes, 0))
                            continue;
                        const Node& t = s.nodes[r.target];
                        if (t.browseNs != e.targetName.namespaceIndex ||
                            s.strings.get(t.browseName) != e.targetName.name ||
                            !visible(s, r.target, user))
                            continue;
                        if (std::find(next.begin(), next.end(), r.target) == next.end())
                            next.push_back(r.target);
                    }
                }
                current.swap(next);
                if (current.empty()) break;
            }
            if (current.empty()) {
                result.statusCode = status::BadNoMatch;
            } else {
                result.targets.reserve(current.size());
                for (NodeIndex n : current) {
                    BrowsePathTarget t;
                    t.targetId = s.idOf(n);
                    t.remainingPathIndex = 0xFFFFFFFFu;
                    result.targets.push_back(std::move(t));
                }
            }
        }
        response.results.push_back(std::move(result));
    }
    return response;
}

}  // namespace pnp::ua::server
