// AddressSpace: construction, the node model's bookkeeping and the application API.
#include "ua/server/address_space.hpp"

#include <algorithm>
#include <random>

#include "ua/server/address_space_impl.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_ids_variables.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

namespace generated {
extern const unsigned char kNs0Blob[];
extern const std::size_t kNs0BlobSize;
}  // namespace generated

namespace {
constexpr std::string_view kUaNamespace = "http://opcfoundation.org/UA/";
constexpr UInt32 kFirstGeneratedId = 50000;
}  // namespace

// ---- Impl: construction ------------------------------------------------------------------
AddressSpace::Impl::Impl(Options o) : options(std::move(o)) {
    namespaces.emplace_back(kUaNamespace);
    namespaces.push_back(options.applicationUri);
    if (options.loadNamespaceZero) {
        auto t0 = std::chrono::steady_clock::now();
        loadNodeSet(generated::kNs0Blob, generated::kNs0BlobSize);
        loadedModels.emplace_back(kUaNamespace);
        ns0LoadMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                        .count();
    }
}

// ---- Impl: ids -------------------------------------------------------------------------------
void AddressSpace::Impl::registerId(NodeIndex i, const NodeId& id) {
    Node& n = nodes[i];
    n.ns = id.namespaceIndex();
    if (id.isNumeric()) {
        n.idKind = 0;
        n.idValue = id.numeric();
        if (n.ns == 0) {
            if (n.idValue >= ns0Index.size()) ns0Index.resize(std::size_t(n.idValue) + 1, kNoNode);
            ns0Index[n.idValue] = i;
        } else {
            numericIndex[numericKey(n.ns, n.idValue)] = i;
        }
    } else {
        n.idKind = 1;
        n.idValue = static_cast<std::uint32_t>(otherIds.size());
        otherIds.push_back(id);
        otherIndex[id] = i;
    }
}

void AddressSpace::Impl::unregisterId(NodeIndex i) {
    const Node& n = nodes[i];
    if (n.idKind == 0) {
        if (n.ns == 0) {
            if (n.idValue < ns0Index.size()) ns0Index[n.idValue] = kNoNode;
        } else {
            numericIndex.erase(numericKey(n.ns, n.idValue));
        }
    } else {
        otherIndex.erase(otherIds[n.idValue]);
        otherIds[n.idValue] = NodeId();
    }
}

NodeId AddressSpace::Impl::freshId(UInt16 ns) {
    if (ns == 0) ns = 1;
    UInt32& next = nextNumericId[ns];
    if (next < kFirstGeneratedId) next = kFirstGeneratedId;
    while (find(NodeId(ns, next)) != kNoNode) ++next;
    return NodeId(ns, next++);
}

// ---- Impl: references ------------------------------------------------------------------------
void AddressSpace::Impl::addRefType(NodeIndex i) {
    Node& n = nodes[i];
    if (!n.extra) n.extra = std::make_unique<NodeExtra>();
    if (refTypes.size() >= kNoRefType)
        throw AddressSpaceError(status::BadTooManyOperations, "too many ReferenceTypes");
    n.extra->refTypeIndex = static_cast<std::uint16_t>(refTypes.size());
    refTypes.push_back(i);
}

void AddressSpace::Impl::rememberWellKnownRefTypes() {
    auto dense = [&](std::uint32_t id) { return refTypeIndexOf(find(id)); };
    rtHasSubtype = dense(ns0::HasSubtype);
    rtHasTypeDefinition = dense(ns0::HasTypeDefinition);
    rtHasComponent = dense(ns0::HasComponent);
    rtHasProperty = dense(ns0::HasProperty);
    rtHasEncoding = dense(ns0::HasEncoding);
    rtOrganizes = dense(ns0::Organizes);
    rtHierarchical = dense(ns0::HierarchicalReferences);
    rtAggregates = dense(ns0::Aggregates);
    rtHasModellingRule = dense(ns0::HasModellingRule);
    rtHasInterface = dense(ns0::HasInterface);
}

void AddressSpace::Impl::rebuildSubtypeClosure() {
    const std::size_t n = refTypes.size();
    const std::size_t words = (n + 63) / 64;
    subtypes.assign(n, std::vector<std::uint64_t>(words, 0));
    std::vector<NodeIndex> stack;
    for (std::size_t t = 0; t < n; ++t) {
        auto& row = subtypes[t];
        if (refTypes[t] == kNoNode) continue;
        stack.assign(1, refTypes[t]);
        while (!stack.empty()) {
            NodeIndex cur = stack.back();
            stack.pop_back();
            std::uint16_t d = refTypeIndexOf(cur);
            if (d == kNoRefType || ((row[d >> 6] >> (d & 63)) & 1u)) continue;
            row[d >> 6] |= std::uint64_t(1) << (d & 63);
            for (const Ref& r : nodes[cur].refs)
                if (r.type == rtHasSubtype && r.isForward() && !r.isExternal())
                    stack.push_back(r.target);
        }
    }
}

void AddressSpace::Impl::link(NodeIndex source, std::uint16_t type, NodeIndex target) {
    nodes[source].refs.push_back(Ref{target, type, 0});
    nodes[target].refs.push_back(Ref{source, type, Ref::kInverse});
    ++referenceCount;
    if (type == rtHasSubtype && nodes[source].nodeClass == NodeClassBits::ReferenceType)
        rebuildSubtypeClosure();
}

bool AddressSpace::Impl::unlink(NodeIndex source, std::uint16_t type, NodeIndex target) {
    if (!nodes[source].refs.erase(Ref{target, type, 0})) return false;
    nodes[target].refs.erase(Ref{source, type, Ref::kInverse});
    --referenceCount;
    if (type == rtHasSubtype && nodes[source].nodeClass == NodeClassBits::ReferenceType)
        rebuildSubtypeClosure();
    return true;
}

NodeIndex AddressSpace::Impl::childByName(NodeIndex parent, const QualifiedName& name) const {
    for (const Ref& r : nodes[parent].refs) {
        if (!r.isForward() || r.isExternal() || !refTypeMatches(r.type, rtHierarchical, true))
            continue;
        const Node& c = nodes[r.target];
        if (c.browseNs == name.namespaceIndex && strings.get(c.browseName) == name.name)
            return r.target;
    }
    return kNoNode;
}

