// Internal: the state behind AddressSpace, shared by the .cpp files of the address space
// (address_space.cpp: model + application API, nodeset_loader.cpp: blob decoding,
// view_services.cpp: Browse/Translate, attribute_services.cpp: Read/Write/type checks,
// method_services.cpp: Call). Not part of the public API.
#pragma once

#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <unordered_map>
#include <vector>

#include "ua/server/address_space.hpp"
#include "ua/server/node.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::server {

inline constexpr std::uint16_t kNoRefType = 0xFFFF;

inline bool isClass(const Node& n, NodeClassBits c) { return n.nodeClass == c; }
inline NodeClass toNodeClass(NodeClassBits c) { return static_cast<NodeClass>(c); }

struct AddressSpace::Impl {
    using ValueListener = AddressSpace::ValueListener;
    explicit Impl(Options o);

    Options options;
    mutable std::shared_mutex mutex;
    // Bumped by every change made under the exclusive lock (see lockForChange()); what is
    // derived from the nodes and cached (method arguments) is valid for one generation.
    std::uint64_t changeGeneration = 0;
    // Bumped by changes of nodes and references (not by value / attribute writes): what is
    // derived from the graph alone (event type chains, notifier paths) is valid for one.
    std::atomic<std::uint64_t> structureGeneration{0};
    std::unique_lock<std::shared_mutex> lockForChange() {
        std::unique_lock lock(mutex);
        ++changeGeneration;
        structureGeneration.fetch_add(1, std::memory_order_release);
        return lock;
    }
    // For writes of values and attributes, which leave the graph as it is.
    std::unique_lock<std::shared_mutex> lockForValueChange() {
        std::unique_lock lock(mutex);
        ++changeGeneration;
        return lock;
    }

    // ---- nodes and ids -------------------------------------------------------------------
    std::vector<Node> nodes;
    std::size_t liveNodes = 0;
    std::size_t referenceCount = 0;                             // each reference once
    std::vector<NodeIndex> ns0Index;                            // numeric ns=0 id -> node
    std::unordered_map<std::uint64_t, NodeIndex> numericIndex;  // other numeric ids
    std::vector<NodeId> otherIds;  // string / guid / opaque ids (Node::idValue indexes it)
    std::unordered_map<NodeId, NodeIndex> otherIndex;
    std::vector<ExpandedNodeId> externalTargets;  // targets on other servers (Ref::kExternal)
    std::vector<NodeId> internedIds;              // non-numeric ids held by CompactNodeId
    std::unordered_map<NodeId, std::uint32_t> internedIndex;
    StringPool strings;
    std::vector<String> namespaces;
    std::unordered_map<UInt16, UInt32> nextNumericId;

    // ---- reference types -------------------------------------------------------------------
    std::vector<NodeIndex> refTypes;  // dense index -> ReferenceType node
    // subtypes[t]: bit set over dense indexes of t and all its subtypes (HasSubtype closure).
    std::vector<std::vector<std::uint64_t>> subtypes;
    std::uint16_t rtHasSubtype = kNoRefType, rtHasTypeDefinition = kNoRefType,
                  rtHasComponent = kNoRefType, rtHasProperty = kNoRefType,
                  rtHasEncoding = kNoRefType, rtOrganizes = kNoRefType, rtHierarchical = kNoRefType,
                  rtAggregates = kNoRefType, rtHasModellingRule = kNoRefType,
                  rtHasInterface = kNoRefType;
    // ModelUris whose nodes are loaded (the compiled ns0 and NodeSet2 XML files).
    std::vector<std::string> loadedModels;

    // Shared reference arrays of the loaded NodeSets (RefList slices borrow from them).
    std::vector<std::unique_ptr<Ref[]>> refPools;
    std::size_t refPoolBytes = 0;
    std::size_t blobBytesTouched = 0;

    std::unordered_map<NodeIndex, std::shared_ptr<const MethodHandler>> methods;
    // Method copied from an InstanceDeclaration -> the declaration (handler fallback).
    std::unordered_map<NodeIndex, NodeIndex> methodDeclarations;
    double ns0LoadMs = 0;
    ValueListener valueListener;  // see AddressSpace::setValueListener
    void valueStored(NodeIndex i) const {
        if (!valueListener) return;
        const Node& n = nodes[i];
        // The stored id itself for string/GUID/opaque ids (no copy).
        if (n.idKind == 0)
            valueListener(NodeId(n.ns, n.idValue), *n.extra->value.owned);
        else
            valueListener(otherIds[n.idValue], *n.extra->value.owned);
    }

