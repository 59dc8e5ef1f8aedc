// The server's address space: nodes, references, the address-space services and the
// application API to build a server's information model.
//
// Services (transport-agnostic; the session layer decodes a request, calls these and encodes
// the response; only responseHeader.serviceResult is set here):
//   browse / browseNext            OPC 10000-4 §5.8.2 / §5.8.3 (with ContinuationPointStore)
//   translateBrowsePaths           §5.8.4
//   registerNodes / unregister     §5.8.5 / §5.8.6 (trivial: ids are returned unchanged)
//   read / write                   §5.10.2 / §5.10.4
//   call                           §5.11.2 (asynchronous completion)
//
// Application API (RAII, value types; errors throw AddressSpaceError):
//   addNamespace, namespaceArray, addObject, addVariable, addProperty, addMethod,
//   addObjectType, addVariableType, addReferenceType, addDataType, addView, instantiate,
//   addReference, deleteReference, deleteNode, setValue, readValue, setValueCallback,
//   setMethodHandler, setExecutable. NodeSet2 XML files: loadNodeSetXml() in
//   ua/server/nodeset_xml.hpp.
//
// Thread safety: every public member function may be called from any thread. The address
// space is guarded by one reader/writer lock: Browse, TranslateBrowsePaths and Read take it
// shared (so they run concurrently with each other and never wait for one another); Write,
// setValue and structural changes take it exclusively for the few microseconds they need.
// The intended use is that the network thread runs the services and application threads
// update live values with setValue(), or serve them on demand with a read callback.
// Callbacks (value read/write callbacks, method handlers) are always invoked WITHOUT the lock
// held, so they may call back into the AddressSpace (e.g. a method handler may setValue()).
// A value read callback runs on the thread that called read() (usually the network thread):
// it must be fast and must not block. Long-running methods complete asynchronously (see
// MethodHandler).
//
// Roles and permissions (ua/server/roles.hpp): the services take the calling session's
// identity (null: a local call, nothing is checked). Once permissions are configured
// (applyPermissions, setRolePermissions, ...) Browse leaves out the nodes the session may not
// browse, Read, Write and Call answer Bad_UserAccessDenied where the session lacks the
// permission, and UserAccessLevel, UserExecutable, UserWriteMask and UserRolePermissions are
// answered per session. Without any configured the checks are skipped altogether.
//
// Not modelled: AccessRestrictions (reading it is Bad_AttributeIdInvalid); a Browse with a
// View accepts any existing View node but does not restrict the references to it; values are
// always current (maxAge is accepted and ignored).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include "ua/server/node.hpp"
#include "ua/server/numeric_range.hpp"
#include "ua/server/roles.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_ids_variable_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

// Thrown by the application API (never by the services, which report StatusCodes).
struct StructureLayout;  // ua/server/structure_codec.hpp

class AddressSpaceError : public std::runtime_error {
  public:
    AddressSpaceError(StatusCode s, const std::string& what)
        : std::runtime_error(what + ": " + s.toString()), status_(s) {}
    StatusCode status() const { return status_; }

  private:
    StatusCode status_;
};

// ---- value callbacks -------------------------------------------------------------------
// read:  returns the current value (with status and source timestamp as appropriate). The
//        address space applies IndexRange and TimestampsToReturn to it.
// write: receives the complete new value (an IndexRange write is merged into the current
//        value first) after access and type checks; returns Good to accept it. When only
//        `write` is set the accepted value is also stored, so a write callback alone works
//        as a validation / notification hook. With `read` set and `write` unset the value
//        is not writable through the Write service (Bad_NotWritable).
struct ValueCallbacks {
    std::function<DataValue(const NodeId& node)> read;
    std::function<StatusCode(const NodeId& node, const DataValue& value)> write;
};

// ---- methods ---------------------------------------------------------------------------
struct MethodCallContext {
    NodeId objectId;
    NodeId methodId;
    NodeId sessionId;  // as passed to AddressSpace::call (null when called locally)
};

// Completes one method call. Copyable; may be invoked from any thread, once (later calls are
// ignored). If every copy is destroyed without being invoked, the call completes with
// Bad_InternalError so that a forgotten completion never hangs a client request.
class MethodCompletion {
  public:
    MethodCompletion() = default;
    MethodCompletion(const MethodCompletion& other) noexcept;
    MethodCompletion(MethodCompletion&& other) noexcept
        : slot_(std::exchange(other.slot_, nullptr)) {}
    MethodCompletion& operator=(MethodCompletion other) noexcept {
        std::swap(slot_, other.slot_);
        return *this;
    }
    ~MethodCompletion();

