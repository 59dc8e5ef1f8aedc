// Attribute Service Set (OPC 10000-4 §5.10): Read, Write, and the value type checks.
#include <algorithm>

#include "ua/server/address_space_impl.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

namespace {

constexpr StatusCode kGood{};

bool isVariableLike(const Node& n) {
    return (n.nodeClass == NodeClassBits::Variable || n.nodeClass == NodeClassBits::VariableType) &&
           n.extra != nullptr;
}

bool isType(const Node& n) {
    return n.nodeClass == NodeClassBits::ObjectType || n.nodeClass == NodeClassBits::VariableType ||
           n.nodeClass == NodeClassBits::ReferenceType || n.nodeClass == NodeClassBits::DataType;
}

void applyTimestamps(DataValue& v, TimestampsToReturn ts, DateTime now) {
    switch (ts) {
        case TimestampsToReturn::Source:
            v.serverTimestamp.reset();
            v.serverPicoseconds.reset();
            break;
        case TimestampsToReturn::Server:
            v.sourceTimestamp.reset();
            v.sourcePicoseconds.reset();
            v.serverTimestamp = now;
            v.serverPicoseconds.reset();
            break;
        case TimestampsToReturn::Both:
            v.serverTimestamp = now;
            v.serverPicoseconds.reset();
            break;
        default:
            v.sourceTimestamp.reset();
            v.sourcePicoseconds.reset();
            v.serverTimestamp.reset();
            v.serverPicoseconds.reset();
            break;
    }
}

// UserAccessLevel = AccessLevel masked by the session's permissions (OPC 10000-3 §8.55).
Byte userAccessLevelOf(UInt32 perms) {
    if (perms == permission::All) return 0xFF;
    Byte keep = access_level::SemanticChange;
    if (perms & permission::Read) keep |= access_level::CurrentRead;
    if (perms & permission::Write)
        keep |=
            access_level::CurrentWrite | access_level::StatusWrite | access_level::TimestampWrite;
    if (perms & permission::ReadHistory) keep |= access_level::HistoryRead;
    if (perms & (permission::InsertHistory | permission::ModifyHistory | permission::DeleteHistory))
        keep |= access_level::HistoryWrite;
    return keep;
}

// UserWriteMask = WriteMask masked: RolePermissions needs WriteRolePermissions, Historizing
// WriteHistorizing, the other attributes WriteAttribute.
constexpr UInt32 kWriteMaskRolePermissions = 1u << 23;
UInt32 userWriteMaskOf(UInt32 perms) {
    if (perms == permission::All) return 0xFFFFFFFFu;
    UInt32 keep = 0;
    if (perms & permission::WriteAttribute)
        keep |= ~(kWriteMaskRolePermissions | write_mask::Historizing);
    if (perms & permission::WriteRolePermissions) keep |= kWriteMaskRolePermissions;
    if (perms & permission::WriteHistorizing) keep |= write_mask::Historizing;
    return keep;
}

DataValue bad(StatusCode s) {
    DataValue v;
    v.status = s;
    return v;
}

bool hasAttribute(const Node& n, AttributeId a) {
    const NodeClassBits c = n.nodeClass;
    switch (a) {
        case AttributeId::NodeId:
        case AttributeId::NodeClass:
        case AttributeId::BrowseName:
        case AttributeId::DisplayName:
        case AttributeId::Description:
        case AttributeId::WriteMask:
        case AttributeId::UserWriteMask:
            return true;
        case AttributeId::IsAbstract:
            return isType(n);
        case AttributeId::Symmetric:
        case AttributeId::InverseName:
            return c == NodeClassBits::ReferenceType && n.extra;
        case AttributeId::ContainsNoLoops:
            return c == NodeClassBits::View;
        case AttributeId::EventNotifier:
            return c == NodeClassBits::Object || c == NodeClassBits::View;
        case AttributeId::Value:
        case AttributeId::DataType:
        case AttributeId::ValueRank:
        case AttributeId::ArrayDimensions:
            return isVariableLike(n);
        case AttributeId::AccessLevel:
        case AttributeId::UserAccessLevel:
        case AttributeId::MinimumSamplingInterval:
        case AttributeId::Historizing:
        case AttributeId::AccessLevelEx:
            return c == NodeClassBits::Variable && n.extra;
        case AttributeId::Executable:
        case AttributeId::UserExecutable:
            return c == NodeClassBits::Method;
        case AttributeId::DataTypeDefinition:
            return c == NodeClassBits::DataType;
        default:
            return false;
    }
}

// Write-mask bit guarding a non-Value attribute (0: never writable).
UInt32 writeMaskBit(AttributeId a) {
    switch (a) {
        case AttributeId::AccessLevel:
            return write_mask::AccessLevel;
        case AttributeId::ArrayDimensions:
            return write_mask::ArrayDimensions;
        case AttributeId::BrowseName:
            return write_mask::BrowseName;
        case AttributeId::ContainsNoLoops:
            return write_mask::ContainsNoLoops;
        case AttributeId::DataType:
            return write_mask::DataType;
        case AttributeId::Description:
            return write_mask::Description;
        case AttributeId::DisplayName:
            return write_mask::DisplayName;
        case AttributeId::EventNotifier:
            return write_mask::EventNotifier;
        case AttributeId::Executable:
            return write_mask::Executable;
        case AttributeId::Historizing:
            return write_mask::Historizing;
        case AttributeId::InverseName:
            return write_mask::InverseName;
        case AttributeId::IsAbstract:
            return write_mask::IsAbstract;
        case AttributeId::MinimumSamplingInterval:
            return write_mask::MinimumSamplingInterval;
        case AttributeId::Symmetric:
            return write_mask::Symmetric;
        case AttributeId::UserAccessLevel:
            return write_mask::UserAccessLevel;
        case AttributeId::UserExecutable:
            return write_mask::UserExecutable;
        case AttributeId::UserWriteMask:
            return write_mask::UserWriteMask;
        case AttributeId::ValueRank:
            return write_mask::ValueRank;
        case AttributeId::WriteMask:
            return write_mask::WriteMask;
        case AttributeId::AccessLevelEx:
            return write_mask::AccessLevelEx;
        default:
            return 0;
    }
}

}  // namespace