// ---- Impl: nodes ----------------------------------------------------------------------------
NodeIndex AddressSpace::Impl::createNode(const NodeId& requested, NodeClassBits cls,
                                         const QualifiedName& browseName, const NodeAttributes& a) {
    if (browseName.name.empty())
        throw AddressSpaceError(status::BadBrowseNameInvalid, "empty BrowseName");
    if (browseName.namespaceIndex >= namespaces.size())
        throw AddressSpaceError(status::BadBrowseNameInvalid, "BrowseName namespace");
    NodeId id = requested;
    if (id.isNumeric() && id.numeric() == 0) id = freshId(id.namespaceIndex());
    if (id.namespaceIndex() >= namespaces.size())
        throw AddressSpaceError(status::BadNodeIdInvalid, "unknown namespace in " + id.toString());
    if (find(id) != kNoNode) throw AddressSpaceError(status::BadNodeIdExists, id.toString());
    const auto index = static_cast<NodeIndex>(nodes.size());
    Node& n = nodes.emplace_back();
    n.nodeClass = cls;
    n.flags = Node::kAlive;
    registerId(index, id);
    n.browseNs = browseName.namespaceIndex;
    n.browseName = strings.intern(browseName.name);
    if (a.displayName.text.empty() && a.displayName.locale.empty()) {
        n.displayText = n.browseName;
    } else {
        n.displayLocale = strings.intern(a.displayName.locale);
        n.displayText = strings.intern(a.displayName.text);
    }
    n.descriptionLocale = strings.intern(a.description.locale);
    n.descriptionText = strings.intern(a.description.text);
    n.writeMask = a.writeMask;
    n.userWriteMask = a.writeMask;
    ++liveNodes;
    return index;
}

void AddressSpace::Impl::deleteNode(NodeIndex i, bool children) {
    if (!nodes[i].alive()) return;
    if (children && rtAggregates != kNoRefType) {
        std::vector<NodeIndex> kids;
        for (const Ref& r : nodes[i].refs)
            if (r.isForward() && !r.isExternal() && r.target != i &&
                refTypeMatches(r.type, rtAggregates, true))
                kids.push_back(r.target);
        // Unlink first so that a child does not see this node again (cycles).
        nodes[i].flags &= static_cast<std::uint8_t>(~Node::kAlive);
        for (NodeIndex k : kids) deleteNode(k, true);
        nodes[i].flags |= Node::kAlive;
    }
    Node& n = nodes[i];
    bool wasRefType = n.nodeClass == NodeClassBits::ReferenceType;
    for (const Ref& r : n.refs) {
        if (!r.isExternal() && r.target != i)
            nodes[r.target].refs.erase(
                Ref{i, r.type, static_cast<std::uint16_t>(r.flags ^ Ref::kInverse)});
        // A reference to itself is listed twice (both ends) but counted once.
        if (r.isExternal() || r.target != i || r.isForward()) --referenceCount;
    }
    Node& m = nodes[i];  // (no reallocation above, but keep the reference fresh)
    m.refs.clear();
    if (wasRefType && m.extra && m.extra->refTypeIndex != kNoRefType) {
        // Drop every reference of the deleted type (rare: a full scan).
        const std::uint16_t d = m.extra->refTypeIndex;
        refTypes[d] = kNoNode;
        for (Node& other : nodes) {
            if (!other.alive()) continue;
            std::vector<Ref> gone;
            for (const Ref& r : other.refs)
                if (r.type == d) gone.push_back(r);
            for (const Ref& r : gone) {
                other.refs.erase(r);
                if (r.isForward() || r.isExternal()) --referenceCount;
            }
        }
    }
    m.extra.reset();
    methods.erase(i);
    methodDeclarations.erase(i);
    if (permissions.nodes.erase(i) != 0) permissions.update();
    unregisterId(i);
    m.flags = 0;
    --liveNodes;
    if (wasRefType) rebuildSubtypeClosure();
}

// ---- Impl: instantiation of type definitions ----------------------------------------------------
namespace {
constexpr int kMaxInstantiationDepth = 16;
}

void AddressSpace::Impl::instantiate(NodeIndex instance, NodeIndex type, int depth,
                                     const std::vector<QualifiedName>* optional) {
    // The type's own declarations first: they override those of supertypes and interfaces
    // (a child that already exists by BrowseName is not copied again).
    std::vector<NodeIndex> interfaces;
    for (int d = 0; type != kNoNode && d < 64; ++d) {
        copyDeclaredChildren(instance, type, depth, optional);
        for (const Ref& r : nodes[type].refs)
            if (r.type == rtHasInterface && r.isForward() && !r.isExternal())
                interfaces.push_back(r.target);
        type = supertypeOf(type);
    }
    const NodeIndex base = find(ns0::BaseInterfaceType);
    for (NodeIndex i : interfaces)
        for (int d = 0; i != kNoNode && i != base && d < 64; ++d, i = supertypeOf(i))
            copyDeclaredChildren(instance, i, depth, optional);
}