    void operator()(StatusCode status, std::vector<Variant> outputs = {}) const;
    void succeed(std::vector<Variant> outputs) const { (*this)(StatusCode{}, std::move(outputs)); }
    void fail(StatusCode status) const { (*this)(status); }
    bool valid() const { return slot_ != nullptr; }

    struct Slot;  // implementation detail: one method of a Call request in flight

  private:
    friend class AddressSpace;
    explicit MethodCompletion(Slot* s) noexcept : slot_(s) {}  // takes over one reference
    Slot* slot_ = nullptr;
};

// The general (asynchronous) form: the handler receives the checked input arguments and a
// completion it calls when done, now or later from any thread. A long-running method
// returns at once and completes from its worker thread; it never blocks the network thread.
using MethodHandler = std::function<void(const MethodCallContext& context,
                                         std::vector<Variant> inputs, MethodCompletion done)>;
// The synchronous convenience form: runs on the calling (network) thread, so it must be quick.
// `inputs` belong to the call: a handler may move them into `outputs` (e.g. an echo).
using SyncMethodHandler = std::function<StatusCode(
    const MethodCallContext& context, std::vector<Variant>& inputs, std::vector<Variant>& outputs)>;
MethodHandler makeMethodHandler(SyncMethodHandler handler);

// ---- browse continuation points ----------------------------------------------------------
// Continuation points of one session (OPC 10000-4 §7.9). The session owns one store and
// passes it to browse() / browseNext(); it is not thread-safe (one session's requests are
// processed one after the other).
class ContinuationPointStore {
  public:
    explicit ContinuationPointStore(std::size_t maxPoints = 16);
    std::size_t size() const { return points_.size(); }
    std::size_t capacity() const { return max_; }
    void clear() { points_.clear(); }

  private:
    friend class AddressSpace;
    struct Point {
        ByteString id;
        BrowseDescription description;
        UInt32 maxReferences = 0;
        std::uint32_t position = 0;  // index into the node's reference list
    };
    bool full() const { return points_.size() >= max_; }
    const ByteString& add(Point p);
    Point* find(const ByteString& id);
    Point take(Point* p);  // removes *p from the store and returns it

    std::vector<Point> points_;
    std::size_t max_;
    std::uint64_t next_;
};

// ---- node attributes for the application API --------------------------------------------
struct NodeAttributes {
    LocalizedText displayName;  // empty: the BrowseName's name
    LocalizedText description;
    UInt32 writeMask = 0;
};

struct ObjectAttributes : NodeAttributes {
    Byte eventNotifier = 0;
    // Create the Mandatory InstanceDeclarations of the type definition (and its supertypes)
    // below the new object, recursively (OPC 10000-3 §6.4.4).
    bool instantiateMandatory = true;
};

struct VariableAttributes : NodeAttributes {
    NodeId dataType = NodeId(0, ns0::BaseDataType);
    Int32 valueRank = -1;  // Scalar
    std::vector<UInt32> arrayDimensions;
    DataValue value;  // initial value (checked against dataType / valueRank)
    Byte accessLevel = access_level::CurrentRead;
    double minimumSamplingInterval = 0;
    bool historizing = false;
    bool instantiateMandatory = true;  // as for objects
};

struct MethodAttributes : NodeAttributes {
    bool executable = true;
};

struct ObjectTypeAttributes : NodeAttributes {
    bool isAbstract = false;
};

struct VariableTypeAttributes : NodeAttributes {
    NodeId dataType = NodeId(0, ns0::BaseDataType);
    Int32 valueRank = -2;  // Any
    std::vector<UInt32> arrayDimensions;
    std::optional<Variant> value;
    bool isAbstract = false;
};

struct ReferenceTypeAttributes : NodeAttributes {
    bool isAbstract = false;
    bool symmetric = false;
    LocalizedText inverseName;
};

struct DataTypeAttributes : NodeAttributes {
    bool isAbstract = false;
    // DataTypeDefinition: an ExtensionObject holding a StructureDefinition or EnumDefinition
    // (empty: none).
    ExtensionObject definition;
};

// What AddressSpace::instantiate creates besides the Mandatory children.
struct InstantiateOptions {
    LocalizedText displayName;  // empty: the BrowseName's name
    // Optional InstanceDeclarations (ModellingRule Optional) to create too, by BrowseName,
    // at any depth below the instance.
    std::vector<QualifiedName> optionalChildren;
    // The reference from the parent; null: as addObject / addVariable choose.
    NodeId referenceType;
    // The new Object's EventNotifier (e.g. 1: SubscribeToEvents, for a state machine whose
    // transition events clients monitor on the machine itself).
    Byte eventNotifier = 0;
};