// ---- values --------------------------------------------------------------------------------
DataValue AddressSpace::Impl::storedValue(const Node& n) const {
    const ValueSlot& slot = n.extra->value;
    if (slot.owned) return *slot.owned;
    if (slot.encoded != nullptr) {
        try {
            return DataValue(decodeFromBuffer<Variant>(slot.encoded, slot.encodedSize));
        } catch (const DecodeError&) {
            return bad(status::BadInternalError);
        }
    }
    return DataValue(Variant());
}

Variant AddressSpace::Impl::decodeDefinition(const Node& n) const {
    const ValueSlot& slot = n.extra->value;
    if (slot.owned && slot.owned->value) return *slot.owned->value;
    if (slot.encoded != nullptr) {
        try {
            return Variant(decodeFromBuffer<ExtensionObject>(slot.encoded, slot.encodedSize));
        } catch (const DecodeError&) {
        }
    }
    return Variant();
}

std::vector<Argument> AddressSpace::Impl::methodArguments(NodeIndex method,
                                                          const char* name) const {
    std::vector<Argument> args;
    NodeIndex prop = kNoNode;
    for (const Ref& r : nodes[method].refs) {
        if (r.isForward() && !r.isExternal() && r.type == rtHasProperty) {
            const Node& t = nodes[r.target];
            if (t.browseNs == 0 && strings.get(t.browseName) == name) {
                prop = r.target;
                break;
            }
        }
    }
    if (prop == kNoNode || !nodes[prop].extra) return args;
    DataValue v = storedValue(nodes[prop]);
    if (!v.value) return args;
    auto take = [&](const ExtensionObject& x) {
        try {
            if (auto a = fromExtensionObject<Argument>(x)) args.push_back(std::move(*a));
        } catch (const DecodeError&) {
        }
    };
    if (const auto* arr = v.value->array<ExtensionObject>())
        for (const auto& x : *arr) take(x);
    else if (const auto* one = v.value->scalar<ExtensionObject>())
        take(*one);
    return args;
}