void AddressSpace::Impl::copyDeclaredChildren(NodeIndex instance, NodeIndex declaration, int depth,
                                              const std::vector<QualifiedName>* optional) {
    if (depth >= kMaxInstantiationDepth || rtAggregates == kNoRefType) return;
    const NodeIndex mandatory = find(ns0::ModellingRule_Mandatory);
    const NodeIndex optionalRule = find(ns0::ModellingRule_Optional);
    auto requested = [&](NodeIndex c) {
        if (optional == nullptr || optionalRule == kNoNode ||
            forwardTarget(c, rtHasModellingRule) != optionalRule)
            return false;
        const Node& n = nodes[c];
        return std::any_of(optional->begin(), optional->end(), [&](const QualifiedName& q) {
            return q.namespaceIndex == n.browseNs && q.name == strings.get(n.browseName);
        });
    };
    struct Child {
        std::uint16_t type;
        NodeIndex node;
    };
    // A method's argument properties always go with it.
    const bool isMethod = nodes[declaration].nodeClass == NodeClassBits::Method;
    auto isArguments = [&](NodeIndex c) {
        std::string_view n = strings.get(nodes[c].browseName);
        return nodes[c].browseNs == 0 && (n == "InputArguments" || n == "OutputArguments");
    };
    std::vector<Child> children;  // copied first: linking below appends to reference lists
    for (const Ref& r : nodes[declaration].refs) {
        if (!r.isForward() || r.isExternal() || !refTypeMatches(r.type, rtAggregates, true))
            continue;
        if ((mandatory != kNoNode && forwardTarget(r.target, rtHasModellingRule) == mandatory) ||
            (isMethod && r.type == rtHasProperty && isArguments(r.target)) || requested(r.target))
            children.push_back({r.type, r.target});
    }
    for (const Child& c : children) {
        const Node& decl = nodes[c.node];
        QualifiedName name{decl.browseNs, String(strings.get(decl.browseName))};
        // Overridden by a subtype's declaration: the fully-inherited InstanceDeclaration
        // hierarchy (OPC 10000-3 §6.3.3.3) still has this declaration's children at the paths
        // the override does not declare (e.g. ParameterSet/ToolFrame of a supertype below a
        // subtype's ParameterSet), so merge them in.
        if (NodeIndex existing = childByName(instance, name); existing != kNoNode) {
            if (nodes[existing].nodeClass != NodeClassBits::Method)
                copyDeclaredChildren(existing, c.node, depth + 1, optional);
            continue;
        }
        copyDeclaration(instance, c.type, c.node, depth + 1, optional);
    }
}

NodeIndex AddressSpace::Impl::copyDeclaration(NodeIndex parent, std::uint16_t refType,
                                              NodeIndex declaration, int depth,
                                              const std::vector<QualifiedName>* optional) {
    const Node& d = nodes[declaration];
    const NodeClassBits cls = d.nodeClass;
    if (cls != NodeClassBits::Object && cls != NodeClassBits::Variable &&
        cls != NodeClassBits::Method)
        return kNoNode;
    const NodeId parentId = idOf(parent);
    NodeId id(parentId.namespaceIndex() == 0 ? UInt16{1} : parentId.namespaceIndex(), UInt32{0});
    if (parentId.idType() == IdType::String) {
        NodeId named(parentId.namespaceIndex(),
                     parentId.string() + "." + std::string(strings.get(d.browseName)));
        if (find(named) == kNoNode) id = named;
    }
    if (id.isNumeric()) id = freshId(id.namespaceIndex());
    const auto index = static_cast<NodeIndex>(nodes.size());
    {
        Node& n = nodes.emplace_back();
        const Node& src = nodes[declaration];  // re-read: emplace_back may reallocate
        n.nodeClass = cls;
        n.flags = static_cast<std::uint8_t>(src.flags | Node::kAlive);
        n.browseNs = src.browseNs;
        n.browseName = src.browseName;
        n.displayLocale = src.displayLocale;
        n.displayText = src.displayText;
        n.descriptionLocale = src.descriptionLocale;
        n.descriptionText = src.descriptionText;
        n.writeMask = src.writeMask;
        n.userWriteMask = src.userWriteMask;
        n.eventNotifier = src.eventNotifier;
        if (src.extra && cls == NodeClassBits::Variable) {
            auto x = std::make_unique<NodeExtra>();
            x->arrayDimensions = src.extra->arrayDimensions;
            x->minimumSamplingInterval = src.extra->minimumSamplingInterval;
            x->dataType = src.extra->dataType;
            x->valueRank = src.extra->valueRank;
            x->accessLevel = src.extra->accessLevel;
            x->userAccessLevel = src.extra->userAccessLevel;
            x->value.encoded = src.extra->value.encoded;
            x->value.encodedSize = src.extra->value.encodedSize;
            if (src.extra->value.owned)
                x->value.owned = std::make_unique<DataValue>(*src.extra->value.owned);
            n.extra = std::move(x);
        }
    }
    registerId(index, id);
    ++liveNodes;
    if (cls == NodeClassBits::Method) methodDeclarations[index] = declaration;
    link(parent, refType, index);
    NodeIndex td = typeDefinitionOf(declaration);
    if (td != kNoNode) link(index, rtHasTypeDefinition, td);
    // the declaration's own children first
    copyDeclaredChildren(index, declaration, depth, optional);
    if (td != kNoNode) instantiate(index, td, depth, optional);
    return index;
}

std::size_t AddressSpace::Impl::bytesUsed() const {
    std::size_t b = nodes.capacity() * sizeof(Node);
    for (const Node& n : nodes) {
        b += n.refs.heapBytes();
        if (n.extra) {
            b += sizeof(NodeExtra) + n.extra->arrayDimensions.capacity() * sizeof(UInt32);
            if (n.extra->value.owned) b += sizeof(DataValue);
        }
    }
    b += refPoolBytes + blobBytesTouched;
    b += ns0Index.capacity() * sizeof(NodeIndex);
    b += numericIndex.size() * 32 + numericIndex.bucket_count() * sizeof(void*);
    b += otherIds.capacity() * sizeof(NodeId);
    b += otherIndex.size() * (sizeof(NodeId) + 16) + otherIndex.bucket_count() * sizeof(void*);
    b += strings.bytesUsed();
    b += refTypes.capacity() * sizeof(NodeIndex);
    for (const auto& row : subtypes) b += row.capacity() * 8 + sizeof(row);
    return b;
}

// ---- ContinuationPointStore -------------------------------------------------------------------
// The seed is drawn at the first continuation point, not here: stores are also made for
// internal one-off browses (every fired event resolves its notifiers with one), and
// std::random_device costs a system call or more.
ContinuationPointStore::ContinuationPointStore(std::size_t maxPoints) : max_(maxPoints), next_(0) {}

const ByteString& ContinuationPointStore::add(Point p) {
    if (next_ == 0) {
        std::random_device rd;
        next_ = ((std::uint64_t(rd()) << 32) ^ rd()) | 1u;
    }
    next_ += 0x9E3779B97F4A7C15ull;  // unpredictable enough, never repeats within 2^64 calls
    std::uint64_t v = next_;
    p.id = ByteString(reinterpret_cast<const Byte*>(&v), sizeof v);
    points_.push_back(std::move(p));
    return points_.back().id;
}