struct ViewAttributes : NodeAttributes {
    bool containsNoLoops = false;
    Byte eventNotifier = 0;
};

// ---- the address space ---------------------------------------------------------------
class AddressSpace {
  public:
    struct Options {
        // Namespace 1 (OPC 10000-3 §8.2.2: the server's local namespace).
        std::string applicationUri = "urn:pnp:server";
        // Load the full namespace 0 (Opc.Ua.NodeSet2.xml, compiled in at build time).
        bool loadNamespaceZero = true;
        // Server limit on references per node in one Browse result (0: client's choice).
        UInt32 maxReferencesPerNode = 0;
    };

    AddressSpace();
    explicit AddressSpace(Options options);
    ~AddressSpace();
    AddressSpace(const AddressSpace&) = delete;
    AddressSpace& operator=(const AddressSpace&) = delete;

    // ---- introspection ---------------------------------------------------------------
    struct Statistics {
        std::size_t nodes = 0;           // live nodes
        std::size_t references = 0;      // references (each counted once)
        std::size_t bytesUsed = 0;       // heap + touched constant data of the model
        double namespaceZeroLoadMs = 0;  // time spent decoding namespace 0
    };
    Statistics statistics() const;
    bool contains(const NodeId& id) const;
    std::optional<NodeClass> nodeClass(const NodeId& id) const;
    // Follows BrowseNames along hierarchical references (convenience for applications):
    // childOf(ns0::ObjectsFolder, {"Server", "ServerStatus"}).
    std::optional<NodeId> resolvePath(const NodeId& start,
                                      std::span<const QualifiedName> path) const;

    // ---- namespaces ------------------------------------------------------------------
    UInt16 addNamespace(std::string_view uri);  // existing index if already present
    std::optional<UInt16> namespaceIndex(std::string_view uri) const;
    std::vector<String> namespaceArray() const;

    // ---- application API: nodes ---------------------------------------------------------
    // `id` null (ns=N;i=0) asks for a fresh numeric id in namespace N (N=0 means 1).
    // `referenceType` null picks Organizes below a folder (FolderType or subtype, or a View)
    // and HasComponent otherwise. Each returns the new node's id.
    // Objects and variables get copies of the Mandatory children their type definition
    // declares (ids "<parent id>.<BrowseName>" below string ids, fresh numeric ids
    // otherwise); a copied method shares the handler of its declaration unless the
    // application sets one on the copy.
    NodeId addObject(const NodeId& parent, const NodeId& id, const QualifiedName& browseName,
                     const ObjectAttributes& attributes = {},
                     const NodeId& typeDefinition = NodeId(0, ns0::BaseObjectType),
                     const NodeId& referenceType = {});
    NodeId addFolder(const NodeId& parent, const NodeId& id, const QualifiedName& browseName,
                     const ObjectAttributes& attributes = {});
    NodeId addVariable(const NodeId& parent, const NodeId& id, const QualifiedName& browseName,
                       const VariableAttributes& attributes,
                       const NodeId& typeDefinition = NodeId(0, ns0::BaseDataVariableType),
                       const NodeId& referenceType = {});
    // A Property: HasProperty from the parent, type PropertyType.
    NodeId addProperty(const NodeId& parent, const NodeId& id, const QualifiedName& browseName,
                       const VariableAttributes& attributes);
    // Also creates the InputArguments / OutputArguments properties (when non-empty).
    NodeId addMethod(const NodeId& parent, const NodeId& id, const QualifiedName& browseName,
                     const std::vector<Argument>& inputArguments,
                     const std::vector<Argument>& outputArguments, MethodHandler handler,
                     const MethodAttributes& attributes = {},
                     const NodeId& referenceType = NodeId(0, ns0::HasComponent));
    NodeId addObjectType(const NodeId& parentType, const NodeId& id,
                         const QualifiedName& browseName,
                         const ObjectTypeAttributes& attributes = {});
    NodeId addVariableType(const NodeId& parentType, const NodeId& id,
                           const QualifiedName& browseName,
                           const VariableTypeAttributes& attributes = {});
    NodeId addReferenceType(const NodeId& parentType, const NodeId& id,
                            const QualifiedName& browseName,
                            const ReferenceTypeAttributes& attributes = {});
    NodeId addDataType(const NodeId& parentType, const NodeId& id, const QualifiedName& browseName,
                       const DataTypeAttributes& attributes = {});
    NodeId addView(const NodeId& parent, const NodeId& id, const QualifiedName& browseName,
                   const ViewAttributes& attributes = {});