std::shared_ptr<const std::vector<Argument>> AddressSpace::Impl::inputArguments(
    NodeIndex method) const {
    {
        std::lock_guard guard(argumentCacheMutex);
        auto it = argumentCache.find(method);
        if (it != argumentCache.end() && it->second.generation == changeGeneration)
            return it->second.arguments;
    }
    auto args =
        std::make_shared<const std::vector<Argument>>(methodArguments(method, "InputArguments"));
    std::lock_guard guard(argumentCacheMutex);
    argumentCache[method] = CachedArguments{changeGeneration, args};
    return args;
}

// ---- type checks ---------------------------------------------------------------------------
bool AddressSpace::Impl::builtinMatches(BuiltinType b, const Variant& v, NodeIndex dataType) const {
    const NodeIndex baseDataType = find(ns0::BaseDataType);
    if (dataType == baseDataType) return true;
    if (b == BuiltinType::Variant || b == BuiltinType::Null) return false;
    if (b == BuiltinType::ExtensionObject) {
        const NodeIndex structure = find(ns0::Structure);
        if (!isSubtype(dataType, structure)) return false;
        if (dataType == structure) return true;
        auto fits = [&](const ExtensionObject& x) {
            if (x.empty()) return true;
            NodeIndex enc = find(x.typeId);
            if (enc == kNoNode) return false;
            NodeIndex dt = kNoNode;
            if (nodes[enc].nodeClass == NodeClassBits::DataType) {
                dt = enc;
            } else {
                for (const Ref& r : nodes[enc].refs)
                    if (r.type == rtHasEncoding && !r.isForward() && !r.isExternal()) {
                        dt = r.target;
                        break;
                    }
            }
            // The body of a structure of a loaded model must decode by its definition.
            return dt != kNoNode && isSubtype(dt, dataType) && bodyFits(x, dt);
        };
        if (const auto* one = v.scalar<ExtensionObject>()) return fits(*one);
        if (const auto* arr = v.array<ExtensionObject>())
            return std::all_of(arr->begin(), arr->end(), fits);
        return false;
    }
    const NodeIndex builtin = find(static_cast<std::uint32_t>(b));
    if (builtin == kNoNode) return false;
    // The value's type is the DataType or one of its subtypes (Int32 for Integer / Number)...
    if (isSubtype(builtin, dataType)) return true;
    // ...or the DataType is a subtype of a built-in type that is encoded as that built-in
    // type (UtcTime/DateTime, Duration/Double, LocaleId/String, option sets over UInt32, ...).
    if (isSubtype(dataType, builtin)) return true;
    // Enumerations are encoded as Int32.
    if (b == BuiltinType::Int32 && isSubtype(dataType, find(ns0::Enumeration))) return true;
    return false;
}

StatusCode AddressSpace::Impl::checkValue(const Variant& v, NodeIndex dataType, Int32 valueRank,
                                          std::span<const UInt32> arrayDimensions,
                                          bool allowEmpty) const {
    if (v.isEmpty()) return allowEmpty ? kGood : status::BadTypeMismatch;
    if (dataType != kNoNode && !builtinMatches(v.type(), v, dataType))
        return status::BadTypeMismatch;
    const std::size_t dims = v.isArray() ? std::max<std::size_t>(1, v.arrayDimensions().size()) : 0;
    bool rankOk = false;
    switch (valueRank) {
        case -3:
            rankOk = dims <= 1;
            break;  // ScalarOrOneDimension
        case -2:
            rankOk = true;
            break;  // Any
        case -1:
            rankOk = dims == 0;
            break;  // Scalar
        case 0:
            rankOk = dims >= 1;
            break;  // OneOrMoreDimensions
        default:
            rankOk = valueRank > 0 && dims == static_cast<std::size_t>(valueRank);
            break;
    }
    if (!rankOk) return status::BadTypeMismatch;
    if (dims > 0 && arrayDimensions.size() == dims) {
        for (std::size_t k = 0; k < dims; ++k) {
            std::size_t actual =
                dims == 1 ? v.arrayLength() : static_cast<std::size_t>(v.arrayDimensions()[k]);
            if (arrayDimensions[k] != 0 && actual > arrayDimensions[k])
                return status::BadTypeMismatch;
        }
    }
    return kGood;
}