ContinuationPointStore::Point* ContinuationPointStore::find(const ByteString& id) {
    for (auto& p : points_)
        if (p.id == id) return &p;
    return nullptr;
}

ContinuationPointStore::Point ContinuationPointStore::take(Point* p) {
    Point out = std::move(*p);
    points_.erase(points_.begin() + (p - points_.data()));
    return out;
}

// ---- AddressSpace: construction and introspection ------------------------------------------
AddressSpace::AddressSpace() : AddressSpace(Options{}) {}
AddressSpace::AddressSpace(Options options) : impl_(std::make_unique<Impl>(std::move(options))) {
    serveNamespaceArray();
}

void AddressSpace::serveNamespaceArray() {
    // Namespace array served live.
    if (contains(NodeId(0, ns0::Server_NamespaceArray))) {
        setValueCallback(
            NodeId(0, ns0::Server_NamespaceArray),
            ValueCallbacks{[this](const NodeId&) { return DataValue{Variant{namespaceArray()}}; },
                           {}});
    }
}
AddressSpace::~AddressSpace() = default;

AddressSpace::Statistics AddressSpace::statistics() const {
    std::shared_lock lock(impl_->mutex);
    Statistics s;
    s.nodes = impl_->liveNodes;
    s.references = impl_->referenceCount;
    s.bytesUsed = impl_->bytesUsed();
    s.namespaceZeroLoadMs = impl_->ns0LoadMs;
    return s;
}

bool AddressSpace::contains(const NodeId& id) const {
    std::shared_lock lock(impl_->mutex);
    return impl_->find(id) != kNoNode;
}

std::optional<NodeClass> AddressSpace::nodeClass(const NodeId& id) const {
    std::shared_lock lock(impl_->mutex);
    NodeIndex i = impl_->find(id);
    if (i == kNoNode) return std::nullopt;
    return toNodeClass(impl_->nodes[i].nodeClass);
}

std::optional<NodeId> AddressSpace::resolvePath(const NodeId& start,
                                                std::span<const QualifiedName> path) const {
    std::shared_lock lock(impl_->mutex);
    NodeIndex i = impl_->find(start);
    for (const auto& name : path) {
        if (i == kNoNode) return std::nullopt;
        i = impl_->childByName(i, name);
    }
    if (i == kNoNode) return std::nullopt;
    return impl_->idOf(i);
}

bool AddressSpace::isSubtypeOf(const NodeId& type, const NodeId& base) const {
    std::shared_lock lock(impl_->mutex);
    NodeIndex t = impl_->find(type), b = impl_->find(base);
    return t != kNoNode && b != kNoNode && impl_->isSubtype(t, b);
}

// ---- namespaces ------------------------------------------------------------------------------
UInt16 AddressSpace::addNamespace(std::string_view uri) {
    auto lock = impl_->lockForChange();
    auto& ns = impl_->namespaces;
    for (std::size_t i = 0; i < ns.size(); ++i)
        if (ns[i] == uri) return static_cast<UInt16>(i);
    if (ns.size() >= 0xFFFF) throw AddressSpaceError(status::BadOutOfRange, "too many namespaces");
    ns.emplace_back(uri);
    return static_cast<UInt16>(ns.size() - 1);
}

std::optional<UInt16> AddressSpace::namespaceIndex(std::string_view uri) const {
    std::shared_lock lock(impl_->mutex);
    const auto& ns = impl_->namespaces;
    for (std::size_t i = 0; i < ns.size(); ++i)
        if (ns[i] == uri) return static_cast<UInt16>(i);
    return std::nullopt;
}

std::vector<String> AddressSpace::namespaceArray() const {
    std::shared_lock lock(impl_->mutex);
    return impl_->namespaces;
}

// ---- application API: nodes ----------------------------------------------------------------
namespace {

NodeIndex need(const AddressSpace::Impl& s, const NodeId& id, StatusCode code, const char* what) {
    NodeIndex i = s.find(id);
    if (i == kNoNode) throw AddressSpaceError(code, std::string(what) + " " + id.toString());
    return i;
}

NodeIndex needClass(const AddressSpace::Impl& s, const NodeId& id, NodeClassBits cls,
                    StatusCode code, const char* what) {
    NodeIndex i = need(s, id, code, what);
    if (s.nodes[i].nodeClass != cls)
        throw AddressSpaceError(code, std::string(what) + " " + id.toString());
    return i;
}

std::uint16_t needRefType(const AddressSpace::Impl& s, const NodeId& id) {
    std::uint16_t t = s.refTypeIndexOf(s.find(id));
    if (t == kNoRefType)
        throw AddressSpaceError(status::BadReferenceTypeIdInvalid,
                                "reference type " + id.toString());
    return t;
}

// Organizes below folders and views, HasComponent elsewhere.
std::uint16_t defaultRefType(const AddressSpace::Impl& s, NodeIndex parent) {
    const Node& p = s.nodes[parent];
    if (p.nodeClass == NodeClassBits::View) return s.rtOrganizes;
    if (p.nodeClass == NodeClassBits::Object) {
        NodeIndex td = s.typeDefinitionOf(parent);
        NodeIndex folder = s.find(ns0::FolderType);
        if (td != kNoNode && folder != kNoNode && s.isSubtype(td, folder)) return s.rtOrganizes;
    }
    return s.rtHasComponent;
}

std::uint16_t refTypeFor(const AddressSpace::Impl& s, const NodeId& refType, NodeIndex parent) {
    if (refType.isNull()) return defaultRefType(s, parent);
    return needRefType(s, refType);
}

}  // namespace

void storeValue(NodeExtra& x, DataValue v) {
    DateTime now = DateTime::now();
    if (!v.sourceTimestamp) v.sourceTimestamp = now;
    v.serverTimestamp = now;
    // In place: a value written again and again (a state machine's, a sensor's) costs no
    // allocation of its own. Readers copy it under the lock.
    if (x.value.owned)
        *x.value.owned = std::move(v);
    else
        x.value.owned = std::make_unique<DataValue>(std::move(v));
}