    // ---- lookups (callers hold the lock) ------------------------------------------------------
    NodeIndex find(const NodeId& id) const {
        if (id.isNumeric()) {
            UInt32 v = id.numeric();
            if (id.namespaceIndex() == 0) return v < ns0Index.size() ? ns0Index[v] : kNoNode;
            auto it = numericIndex.find(numericKey(id.namespaceIndex(), v));
            return it == numericIndex.end() ? kNoNode : it->second;
        }
        auto it = otherIndex.find(id);
        return it == otherIndex.end() ? kNoNode : it->second;
    }
    NodeIndex find(std::uint32_t ns0Id) const {
        return ns0Id < ns0Index.size() ? ns0Index[ns0Id] : kNoNode;
    }
    static std::uint64_t numericKey(UInt16 ns, UInt32 v) {
        return (static_cast<std::uint64_t>(ns) << 32) | v;
    }
    NodeId idOf(NodeIndex i) const {
        const Node& n = nodes[i];
        return n.idKind == 0 ? NodeId(n.ns, n.idValue) : otherIds[n.idValue];
    }
    ExpandedNodeId targetIdOf(const Ref& r) const {
        return r.isExternal() ? externalTargets[r.target] : ExpandedNodeId(idOf(r.target));
    }
    bool isNs0(const NodeId& id, std::uint32_t v) const {
        return id.namespaceIndex() == 0 && id.isNumeric() && id.numeric() == v;
    }
    CompactNodeId compact(const NodeId& id) {
        if (id.isNumeric()) return CompactNodeId{id.numeric(), id.namespaceIndex(), 0};
        auto [it, added] =
            internedIndex.emplace(id, static_cast<std::uint32_t>(internedIds.size()));
        if (added) internedIds.push_back(id);
        return CompactNodeId{it->second, 0, 1};
    }
    NodeId expand(const CompactNodeId& c) const {
        return c.interned ? internedIds[c.value] : NodeId(c.ns, c.value);
    }
    NodeIndex find(const CompactNodeId& c) const {
        if (!c.interned && c.ns == 0) return find(c.value);
        return find(expand(c));
    }
    QualifiedName browseNameOf(const Node& n) const {
        return QualifiedName{n.browseNs, String(strings.get(n.browseName))};
    }
    LocalizedText displayNameOf(const Node& n) const {
        return LocalizedText(String(strings.get(n.displayLocale)),
                             String(strings.get(n.displayText)));
    }
    std::uint16_t refTypeIndexOf(NodeIndex i) const {
        if (i == kNoNode) return kNoRefType;
        const Node& n = nodes[i];
        return (n.nodeClass == NodeClassBits::ReferenceType && n.extra) ? n.extra->refTypeIndex
                                                                        : kNoRefType;
    }
    bool refTypeMatches(std::uint16_t type, std::uint16_t base, bool includeSubtypes) const {
        if (type == base) return true;
        if (!includeSubtypes || base >= subtypes.size()) return false;
        const auto& row = subtypes[base];
        return (type >> 6) < row.size() && ((row[type >> 6] >> (type & 63)) & 1u) != 0;
    }
    // Target of the first forward reference of `type` (exact type), kNoNode if none.
    NodeIndex forwardTarget(NodeIndex i, std::uint16_t type) const {
        for (const Ref& r : nodes[i].refs)
            if (r.type == type && r.isForward() && !r.isExternal()) return r.target;
        return kNoNode;
    }
    NodeIndex typeDefinitionOf(NodeIndex i) const { return forwardTarget(i, rtHasTypeDefinition); }
    NodeIndex supertypeOf(NodeIndex i) const {
        for (const Ref& r : nodes[i].refs)
            if (r.type == rtHasSubtype && !r.isForward() && !r.isExternal()) return r.target;
        return kNoNode;
    }
    bool isSubtype(NodeIndex t, NodeIndex base) const {
        for (int depth = 0; t != kNoNode && depth < 64; ++depth) {
            if (t == base) return true;
            t = supertypeOf(t);
        }
        return false;
    }
    // Child of `parent` with this BrowseName over hierarchical forward references.
    NodeIndex childByName(NodeIndex parent, const QualifiedName& name) const;

    // ---- mutation (callers hold the lock exclusively) -------------------------------------
    NodeIndex createNode(const NodeId& id, NodeClassBits cls, const QualifiedName& browseName,
                         const NodeAttributes& attributes);
    void registerId(NodeIndex i, const NodeId& id);
    void unregisterId(NodeIndex i);
    void link(NodeIndex source, std::uint16_t type, NodeIndex target);
    bool unlink(NodeIndex source, std::uint16_t type, NodeIndex target);
    void addRefType(NodeIndex i);
    void rebuildSubtypeClosure();
    void rememberWellKnownRefTypes();
    NodeId freshId(UInt16 ns);
    void deleteNode(NodeIndex i, bool children);
    // Copies the Mandatory InstanceDeclarations of `type`, its supertypes and the interfaces
    // they implement below `instance`, and the Optional ones named in `optional`.
    void instantiate(NodeIndex instance, NodeIndex type, int depth = 0,
                     const std::vector<QualifiedName>* optional = nullptr);
    // Copies the Mandatory (and requested Optional) aggregated children of `declaration`.
    void copyDeclaredChildren(NodeIndex instance, NodeIndex declaration, int depth,
                              const std::vector<QualifiedName>* optional);
    NodeIndex copyDeclaration(NodeIndex parent, std::uint16_t refType, NodeIndex declaration,
                              int depth, const std::vector<QualifiedName>* optional);
    std::shared_ptr<const MethodHandler> handlerOf(NodeIndex method) const {
        auto h = methods.find(method);
        if (h != methods.end() && h->second && *h->second) return h->second;
        auto d = methodDeclarations.find(method);
        if (d == methodDeclarations.end()) return nullptr;
        h = methods.find(d->second);
        return (h != methods.end() && h->second && *h->second) ? h->second : nullptr;
    }