    // Creates an instance of an ObjectType or VariableType below `parent` in one call: an
    // Object or Variable (a Variable takes DataType, ValueRank, ArrayDimensions and Value
    // from its type) with HasTypeDefinition, and the children its InstanceDeclarations
    // require (OPC 10000-3 §6.4): the Mandatory ones of the type, of each supertype and of
    // every interface they implement (HasInterface), the Optional ones listed in `options`;
    // placeholders are never instantiated, ModellingRules never copied.
    NodeId instantiate(const NodeId& parent, const NodeId& type, const NodeId& id,
                       const QualifiedName& browseName, const InstantiateOptions& options = {});

    // References. The target may be a node of another server (not browsed further).
    void addReference(const NodeId& source, const NodeId& referenceType,
                      const ExpandedNodeId& target, bool isForward = true);
    // false when no such reference exists.
    bool deleteReference(const NodeId& source, const NodeId& referenceType,
                         const ExpandedNodeId& target, bool isForward = true);
    // Deletes the node and every reference to or from it; with deleteChildren also the nodes
    // it aggregates (HasComponent / HasProperty / ..., recursively).
    void deleteNode(const NodeId& id, bool deleteChildren = true);
    // Changes whenever nodes or references are added or removed (not on value or attribute
    // writes): a cache of something derived from the graph is valid while it stays the same.
    std::uint64_t structureGeneration() const;

    // ---- application API: values ------------------------------------------------------
    // Sets a Variable's value without access checks but with the type check (returns
    // Bad_TypeMismatch & co. instead of throwing). A source timestamp is added when absent.
    StatusCode setValue(const NodeId& variable, DataValue value);
    // Variables written together again and again (a state machine's state variables): their
    // nodes are looked up once per structure generation instead of on every write. Not
    // thread-safe itself: its owner serialises the writes through it.
    class VariableGroup {
      public:
        explicit VariableGroup(std::vector<NodeId> variables = {})
            : variables_(std::move(variables)) {}
        const std::vector<NodeId>& variables() const { return variables_; }

      private:
        friend class AddressSpace;
        std::vector<NodeId> variables_;
        bool resolved_ = false;
        std::uint64_t generation_ = 0;  // the structure generation nodes_ was resolved in
        std::vector<std::uint32_t> nodes_;
    };
    // Several values of a group as one change: a Read (or a Read request's items, which are
    // read under one lock) sees all of them or none. values[k].first indexes
    // group.variables(); each value is checked as by setValue, a bad one is skipped and the
    // first bad status returned. Methods in the group may be in `executable` (index, flag):
    // set in the same change, as setExecutable().
    StatusCode setValues(VariableGroup& group,
                         std::vector<std::pair<std::size_t, DataValue>> values,
                         const std::vector<std::pair<std::size_t, bool>>& executable = {});
    // The values of a group's variables, as readValue() each (read callbacks included).
    std::vector<DataValue> readValues(VariableGroup& group) const;
    DataValue readValue(const NodeId& variable) const;
    // Serves the value from callbacks (replaces previous callbacks; empty to remove).
    void setValueCallback(const NodeId& variable, ValueCallbacks callbacks);
    void setMethodHandler(const NodeId& method, MethodHandler handler);
    // Sets a Method's Executable and UserExecutable attributes (no WriteMask check, unlike
    // writeAttribute). Bad_NodeIdUnknown / Bad_MethodInvalid instead of throwing.
    StatusCode setExecutable(const NodeId& method, bool executable);
    // Told of every stored value change (setValue, Write) - for the subscription engine.
    // Called with the address space locked exclusively: it must be quick and must not call
    // back into the AddressSpace. One listener; empty to remove.
    using ValueListener = std::function<void(const NodeId& node, const DataValue& value)>;
    void setValueListener(ValueListener listener);

    // ---- roles and permissions (ua/server/roles.hpp) ----------------------------------
    // Replaces every permission setting by `p` (e.g. pnpRolePolicy()).
    void applyPermissions(const PermissionDefaults& p);
    // A node's RolePermissions attribute (nullopt: none, the namespace's or the server's
    // default applies). Throws AddressSpaceError for an unknown node.
    void setRolePermissions(const NodeId& node,
                            std::optional<std::vector<RolePermissionType>> permissions);
    // A namespace's DefaultRolePermissions (nullopt: none, the server's default applies).
    void setNamespaceDefaultRolePermissions(
        UInt16 namespaceIndex, std::optional<std::vector<RolePermissionType>> permissions);
    // The server-wide default (nullopt: every session may do everything).
    void setDefaultRolePermissions(std::optional<std::vector<RolePermissionType>> permissions);
    // The role counts only for sessions on a SignAndEncrypt channel.
    void requireEncryptedChannel(const NodeId& role);
    // Whether any permission is configured (false: the services check nothing).
    bool enforcesPermissions() const;
    // The session's permissions on a node (PermissionType bits); 0 for an unknown node.
    UInt32 userPermissions(const NodeId& node, const SessionIdentity& user) const;
    // The rules in force for a node, for checks made outside the address space's lock (the
    // subscription engine's events): null when everything is allowed.
    struct EffectivePermissions {
        std::shared_ptr<const RolePermissionSet> set;
        std::uint32_t encryptionRequired = 0;
        UInt32 of(const SessionIdentity& user) const {
            return set ? set->permissionsOf(user, encryptionRequired) : permission::All;
        }
    };
    EffectivePermissions effectivePermissions(const NodeId& node) const;