NodeId AddressSpace::addObject(const NodeId& parent, const NodeId& id,
                               const QualifiedName& browseName, const ObjectAttributes& attributes,
                               const NodeId& typeDefinition, const NodeId& referenceType) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = need(s, parent, status::BadParentNodeIdInvalid, "parent");
    NodeIndex td = needClass(s, typeDefinition, NodeClassBits::ObjectType,
                             status::BadTypeDefinitionInvalid, "type definition");
    std::uint16_t rt = refTypeFor(s, referenceType, p);
    NodeIndex i = s.createNode(id, NodeClassBits::Object, browseName, attributes);
    s.nodes[i].eventNotifier = attributes.eventNotifier;
    s.link(p, rt, i);
    s.link(i, s.rtHasTypeDefinition, td);
    if (attributes.instantiateMandatory) s.instantiate(i, td);
    return s.idOf(i);
}

NodeId AddressSpace::instantiate(const NodeId& parent, const NodeId& type, const NodeId& id,
                                 const QualifiedName& browseName,
                                 const InstantiateOptions& options) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = need(s, parent, status::BadParentNodeIdInvalid, "parent");
    NodeIndex td = need(s, type, status::BadTypeDefinitionInvalid, "type definition");
    const NodeClassBits cls = s.nodes[td].nodeClass;
    if ((cls != NodeClassBits::ObjectType && cls != NodeClassBits::VariableType) ||
        s.nodes[td].has(Node::kIsAbstract))
        throw AddressSpaceError(status::BadTypeDefinitionInvalid,
                                type.toString() + " is not a concrete ObjectType or VariableType");
    std::uint16_t rt = refTypeFor(s, options.referenceType, p);
    NodeAttributes a;
    a.displayName = options.displayName;
    const bool isObject = cls == NodeClassBits::ObjectType;
    NodeIndex i =
        s.createNode(id, isObject ? NodeClassBits::Object : NodeClassBits::Variable, browseName, a);
    if (isObject) s.nodes[i].eventNotifier = options.eventNotifier;
    if (!isObject) {
        const NodeExtra* from = s.nodes[td].extra.get();
        auto x = std::make_unique<NodeExtra>();
        if (from != nullptr) {
            x->dataType = from->dataType;
            // A VariableType's ValueRank may be Any (-2); an instance keeps it.
            x->valueRank = from->valueRank;
            x->arrayDimensions = from->arrayDimensions;
            x->value.encoded = from->value.encoded;
            x->value.encodedSize = from->value.encodedSize;
            if (from->value.owned) x->value.owned = std::make_unique<DataValue>(*from->value.owned);
        }
        s.nodes[i].extra = std::move(x);
    }
    s.link(p, rt, i);
    s.link(i, s.rtHasTypeDefinition, td);
    s.instantiate(i, td, 0, &options.optionalChildren);
    return s.idOf(i);
}

NodeId AddressSpace::addFolder(const NodeId& parent, const NodeId& id,
                               const QualifiedName& browseName,
                               const ObjectAttributes& attributes) {
    return addObject(parent, id, browseName, attributes, NodeId(0, ns0::FolderType),
                     NodeId(0, ns0::Organizes));
}

NodeId AddressSpace::addVariable(const NodeId& parent, const NodeId& id,
                                 const QualifiedName& browseName, const VariableAttributes& a,
                                 const NodeId& typeDefinition, const NodeId& referenceType) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = need(s, parent, status::BadParentNodeIdInvalid, "parent");
    NodeIndex td = needClass(s, typeDefinition, NodeClassBits::VariableType,
                             status::BadTypeDefinitionInvalid, "type definition");
    NodeIndex dt =
        needClass(s, a.dataType, NodeClassBits::DataType, status::BadTypeMismatch, "data type");
    std::uint16_t rt = refTypeFor(s, referenceType, p);
    if (a.value.value && !a.value.value->isEmpty()) {
        StatusCode c = s.checkValue(*a.value.value, dt, a.valueRank, a.arrayDimensions, true);
        if (c.isBad()) throw AddressSpaceError(c, "initial value of " + browseName.toString());
    }
    NodeIndex i = s.createNode(id, NodeClassBits::Variable, browseName, a);
    Node& n = s.nodes[i];
    n.set(Node::kHistorizing, a.historizing);
    auto x = std::make_unique<NodeExtra>();
    x->dataType = s.compact(a.dataType);
    x->valueRank = a.valueRank;
    x->arrayDimensions = a.arrayDimensions;
    x->accessLevel = a.accessLevel;
    x->userAccessLevel = a.accessLevel;
    x->minimumSamplingInterval = a.minimumSamplingInterval;
    storeValue(*x, a.value);
    n.extra = std::move(x);
    s.link(p, rt, i);
    s.link(i, s.rtHasTypeDefinition, td);
    if (a.instantiateMandatory) s.instantiate(i, td);
    return s.idOf(i);
}

NodeId AddressSpace::addProperty(const NodeId& parent, const NodeId& id,
                                 const QualifiedName& browseName, const VariableAttributes& a) {
    return addVariable(parent, id, browseName, a, NodeId(0, ns0::PropertyType),
                       NodeId(0, ns0::HasProperty));
}