    // ---- roles and permissions (address_space.cpp) --------------------------------------------
    struct Permissions {
        bool active = false;  // anything configured (else nothing is checked)
        std::shared_ptr<const RolePermissionSet> serverDefault;
        std::unordered_map<UInt16, std::shared_ptr<const RolePermissionSet>> namespaces;
        std::unordered_map<NodeIndex, std::shared_ptr<const RolePermissionSet>> nodes;
        std::uint32_t encryptionRequired = 0;  // role bits
        void update() { active = serverDefault || !namespaces.empty() || !nodes.empty(); }
    } permissions;
    // The rules for node i (null: everything allowed). Lock held.
    const std::shared_ptr<const RolePermissionSet>* permissionSetOf(NodeIndex i) const {
        if (!permissions.nodes.empty()) {
            auto it = permissions.nodes.find(i);
            if (it != permissions.nodes.end()) return &it->second;
        }
        if (!permissions.namespaces.empty()) {
            auto it = permissions.namespaces.find(nodes[i].ns);
            if (it != permissions.namespaces.end()) return &it->second;
        }
        return permissions.serverDefault ? &permissions.serverDefault : nullptr;
    }
    // The session's permissions on node i; everything for local calls (user null) and while
    // no permission is configured. Lock held.
    UInt32 userPermissions(NodeIndex i, const SessionIdentity* user) const {
        if (user == nullptr || !permissions.active) return permission::All;
        const auto* set = permissionSetOf(i);
        return set ? (*set)->permissionsOf(*user, permissions.encryptionRequired) : permission::All;
    }
    bool checksPermissions(const SessionIdentity* user) const {
        return user != nullptr && permissions.active;
    }

    // ---- NodeSet blobs (nodeset_loader.cpp) -------------------------------------------------
    void loadNodeSet(const Byte* blob, std::size_t size);

    // ---- attributes (attribute_services.cpp) --------------------------------------------------
    // Reads an attribute; the lock is held shared on entry and may be released for a read
    // callback (`lock` is the caller's lock).
    DataValue readAttribute(std::shared_lock<std::shared_mutex>& lock, const ReadValueId& item,
                            TimestampsToReturn timestamps,
                            const SessionIdentity* user = nullptr) const;
    StatusCode checkValue(const Variant& v, NodeIndex dataType, Int32 valueRank,
                          std::span<const UInt32> arrayDimensions, bool allowEmpty) const;
    bool builtinMatches(BuiltinType b, const Variant& v, NodeIndex dataType) const;
    DataValue storedValue(const Node& n) const;
    Variant decodeDefinition(const Node& n) const;
    std::vector<Argument> methodArguments(NodeIndex method, const char* name) const;
    // The InputArguments of `method`, decoded once per changeGeneration (a Call would
    // otherwise copy and decode the property's ExtensionObjects every time). Shared lock held.
    std::shared_ptr<const std::vector<Argument>> inputArguments(NodeIndex method) const;
    struct CachedArguments {
        std::uint64_t generation = 0;
        std::shared_ptr<const std::vector<Argument>> arguments;
    };
    mutable std::mutex argumentCacheMutex;
    mutable std::unordered_map<NodeIndex, CachedArguments> argumentCache;
    StatusCode writeAttribute(std::unique_lock<std::shared_mutex>& lock, const WriteValue& item,
                              bool checkAccess, const SessionIdentity* user = nullptr);

    // ---- browse (view_services.cpp) -----------------------------------------------------------
    ReferenceDescription describe(const Ref& r, UInt32 resultMask) const;
    bool referenceMatches(const Ref& r, BrowseDirection dir, std::uint16_t type,
                          bool includeSubtypes, UInt32 nodeClassMask) const;

    // ---- structures of loaded models (nodeset_xml.cpp) --------------------------------------
    // The layout of structure DataType `dt` from its DataTypeDefinition (nullptr: none).
    std::shared_ptr<const StructureLayout> structureLayoutOf(NodeIndex dt) const;
    // Whether a binary ExtensionObject body decodes as DataType `dt` by its definition. Types
    // of namespace 0 are left to their generated codecs, types without a definition pass.
    bool bodyFits(const ExtensionObject& x, NodeIndex dt) const;

    std::size_t bytesUsed() const;
};

// Number of ns0 nodes compiled in (from the generated blob).
std::size_t namespaceZeroBlobNodeCount();

// Stores a Variable's value (the lock held exclusively): the server timestamp now, the
// source timestamp too unless given.
void storeValue(NodeExtra& x, DataValue v);

}  // namespace pnp::ua::server