    // ---- services ---------------------------------------------------------------------
    // `user`: the calling session (null: no permission checks).
    BrowseResponse browse(const BrowseRequest& request, ContinuationPointStore& points,
                          const SessionIdentity* user = nullptr) const;
    BrowseNextResponse browseNext(const BrowseNextRequest& request, ContinuationPointStore& points,
                                  const SessionIdentity* user = nullptr) const;
    TranslateBrowsePathsToNodeIdsResponse translateBrowsePaths(
        const TranslateBrowsePathsToNodeIdsRequest& request,
        const SessionIdentity* user = nullptr) const;
    RegisterNodesResponse registerNodes(const RegisterNodesRequest& request) const;
    UnregisterNodesResponse unregisterNodes(const UnregisterNodesRequest& request) const;
    ReadResponse read(const ReadRequest& request, const SessionIdentity* user = nullptr) const;
    WriteResponse write(const WriteRequest& request, const SessionIdentity* user = nullptr);
    // Checks every call, runs the handlers and invokes `done` once all of them completed:
    // before call() returns when every handler completed synchronously, otherwise on the
    // thread of the last completion (the session layer posts it back to its own thread).
    // The rvalue form hands the input arguments to the handlers without copying them.
    void call(CallRequest&& request, const NodeId& sessionId,
              std::function<void(CallResponse)> done, const SessionIdentity* user = nullptr);
    void call(const CallRequest& request, const NodeId& sessionId,
              std::function<void(CallResponse)> done, const SessionIdentity* user = nullptr);
    // Blocks until every method completed (for application threads and tests; never call it
    // on the network thread with asynchronous handlers).
    CallResponse callSync(const CallRequest& request, const NodeId& sessionId = {});

    // ---- single operations ---------------------------------------------------------------
    BrowseResult browse(const BrowseDescription& description, UInt32 maxReferences,
                        ContinuationPointStore& points) const;
    BrowsePathResult translateBrowsePath(const BrowsePath& path) const;
    DataValue read(const ReadValueId& item,
                   TimestampsToReturn timestamps = TimestampsToReturn::Neither,
                   const SessionIdentity* user = nullptr) const;
    DataValue readAttribute(const NodeId& id, AttributeId attribute,
                            std::string_view indexRange = {}) const;
    StatusCode write(const WriteValue& item, const SessionIdentity* user = nullptr);
    StatusCode writeAttribute(const NodeId& id, AttributeId attribute, const Variant& value);

    // ---- type checks (exposed for the session layer and tests) -------------------------
    // Whether a value of built-in type/ExtensionObject content fits DataType `dataType`
    // (subtypes included, OPC 10000-4 §7.7 / 10000-3 §8), with the ValueRank and
    // ArrayDimensions constraints. Good or Bad_TypeMismatch.
    StatusCode checkValue(const Variant& value, const NodeId& dataType, Int32 valueRank,
                          std::span<const UInt32> arrayDimensions = {}) const;
    bool isSubtypeOf(const NodeId& type, const NodeId& base) const;
    // The binary layout of a structure DataType from its DataTypeDefinition, for the dynamic
    // structure codec (ua/server/structure_codec.hpp); nullptr for other nodes.
    std::shared_ptr<const StructureLayout> structureLayout(const NodeId& dataType) const;

    // Internal state (defined in address_space_impl.hpp, private to pnp_ua_server).
    struct Impl;

  private:
    friend struct NodeSetXmlAccess;  // the NodeSet2 XML loader (nodeset_xml.cpp)
    // Serves Server.NamespaceArray from namespaceArray() once namespace 0 is loaded.
    void serveNamespaceArray();
    // The group's nodes, looked up again after a structural change (either lock held).
    static void resolve(const Impl& s, VariableGroup& group);
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::ua::server