NodeId AddressSpace::addMethod(const NodeId& parent, const NodeId& id,
                               const QualifiedName& browseName,
                               const std::vector<Argument>& inputArguments,
                               const std::vector<Argument>& outputArguments, MethodHandler handler,
                               const MethodAttributes& attributes, const NodeId& referenceType) {
    NodeId methodId;
    {
        auto lock = impl_->lockForChange();
        Impl& s = *impl_;
        NodeIndex p = need(s, parent, status::BadParentNodeIdInvalid, "parent");
        std::uint16_t rt = needRefType(s, referenceType);
        for (const auto* args : {&inputArguments, &outputArguments})
            for (const Argument& arg : *args)
                if (s.find(arg.dataType) == kNoNode ||
                    s.nodes[s.find(arg.dataType)].nodeClass != NodeClassBits::DataType)
                    throw AddressSpaceError(status::BadTypeMismatch,
                                            "argument " + arg.name + " data type");
        NodeIndex i = s.createNode(id, NodeClassBits::Method, browseName, attributes);
        s.nodes[i].set(Node::kExecutable, attributes.executable);
        s.nodes[i].set(Node::kUserExecutable, attributes.executable);
        s.link(p, rt, i);
        if (handler) s.methods[i] = std::make_shared<const MethodHandler>(std::move(handler));
        methodId = s.idOf(i);
    }
    auto addArgs = [&](const std::vector<Argument>& args, const char* name) {
        if (args.empty()) return;
        std::vector<ExtensionObject> objs;
        objs.reserve(args.size());
        for (const auto& a : args) objs.push_back(toExtensionObject(a));
        VariableAttributes va;
        va.dataType = NodeId(0, ns0::Argument);
        va.valueRank = 1;
        va.arrayDimensions = {static_cast<UInt32>(args.size())};
        va.value = DataValue(Variant(std::move(objs)));
        NodeId propId(methodId.namespaceIndex(), UInt32{0});
        if (methodId.idType() == IdType::String &&
            !contains(NodeId(methodId.namespaceIndex(), methodId.string() + "." + name)))
            propId = NodeId(methodId.namespaceIndex(), methodId.string() + "." + name);
        addProperty(methodId, propId, QualifiedName{0, name}, va);
    };
    addArgs(inputArguments, "InputArguments");
    addArgs(outputArguments, "OutputArguments");
    return methodId;
}

NodeId AddressSpace::addObjectType(const NodeId& parentType, const NodeId& id,
                                   const QualifiedName& browseName, const ObjectTypeAttributes& a) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = needClass(s, parentType, NodeClassBits::ObjectType,
                            status::BadParentNodeIdInvalid, "parent type");
    NodeIndex i = s.createNode(id, NodeClassBits::ObjectType, browseName, a);
    s.nodes[i].set(Node::kIsAbstract, a.isAbstract);
    s.link(p, s.rtHasSubtype, i);
    return s.idOf(i);
}

NodeId AddressSpace::addVariableType(const NodeId& parentType, const NodeId& id,
                                     const QualifiedName& browseName,
                                     const VariableTypeAttributes& a) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = needClass(s, parentType, NodeClassBits::VariableType,
                            status::BadParentNodeIdInvalid, "parent type");
    NodeIndex dt =
        needClass(s, a.dataType, NodeClassBits::DataType, status::BadTypeMismatch, "data type");
    if (a.value && !a.value->isEmpty()) {
        StatusCode c = s.checkValue(*a.value, dt, a.valueRank, a.arrayDimensions, true);
        if (c.isBad()) throw AddressSpaceError(c, "value of " + browseName.toString());
    }
    NodeIndex i = s.createNode(id, NodeClassBits::VariableType, browseName, a);
    s.nodes[i].set(Node::kIsAbstract, a.isAbstract);
    auto x = std::make_unique<NodeExtra>();
    x->dataType = s.compact(a.dataType);
    x->valueRank = a.valueRank;
    x->arrayDimensions = a.arrayDimensions;
    if (a.value) x->value.owned = std::make_unique<DataValue>(*a.value);
    s.nodes[i].extra = std::move(x);
    s.link(p, s.rtHasSubtype, i);
    return s.idOf(i);
}

NodeId AddressSpace::addReferenceType(const NodeId& parentType, const NodeId& id,
                                      const QualifiedName& browseName,
                                      const ReferenceTypeAttributes& a) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = needClass(s, parentType, NodeClassBits::ReferenceType,
                            status::BadParentNodeIdInvalid, "parent type");
    NodeIndex i = s.createNode(id, NodeClassBits::ReferenceType, browseName, a);
    Node& n = s.nodes[i];
    n.set(Node::kIsAbstract, a.isAbstract);
    n.set(Node::kSymmetric, a.symmetric);
    s.addRefType(i);
    if (!a.inverseName.text.empty()) {
        n.extra->hasInverseName = true;
        n.extra->inverseLocale = s.strings.intern(a.inverseName.locale);
        n.extra->inverseText = s.strings.intern(a.inverseName.text);
    }
    s.link(p, s.rtHasSubtype, i);  // rebuilds the subtype closure
    return s.idOf(i);
}

NodeId AddressSpace::addDataType(const NodeId& parentType, const NodeId& id,
                                 const QualifiedName& browseName, const DataTypeAttributes& a) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = needClass(s, parentType, NodeClassBits::DataType, status::BadParentNodeIdInvalid,
                            "parent type");
    NodeIndex i = s.createNode(id, NodeClassBits::DataType, browseName, a);
    s.nodes[i].set(Node::kIsAbstract, a.isAbstract);
    if (!a.definition.empty()) {
        auto x = std::make_unique<NodeExtra>();
        x->value.owned = std::make_unique<DataValue>(Variant(a.definition));
        s.nodes[i].extra = std::move(x);
    }
    s.link(p, s.rtHasSubtype, i);
    return s.idOf(i);
}

NodeId AddressSpace::addView(const NodeId& parent, const NodeId& id,
                             const QualifiedName& browseName, const ViewAttributes& a) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex p = need(s, parent, status::BadParentNodeIdInvalid, "parent");
    NodeIndex i = s.createNode(id, NodeClassBits::View, browseName, a);
    s.nodes[i].set(Node::kContainsNoLoops, a.containsNoLoops);
    s.nodes[i].eventNotifier = a.eventNotifier;
    s.link(p, s.rtOrganizes, i);
    return s.idOf(i);
}