StatusCode AddressSpace::checkValue(const Variant& value, const NodeId& dataType, Int32 valueRank,
                                    std::span<const UInt32> arrayDimensions) const {
    std::shared_lock lock(impl_->mutex);
    NodeIndex dt = impl_->find(dataType);
    if (dt == kNoNode || impl_->nodes[dt].nodeClass != NodeClassBits::DataType)
        return status::BadTypeMismatch;
    return impl_->checkValue(value, dt, valueRank, arrayDimensions, false);
}

// ---- Read ----------------------------------------------------------------------------------
DataValue AddressSpace::Impl::readAttribute(std::shared_lock<std::shared_mutex>& lock,
                                            const ReadValueId& item, TimestampsToReturn timestamps,
                                            const SessionIdentity* user) const {
    const NodeIndex i = find(item.nodeId);
    if (i == kNoNode) return bad(status::BadNodeIdUnknown);
    const auto attr = static_cast<AttributeId>(item.attributeId);
    const Node& n = nodes[i];
    // The session's permissions (OPC 10000-3 §8.55): Read for the Value, ReadRolePermissions
    // for RolePermissions, Browse for the other attributes.
    const bool checked = checksPermissions(user);
    const UInt32 perms = checked ? userPermissions(i, user) : permission::All;
    if (checked) {
        const UInt32 needed = attr == AttributeId::Value ? permission::Read
                              : attr == AttributeId::RolePermissions
                                  ? permission::ReadRolePermissions
                              : attr == AttributeId::UserRolePermissions ? 0u
                                                                         : permission::Browse;
        if ((perms & needed) != needed) return bad(status::BadUserAccessDenied);
    }

    if (!item.dataEncoding.name.empty() || item.dataEncoding.namespaceIndex != 0) {
        const auto& name = item.dataEncoding.name;
        if (attr != AttributeId::Value) return bad(status::BadDataEncodingInvalid);
        if (item.dataEncoding.namespaceIndex != 0 ||
            (name != "Default Binary" && name != "Default XML" && name != "Default JSON"))
            return bad(status::BadDataEncodingInvalid);
        if (name != "Default Binary") return bad(status::BadDataEncodingUnsupported);
        if (!isVariableLike(n) || !isSubtype(find(n.extra->dataType), find(ns0::Structure)))
            return bad(status::BadDataEncodingInvalid);
    }
    std::optional<NumericRange> range;
    if (!item.indexRange.empty()) {
        range = NumericRange::parse(item.indexRange);
        if (!range) return bad(status::BadIndexRangeInvalid);
    }

    const NodeClassBits cls = n.nodeClass;
    Variant v;
    auto invalid = [] { return bad(status::BadAttributeIdInvalid); };
    switch (attr) {
        case AttributeId::Value: {
            if (!isVariableLike(n)) return invalid();
            if (cls == NodeClassBits::Variable) {
                if (!(n.extra->accessLevel & access_level::CurrentRead))
                    return bad(status::BadNotReadable);
                if (!(n.extra->userAccessLevel & access_level::CurrentRead))
                    return bad(status::BadUserAccessDenied);
            }
            DataValue dv;
            if (n.extra->value.callbacks && n.extra->value.callbacks->read) {
                auto callbacks = n.extra->value.callbacks;
                NodeId id = idOf(i);
                lock.unlock();
                try {
                    dv = callbacks->read(id);
                } catch (...) {
                    dv = bad(status::BadInternalError);
                }
                lock.lock();
            } else {
                dv = storedValue(n);
            }
            if (range && dv.value) {
                Variant cut;
                StatusCode s = readRange(*dv.value, *range, cut);
                if (s.isBad()) return bad(s);
                dv.value = std::move(cut);
            } else if (range && dv.statusOrGood().isGood()) {
                return bad(status::BadIndexRangeNoData);
            }
            applyTimestamps(dv, timestamps, DateTime::now());
            return dv;
        }
        case AttributeId::NodeId:
            v = Variant(idOf(i));
            break;
        case AttributeId::NodeClass:
            v = Variant(static_cast<Int32>(cls));
            break;
        case AttributeId::BrowseName:
            v = Variant(browseNameOf(n));
            break;
        case AttributeId::DisplayName:
            v = Variant(displayNameOf(n));
            break;
        case AttributeId::Description:
            v = Variant(LocalizedText(String(strings.get(n.descriptionLocale)),
                                      String(strings.get(n.descriptionText))));
            break;
        case AttributeId::WriteMask:
            v = Variant(n.writeMask);
            break;
        case AttributeId::UserWriteMask:
            v = Variant(n.userWriteMask & userWriteMaskOf(perms));
            break;
        case AttributeId::IsAbstract:
            if (!isType(n)) return invalid();
            v = Variant(n.has(Node::kIsAbstract));
            break;
        case AttributeId::Symmetric:
            if (cls != NodeClassBits::ReferenceType) return invalid();
            v = Variant(n.has(Node::kSymmetric));
            break;
        case AttributeId::InverseName:
            if (cls != NodeClassBits::ReferenceType) return invalid();
            if (n.extra && n.extra->hasInverseName)
                v = Variant(LocalizedText(String(strings.get(n.extra->inverseLocale)),
                                          String(strings.get(n.extra->inverseText))));
            else
                v = Variant(LocalizedText());
            break;
        case AttributeId::ContainsNoLoops:
            if (cls != NodeClassBits::View) return invalid();
            v = Variant(n.has(Node::kContainsNoLoops));
            break;
        case AttributeId::EventNotifier:
            if (cls != NodeClassBits::Object && cls != NodeClassBits::View) return invalid();
            v = Variant(n.eventNotifier);
            break;
        case AttributeId::DataType:
            if (!isVariableLike(n)) return invalid();
            v = Variant(expand(n.extra->dataType));
            break;
        case AttributeId::ValueRank:
            if (!isVariableLike(n)) return invalid();
            v = Variant(n.extra->valueRank);
            break;
        case AttributeId::ArrayDimensions:
            if (!isVariableLike(n)) return invalid();
            v = Variant(n.extra->arrayDimensions);
            break;
        case AttributeId::AccessLevel:
        case AttributeId::UserAccessLevel:
        case AttributeId::AccessLevelEx:
        case AttributeId::MinimumSamplingInterval:
        case AttributeId::Historizing:
            if (cls != NodeClassBits::Variable || !n.extra) return invalid();
            if (attr == AttributeId::AccessLevel)
                v = Variant(n.extra->accessLevel);
            else if (attr == AttributeId::UserAccessLevel)
                v = Variant(static_cast<Byte>(n.extra->userAccessLevel & userAccessLevelOf(perms)));
            else if (attr == AttributeId::AccessLevelEx)
                v = Variant(static_cast<UInt32>(n.extra->accessLevel));
            else if (attr == AttributeId::MinimumSamplingInterval)
                v = Variant(n.extra->minimumSamplingInterval);
            else
                v = Variant(n.has(Node::kHistorizing));
            break;
        case AttributeId::Executable:
            if (cls != NodeClassBits::Method) return invalid();
            v = Variant(n.has(Node::kExecutable));
            break;
        case AttributeId::UserExecutable:
            if (cls != NodeClassBits::Method) return invalid();
            v = Variant(n.has(Node::kUserExecutable) && (perms & permission::Call) != 0);
            break;
        case AttributeId::RolePermissions:
        case AttributeId::UserRolePermissions: {
            // Only where permissions are configured (before: not modelled at all).
            if (!permissions.active) return invalid();
            const auto* set = permissionSetOf(i);
            std::vector<RolePermissionType> list;
            if (set && attr == AttributeId::RolePermissions)
                list = (*set)->entries();
            else if (set)
                list = user ? (*set)->entriesOf(*user, permissions.encryptionRequired)
                            : (*set)->entries();
            std::vector<ExtensionObject> encoded;
            encoded.reserve(list.size());
            for (const auto& e : list) encoded.push_back(toExtensionObject(e));
            v = Variant(std::move(encoded));
            break;
        }
        case AttributeId::DataTypeDefinition:
            if (cls != NodeClassBits::DataType || !n.extra || n.extra->value.empty())
                return invalid();
            v = decodeDefinition(n);
            break;
        default:
            // AccessRestrictions is not modelled.
            return invalid();
    }
    DataValue dv;
    if (range) {
        Variant cut;
        StatusCode s = readRange(v, *range, cut);
        if (s.isBad()) return bad(s);
        dv.value = std::move(cut);
    } else {
        dv.value = std::move(v);
    }
    if (timestamps == TimestampsToReturn::Server || timestamps == TimestampsToReturn::Both)
        dv.serverTimestamp = DateTime::now();
    return dv;
}