void AddressSpace::addReference(const NodeId& source, const NodeId& referenceType,
                                const ExpandedNodeId& target, bool isForward) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex src = need(s, source, status::BadSourceNodeIdInvalid, "source");
    std::uint16_t rt = needRefType(s, referenceType);
    NodeId local = target.nodeId;
    bool external = target.serverIndex != 0;
    if (!external && !target.namespaceUri.empty()) {
        bool found = false;
        for (std::size_t k = 0; k < s.namespaces.size(); ++k) {
            if (s.namespaces[k] == target.namespaceUri) {
                local.setNamespaceIndex(static_cast<UInt16>(k));
                found = true;
            }
        }
        if (!found) throw AddressSpaceError(status::BadTargetNodeIdInvalid, target.toString());
    }
    if (external) {
        Ref r{static_cast<NodeIndex>(s.externalTargets.size()), rt,
              static_cast<std::uint16_t>(Ref::kExternal | (isForward ? 0 : Ref::kInverse))};
        for (const Ref& e : s.nodes[src].refs)
            if (e.isExternal() && e.type == rt && e.isForward() == isForward &&
                s.externalTargets[e.target] == target)
                throw AddressSpaceError(status::BadDuplicateReferenceNotAllowed, target.toString());
        s.externalTargets.push_back(target);
        s.nodes[src].refs.push_back(r);
        ++s.referenceCount;
        return;
    }
    NodeIndex dst = need(s, local, status::BadTargetNodeIdInvalid, "target");
    NodeIndex from = isForward ? src : dst, to = isForward ? dst : src;
    for (const Ref& e : s.nodes[from].refs)
        if (e == Ref{to, rt, 0})
            throw AddressSpaceError(status::BadDuplicateReferenceNotAllowed, target.toString());
    s.link(from, rt, to);
}

bool AddressSpace::deleteReference(const NodeId& source, const NodeId& referenceType,
                                   const ExpandedNodeId& target, bool isForward) {
    auto lock = impl_->lockForChange();
    Impl& s = *impl_;
    NodeIndex src = s.find(source);
    std::uint16_t rt = s.refTypeIndexOf(s.find(referenceType));
    if (src == kNoNode || rt == kNoRefType) return false;
    if (target.serverIndex != 0) {
        for (const Ref& e : s.nodes[src].refs) {
            if (e.isExternal() && e.type == rt && e.isForward() == isForward &&
                s.externalTargets[e.target] == target) {
                Ref copy = e;
                s.nodes[src].refs.erase(copy);
                --s.referenceCount;
                return true;
            }
        }
        return false;
    }
    NodeIndex dst = s.find(target.nodeId);
    if (dst == kNoNode) return false;
    return isForward ? s.unlink(src, rt, dst) : s.unlink(dst, rt, src);
}

void AddressSpace::deleteNode(const NodeId& id, bool deleteChildren) {
    auto lock = impl_->lockForChange();
    NodeIndex i = need(*impl_, id, status::BadNodeIdUnknown, "node");
    impl_->deleteNode(i, deleteChildren);
}

// ---- roles and permissions -------------------------------------------------------------------
namespace {
std::shared_ptr<const RolePermissionSet> prepared(
    std::optional<std::vector<RolePermissionType>> p) {
    if (!p) return nullptr;
    return std::make_shared<const RolePermissionSet>(std::move(*p));
}
}  // namespace

void AddressSpace::applyPermissions(const PermissionDefaults& p) {
    auto lock = impl_->lockForValueChange();
    Impl::Permissions next;
    next.serverDefault = prepared(p.serverDefault);
    for (const auto& [ns, list] : p.namespaceDefaults) next.namespaces[ns] = prepared(list);
    for (const auto& [id, list] : p.nodes) {
        NodeIndex i = impl_->find(id);
        if (i == kNoNode) continue;  // e.g. a policy naming optional ns0 nodes
        next.nodes[i] = prepared(list);
    }
    for (const auto& r : p.encryptionRequired) {
        int bit = wellKnownRoleBit(r);
        if (bit >= 0) next.encryptionRequired |= 1u << bit;
    }
    next.update();
    impl_->permissions = std::move(next);
}

void AddressSpace::setRolePermissions(const NodeId& node,
                                      std::optional<std::vector<RolePermissionType>> permissions) {
    auto lock = impl_->lockForValueChange();
    NodeIndex i = impl_->find(node);
    if (i == kNoNode) throw AddressSpaceError(status::BadNodeIdUnknown, node.toString());
    if (permissions)
        impl_->permissions.nodes[i] = prepared(std::move(permissions));
    else
        impl_->permissions.nodes.erase(i);
    impl_->permissions.update();
}

void AddressSpace::setNamespaceDefaultRolePermissions(
    UInt16 namespaceIndex, std::optional<std::vector<RolePermissionType>> permissions) {
    auto lock = impl_->lockForValueChange();
    if (permissions)
        impl_->permissions.namespaces[namespaceIndex] = prepared(std::move(permissions));
    else
        impl_->permissions.namespaces.erase(namespaceIndex);
    impl_->permissions.update();
}

void AddressSpace::setDefaultRolePermissions(
    std::optional<std::vector<RolePermissionType>> permissions) {
    auto lock = impl_->lockForValueChange();
    impl_->permissions.serverDefault = prepared(std::move(permissions));
    impl_->permissions.update();
}

void AddressSpace::requireEncryptedChannel(const NodeId& role) {
    int bit = wellKnownRoleBit(role);
    if (bit < 0)
        throw AddressSpaceError(status::BadInvalidArgument,
                                "only well-known roles can require encryption");
    auto lock = impl_->lockForValueChange();
    impl_->permissions.encryptionRequired |= 1u << bit;
}

bool AddressSpace::enforcesPermissions() const {
    std::shared_lock lock(impl_->mutex);
    return impl_->permissions.active;
}

UInt32 AddressSpace::userPermissions(const NodeId& node, const SessionIdentity& user) const {
    std::shared_lock lock(impl_->mutex);
    NodeIndex i = impl_->find(node);
    if (i == kNoNode) return 0;
    return impl_->userPermissions(i, &user);
}

AddressSpace::EffectivePermissions AddressSpace::effectivePermissions(const NodeId& node) const {
    std::shared_lock lock(impl_->mutex);
    EffectivePermissions out;
    if (!impl_->permissions.active) return out;
    NodeIndex i = impl_->find(node);
    if (i == kNoNode) return out;
    if (const auto* set = impl_->permissionSetOf(i)) out.set = *set;
    out.encryptionRequired = impl_->permissions.encryptionRequired;
    return out;
}

std::uint64_t AddressSpace::structureGeneration() const {
    return impl_->structureGeneration.load(std::memory_order_acquire);
}

// ---- application API: values ---------------------------------------------------------------
namespace {
// setValue's work, the exclusive lock held.
StatusCode setValueAt(AddressSpace::Impl& s, NodeIndex i, DataValue value) {
    if (i == kNoNode) return status::BadNodeIdUnknown;
    Node& n = s.nodes[i];
    if ((n.nodeClass != NodeClassBits::Variable && n.nodeClass != NodeClassBits::VariableType) ||
        !n.extra)
        return status::BadNodeClassInvalid;
    if (value.value) {
        StatusCode c = s.checkValue(*value.value, s.find(n.extra->dataType), n.extra->valueRank,
                                    n.extra->arrayDimensions, true);
        if (c.isBad()) return c;
    }
    storeValue(*n.extra, std::move(value));
    s.valueStored(i);
    return StatusCode{};
}
}  // namespace

StatusCode AddressSpace::setValue(const NodeId& variable, DataValue value) {
    auto lock = impl_->lockForValueChange();
    return setValueAt(*impl_, impl_->find(variable), std::move(value));
}

// Structural changes take the exclusive lock: with either lock held the generation cannot
// move, so the indices stay valid while the caller holds it.
void AddressSpace::resolve(const Impl& s, VariableGroup& group) {
    const std::uint64_t generation = s.structureGeneration.load(std::memory_order_acquire);
    if (group.resolved_ && group.generation_ == generation) return;
    group.nodes_.clear();
    for (const NodeId& v : group.variables_) group.nodes_.push_back(s.find(v));
    group.resolved_ = true;
    group.generation_ = generation;
}

StatusCode AddressSpace::setValues(VariableGroup& group,
                                   std::vector<std::pair<std::size_t, DataValue>> values,
                                   const std::vector<std::pair<std::size_t, bool>>& executable) {
    auto lock = impl_->lockForValueChange();
    Impl& s = *impl_;
    resolve(s, group);
    for (const auto& [k, on] : executable) {
        if (k >= group.nodes_.size() || group.nodes_[k] == kNoNode) continue;
        Node& n = s.nodes[group.nodes_[k]];
        if (n.nodeClass != NodeClassBits::Method) continue;
        n.set(Node::kExecutable, on);  // as setExecutable()
        n.set(Node::kUserExecutable, on);
    }
    StatusCode first;
    for (auto& [k, value] : values) {
        StatusCode c = k < group.nodes_.size() ? setValueAt(s, group.nodes_[k], std::move(value))
                                               : StatusCode(status::BadNodeIdUnknown);
        if (c.isBad() && first.isGood()) first = c;
    }
    return first;
}

std::vector<DataValue> AddressSpace::readValues(VariableGroup& group) const {
    std::vector<DataValue> out;
    out.reserve(group.variables_.size());
    // Read below by readValue(), without this lock: values served by callbacks, and the
    // nodes that are missing or no variables (for readValue's status).
    std::vector<std::size_t> byReadValue;
    {
        std::shared_lock lock(impl_->mutex);
        const Impl& s = *impl_;
        resolve(s, group);
        for (std::size_t k = 0; k < group.nodes_.size(); ++k) {
            const NodeIndex i = group.nodes_[k];
            const Node* n = i == kNoNode ? nullptr : &s.nodes[i];
            const bool stored = n != nullptr && n->extra && !n->extra->value.callbacks &&
                                (n->nodeClass == NodeClassBits::Variable ||
                                 n->nodeClass == NodeClassBits::VariableType);
            if (stored) {
                out.push_back(s.storedValue(*n));
            } else {
                byReadValue.push_back(k);
                out.emplace_back();
            }
        }
    }
    for (std::size_t k : byReadValue) out[k] = readValue(group.variables_[k]);
    return out;
}

DataValue AddressSpace::readValue(const NodeId& variable) const {
    ReadValueId item;
    item.nodeId = variable;
    item.attributeId = static_cast<UInt32>(AttributeId::Value);
    return read(item, TimestampsToReturn::Both);
}

void AddressSpace::setValueCallback(const NodeId& variable, ValueCallbacks callbacks) {
    auto lock = impl_->lockForValueChange();
    Impl& s = *impl_;
    NodeIndex i = need(s, variable, status::BadNodeIdUnknown, "variable");
    Node& n = s.nodes[i];
    if ((n.nodeClass != NodeClassBits::Variable && n.nodeClass != NodeClassBits::VariableType) ||
        !n.extra)
        throw AddressSpaceError(status::BadNodeClassInvalid, variable.toString());
    if (!callbacks.read && !callbacks.write)
        n.extra->value.callbacks.reset();
    else
        n.extra->value.callbacks = std::make_shared<const ValueCallbacks>(std::move(callbacks));
}

void AddressSpace::setValueListener(ValueListener listener) {
    auto lock = impl_->lockForValueChange();
    impl_->valueListener = std::move(listener);
}

StatusCode AddressSpace::setExecutable(const NodeId& method, bool executable) {
    auto lock = impl_->lockForValueChange();
    Impl& s = *impl_;
    NodeIndex i = s.find(method);
    if (i == kNoNode) return status::BadNodeIdUnknown;
    if (s.nodes[i].nodeClass != NodeClassBits::Method) return status::BadMethodInvalid;
    s.nodes[i].set(Node::kExecutable, executable);
    s.nodes[i].set(Node::kUserExecutable, executable);
    return status::Good;
}

void AddressSpace::setMethodHandler(const NodeId& method, MethodHandler handler) {
    auto lock = impl_->lockForValueChange();
    Impl& s = *impl_;
    NodeIndex i = needClass(s, method, NodeClassBits::Method, status::BadMethodInvalid, "method");
    if (handler)
        s.methods[i] = std::make_shared<const MethodHandler>(std::move(handler));
    else
        s.methods.erase(i);
}

// ---- RegisterNodes / UnregisterNodes ---------------------------------------------------------
RegisterNodesResponse AddressSpace::registerNodes(const RegisterNodesRequest& request) const {
    RegisterNodesResponse r;
    if (request.nodesToRegister.empty())
        r.responseHeader.serviceResult = status::BadNothingToDo;
    else
        r.registeredNodeIds = request.nodesToRegister;
    return r;
}

UnregisterNodesResponse AddressSpace::unregisterNodes(const UnregisterNodesRequest& request) const {
    UnregisterNodesResponse r;
    if (request.nodesToUnregister.empty()) r.responseHeader.serviceResult = status::BadNothingToDo;
    return r;
}

}  // namespace pnp::ua::server