ReadResponse AddressSpace::read(const ReadRequest& request, const SessionIdentity* user) const {
    ReadResponse response;
    const auto ts = static_cast<Int32>(request.timestampsToReturn);
    if (request.nodesToRead.empty()) {
        response.responseHeader.serviceResult = status::BadNothingToDo;
        return response;
    }
    if (ts < 0 || ts > 3) {
        response.responseHeader.serviceResult = status::BadTimestampsToReturnInvalid;
        return response;
    }
    if (request.maxAge < 0) {
        response.responseHeader.serviceResult = status::BadMaxAgeInvalid;
        return response;
    }
    response.results.reserve(request.nodesToRead.size());
    std::shared_lock lock(impl_->mutex);
    for (const auto& item : request.nodesToRead)
        response.results.push_back(
            impl_->readAttribute(lock, item, request.timestampsToReturn, user));
    return response;
}

DataValue AddressSpace::read(const ReadValueId& item, TimestampsToReturn timestamps,
                             const SessionIdentity* user) const {
    const auto ts = static_cast<Int32>(timestamps);
    if (ts < 0 || ts > 3) return bad(status::BadTimestampsToReturnInvalid);
    std::shared_lock lock(impl_->mutex);
    return impl_->readAttribute(lock, item, timestamps, user);
}

DataValue AddressSpace::readAttribute(const NodeId& id, AttributeId attribute,
                                      std::string_view indexRange) const {
    ReadValueId item;
    item.nodeId = id;
    item.attributeId = static_cast<UInt32>(attribute);
    item.indexRange = String(indexRange);
    return read(item, TimestampsToReturn::Neither);
}

// ---- Write ---------------------------------------------------------------------------------
StatusCode AddressSpace::Impl::writeAttribute(std::unique_lock<std::shared_mutex>& lock,
                                              const WriteValue& item, bool checkAccess,
                                              const SessionIdentity* user) {
    NodeIndex i = find(item.nodeId);
    if (i == kNoNode) return status::BadNodeIdUnknown;
    const auto attr = static_cast<AttributeId>(item.attributeId);
    if (item.attributeId == 0 || item.attributeId > static_cast<UInt32>(AttributeId::AccessLevelEx))
        return status::BadAttributeIdInvalid;
    const DataValue& dv = item.value;
    if (checksPermissions(user)) {
        // Write for the Value, WriteHistorizing / WriteRolePermissions for those, WriteAttribute
        // for the others (OPC 10000-3 §8.55).
        const UInt32 needed = attr == AttributeId::Value         ? permission::Write
                              : attr == AttributeId::Historizing ? permission::WriteHistorizing
                              : attr == AttributeId::RolePermissions
                                  ? permission::WriteRolePermissions
                                  : permission::WriteAttribute;
        if ((userPermissions(i, user) & needed) != needed) return status::BadUserAccessDenied;
    }

    if (attr != AttributeId::Value) {
        Node& n = nodes[i];
        if (!hasAttribute(n, attr)) return status::BadAttributeIdInvalid;
        const UInt32 bit = writeMaskBit(attr);
        if (bit == 0) return status::BadNotWritable;
        if (checkAccess && !(n.writeMask & bit)) return status::BadNotWritable;
        if (checkAccess && !(n.userWriteMask & bit)) return status::BadUserAccessDenied;
        if (!item.indexRange.empty()) return status::BadWriteNotSupported;
        if (!dv.value) return status::BadTypeMismatch;
        const Variant& v = *dv.value;
        auto asLt = [&]() { return v.scalar<LocalizedText>(); };
        switch (attr) {
            case AttributeId::DisplayName:
            case AttributeId::Description:
            case AttributeId::InverseName: {
                const LocalizedText* lt = asLt();
                if (!lt) return status::BadTypeMismatch;
                StrId loc = strings.intern(lt->locale), txt = strings.intern(lt->text);
                if (attr == AttributeId::DisplayName) {
                    n.displayLocale = loc;
                    n.displayText = txt;
                } else if (attr == AttributeId::Description) {
                    n.descriptionLocale = loc;
                    n.descriptionText = txt;
                } else {
                    n.extra->inverseLocale = loc;
                    n.extra->inverseText = txt;
                    n.extra->hasInverseName = !lt->text.empty();
                }
                return kGood;
            }
            case AttributeId::BrowseName: {
                const auto* q = v.scalar<QualifiedName>();
                if (!q) return status::BadTypeMismatch;
                if (q->name.empty()) return status::BadBrowseNameInvalid;
                n.browseNs = q->namespaceIndex;
                n.browseName = strings.intern(q->name);
                return kGood;
            }
            case AttributeId::WriteMask:
            case AttributeId::UserWriteMask: {
                const auto* m = v.scalar<UInt32>();
                if (!m) return status::BadTypeMismatch;
                (attr == AttributeId::WriteMask ? n.writeMask : n.userWriteMask) = *m;
                return kGood;
            }
            case AttributeId::IsAbstract:
            case AttributeId::Symmetric:
            case AttributeId::ContainsNoLoops:
            case AttributeId::Historizing:
            case AttributeId::Executable:
            case AttributeId::UserExecutable: {
                const auto* b = v.scalar<Boolean>();
                if (!b) return status::BadTypeMismatch;
                std::uint8_t f = attr == AttributeId::IsAbstract        ? Node::kIsAbstract
                                 : attr == AttributeId::Symmetric       ? Node::kSymmetric
                                 : attr == AttributeId::ContainsNoLoops ? Node::kContainsNoLoops
                                 : attr == AttributeId::Historizing     ? Node::kHistorizing
                                 : attr == AttributeId::Executable      ? Node::kExecutable
                                                                        : Node::kUserExecutable;
                n.set(f, *b);
                return kGood;
            }
            case AttributeId::EventNotifier:
            case AttributeId::AccessLevel:
            case AttributeId::UserAccessLevel: {
                const auto* b = v.scalar<Byte>();
                if (!b) return status::BadTypeMismatch;
                if (attr == AttributeId::EventNotifier)
                    n.eventNotifier = *b;
                else if (attr == AttributeId::AccessLevel)
                    n.extra->accessLevel = *b;
                else
                    n.extra->userAccessLevel = *b;
                return kGood;
            }
            case AttributeId::AccessLevelEx: {
                const auto* b = v.scalar<UInt32>();
                if (!b) return status::BadTypeMismatch;
                if (*b > 0xFF) return status::BadNotSupported;
                n.extra->accessLevel = static_cast<Byte>(*b);
                return kGood;
            }
            case AttributeId::MinimumSamplingInterval: {
                const auto* d = v.scalar<Double>();
                if (!d) return status::BadTypeMismatch;
                n.extra->minimumSamplingInterval = *d;
                return kGood;
            }
            case AttributeId::ValueRank: {
                const auto* r = v.scalar<Int32>();
                if (!r) return status::BadTypeMismatch;
                if (*r < -3) return status::BadOutOfRange;
                n.extra->valueRank = *r;
                return kGood;
            }
            case AttributeId::ArrayDimensions: {
                const auto* a = v.array<UInt32>();
                if (!a) return status::BadTypeMismatch;
                n.extra->arrayDimensions = *a;
                return kGood;
            }
            case AttributeId::DataType: {
                const auto* d = v.scalar<NodeId>();
                if (!d) return status::BadTypeMismatch;
                NodeIndex dt = find(*d);
                if (dt == kNoNode || nodes[dt].nodeClass != NodeClassBits::DataType)
                    return status::BadTypeMismatch;
                n.extra->dataType = compact(*d);
                return kGood;
            }
            default:
                return status::BadNotWritable;
        }
    }

    // ---- Value ----
    {
        Node& n = nodes[i];
        if (!isVariableLike(n)) return status::BadAttributeIdInvalid;
        const bool isVariable = n.nodeClass == NodeClassBits::Variable;
        const Byte al = n.extra->accessLevel;
        if (checkAccess) {
            if (isVariable) {
                if (!(al & access_level::CurrentWrite)) return status::BadNotWritable;
                if (!(n.extra->userAccessLevel & access_level::CurrentWrite))
                    return status::BadUserAccessDenied;
            } else if (!(n.writeMask & write_mask::ValueForVariableType)) {
                return status::BadNotWritable;
            }
            // Status and timestamps are written only where the AccessLevel says so.
            if (dv.serverTimestamp || dv.serverPicoseconds) return status::BadWriteNotSupported;
            if (dv.status && dv.status->value != 0 && !(al & access_level::StatusWrite))
                return status::BadWriteNotSupported;
            if ((dv.sourceTimestamp || dv.sourcePicoseconds) &&
                !(al & access_level::TimestampWrite))
                return status::BadWriteNotSupported;
        }
    }
    std::optional<NumericRange> range;
    if (!item.indexRange.empty()) {
        range = NumericRange::parse(item.indexRange);
        if (!range) return status::BadIndexRangeInvalid;
    }
    auto callbacks = nodes[i].extra->value.callbacks;
    if (callbacks && callbacks->read && !callbacks->write) return status::BadNotWritable;
    const NodeId id = idOf(i);

    DataValue next;
    next.status = dv.status;
    next.sourceTimestamp = dv.sourceTimestamp;
    next.sourcePicoseconds = dv.sourcePicoseconds;
    if (range) {
        DataValue current;
        if (callbacks && callbacks->read) {
            lock.unlock();
            try {
                current = callbacks->read(id);
            } catch (...) {
                current = bad(status::BadInternalError);
            }
            lock.lock();
            i = find(id);
            if (i == kNoNode) return status::BadNodeIdUnknown;
        } else {
            current = storedValue(nodes[i]);
        }
        if (!current.value || !dv.value) return status::BadIndexRangeNoData;
        Variant merged = std::move(*current.value);
        StatusCode s = writeRange(merged, *range, *dv.value);
        if (s.isBad()) return s;
        next.value = std::move(merged);
    } else {
        next.value = dv.value ? *dv.value : Variant();
    }
    {
        const NodeExtra& x = *nodes[i].extra;
        StatusCode c =
            checkValue(*next.value, find(x.dataType), x.valueRank, x.arrayDimensions, true);
        if (c.isBad()) return c;
    }
    if (callbacks && callbacks->write) {
        lock.unlock();
        StatusCode s;
        try {
            s = callbacks->write(id, next);
        } catch (...) {
            s = status::BadInternalError;
        }
        lock.lock();
        if (s.isBad() || callbacks->read) return s;
        i = find(id);
        if (i == kNoNode || !nodes[i].extra) return status::BadNodeIdUnknown;
    }
    storeValue(*nodes[i].extra, std::move(next));
    valueStored(i);
    ++changeGeneration;  // the lock may have been released for a write callback
    return kGood;
}

WriteResponse AddressSpace::write(const WriteRequest& request, const SessionIdentity* user) {
    WriteResponse response;
    if (request.nodesToWrite.empty()) {
        response.responseHeader.serviceResult = status::BadNothingToDo;
        return response;
    }
    response.results.reserve(request.nodesToWrite.size());
    auto lock = impl_->lockForValueChange();
    for (const auto& item : request.nodesToWrite)
        response.results.push_back(impl_->writeAttribute(lock, item, true, user));
    return response;
}

StatusCode AddressSpace::write(const WriteValue& item, const SessionIdentity* user) {
    auto lock = impl_->lockForValueChange();
    return impl_->writeAttribute(lock, item, true, user);
}

StatusCode AddressSpace::writeAttribute(const NodeId& id, AttributeId attribute,
                                        const Variant& value) {
    WriteValue item;
    item.nodeId = id;
    item.attributeId = static_cast<UInt32>(attribute);
    item.value = DataValue(value);
    auto lock = impl_->lockForValueChange();
    return impl_->writeAttribute(lock, item, true);
}

}  // namespace pnp::ua::server
