// The client subcommands of `pnp ua`: endpoints, browse, read, write, call, monitor, events.
#include <algorithm>
#include <atomic>
#include <cctype>
#include <csignal>
#include <iostream>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "commands.hpp"
#include "output.hpp"
#include "ua/client/browse_path.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types.hpp"  // the codec registry
#include "ua/types/status_codes.hpp"
#include "value_text.hpp"

namespace pnp::cli {

namespace uac = pnp::ua::client;

namespace {

using uac::AttributeId;

// ---- connection --------------------------------------------------------------------------
uac::ClientConfig clientConfig(const ClientOptions& o) {
    uac::ClientConfig c;
    c.applicationName = kCliApplicationName;
    c.applicationUri = cliApplicationUri();
    c.requestTimeout = std::chrono::milliseconds(o.timeoutMs);
    c.connectTimeout = std::chrono::milliseconds(o.timeoutMs);
    c.closeTimeout = std::chrono::milliseconds(std::min(o.timeoutMs, 1000));
    c.reconnect.enabled = false;  // one-shot commands: fail fast and say why
    c.security = clientSecurity(o.security);
    c.useDefaultSecurity = false;  // --insecure means None
    return c;
}

// reconnect: for long-running commands (monitor, events), which follow the server.
std::unique_ptr<uac::Client> connect(const ClientOptions& o, bool reconnect = false) {
    uac::ClientConfig config = clientConfig(o);
    config.reconnect.enabled = reconnect;
    auto client = std::make_unique<uac::Client>(config);
    uac::Identity identity = uac::Anonymous{};
    if (!o.user.empty()) {
        auto [name, password] = splitUser(o.user);
        identity = uac::UserName{name, password};
    }
    if (auto user = userCertificate(o.security)) {
        if (!o.user.empty()) throw UsageError("--user and --user-cert exclude each other");
        identity = std::move(*user);
    }
    client->connect(o.url, identity);
    return client;
}

void printJson(const Json& j) {
    std::cout << j.dump(2, ' ', false, Json::error_handler_t::replace) << '\n';
}

// ---- nodes -------------------------------------------------------------------------------
constexpr const char* kNodeForms =
    "expected i=85, ns=2;s=Name, nsu=urn:pnp:demo;s=Demo or a browse path like "
    "/Objects/Server/ServerStatus";

// A browse path (from the Root folder) rather than a NodeId.
bool isPath(const std::string& text) {
    return text.starts_with("/") || text.starts_with(".") || text.starts_with("<");
}

// Rejects malformed NODE text before anything is sent (a usage error, exit code 2).
void checkNodeText(const std::string& text) {
    if (isPath(text)) {
        try {
            uac::parseRelativePath(text, [](std::string_view) { return UInt16{0}; });
        } catch (const uac::Error& e) {
            throw UsageError("invalid browse path \"" + text + "\": " + e.what());
        }
        return;
    }
    auto x = ExpandedNodeId::parse(text);
    if (!x || x->serverIndex != 0) throw UsageError("invalid node \"" + text + "\": " + kNodeForms);
}

// Throws client::Error (BadNoMatch, BadNotFound for an unknown namespace URI, ...).
NodeId resolveNode(uac::Client& c, const std::string& text) {
    if (isPath(text)) return c.resolve(text);
    return c.parseNodeId(text);
}

std::string ns0Name(const NodeId& id) {
    if (id.namespaceIndex() != 0 || !id.isNumeric()) return {};
    return std::string(ns0::nameOf(id.numeric()));
}

// "Int32", or the NodeId text when the node has no well-known name.
std::string nodeName(const NodeId& id) {
    std::string n = ns0Name(id);
    return n.empty() ? id.toString() : n;
}

std::string nodeName(const ExpandedNodeId& id) {
    if (id.isLocal()) return nodeName(id.nodeId);
    return id.toString();
}

// ---- attributes --------------------------------------------------------------------------
constexpr const char* kAttributeNames[] = {
    "",
    "NodeId",
    "NodeClass",
    "BrowseName",
    "DisplayName",
    "Description",
    "WriteMask",
    "UserWriteMask",
    "IsAbstract",
    "Symmetric",
    "InverseName",
    "ContainsNoLoops",
    "EventNotifier",
    "Value",
    "DataType",
    "ValueRank",
    "ArrayDimensions",
    "AccessLevel",
    "UserAccessLevel",
    "MinimumSamplingInterval",
    "Historizing",
    "Executable",
    "UserExecutable",
    "DataTypeDefinition",
    "RolePermissions",
    "UserRolePermissions",
    "AccessRestrictions",
    "AccessLevelEx",
};
constexpr UInt32 kAttributeCount = sizeof(kAttributeNames) / sizeof(kAttributeNames[0]);

std::string lower(std::string s) {
    for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
}

UInt32 parseAttribute(const std::string& text) {
    for (UInt32 i = 1; i < kAttributeCount; ++i)
        if (lower(kAttributeNames[i]) == lower(text)) return i;
    try {
        std::size_t used = 0;
        unsigned long n = std::stoul(text, &used);
        if (used == text.size() && n >= 1 && n < kAttributeCount) return static_cast<UInt32>(n);
    } catch (const std::exception&) {
    }
    std::string names;
    for (UInt32 i = 1; i < kAttributeCount; ++i)
        names += std::string(i > 1 ? ", " : "") + kAttributeNames[i];
    throw UsageError("unknown attribute \"" + text + "\"; one of: " + names);
}

std::string accessLevelText(UInt32 bits) {
    static constexpr std::pair<UInt32, const char*> kBits[] = {
        {0x1, "CurrentRead"},          {0x2, "CurrentWrite"},     {0x4, "HistoryRead"},
        {0x8, "HistoryWrite"},         {0x10, "SemanticChange"},  {0x20, "StatusWrite"},
        {0x40, "TimestampWrite"},      {0x100, "NonatomicRead"},  {0x200, "NonatomicWrite"},
        {0x400, "WriteFullArrayOnly"}, {0x800, "NoSubDataTypes"}, {0x1000, "NonVolatile"},
        {0x2000, "Constant"}};
    std::string s;
    for (auto [bit, name] : kBits)
        if (bits & bit) s += (s.empty() ? "" : "|") + std::string(name);
    return s.empty() ? "None" : s;
}

std::string valueRankText(Int32 r) {
    switch (r) {
        case -3:
            return "ScalarOrOneDimension";
        case -2:
            return "Any";
        case -1:
            return "Scalar";
        case 0:
            return "OneOrMoreDimensions";
        case 1:
            return "OneDimension";
        default:
            return r > 1 ? std::to_string(r) + " dimensions" : "";
    }
}

// A readable name for the value of attribute `attr` (NodeClass, AccessLevel, ...), or "".
std::string attributeValueName(UInt32 attr, const Variant& v) {
    switch (static_cast<AttributeId>(attr)) {
        case AttributeId::NodeClass:
            if (auto* i = v.scalar<Int32>())
                return std::string(toString(static_cast<NodeClass>(*i)));
            break;
        case AttributeId::DataType:
            if (auto* n = v.scalar<NodeId>()) return ns0Name(*n);
            break;
        case AttributeId::ValueRank:
            if (auto* i = v.scalar<Int32>()) return valueRankText(*i);
            break;
        case AttributeId::AccessLevel:
        case AttributeId::UserAccessLevel:
            if (auto* b = v.scalar<Byte>()) return accessLevelText(*b);
            break;
        case AttributeId::AccessLevelEx:
            if (auto* u = v.scalar<UInt32>()) return accessLevelText(*u);
            break;
        default:
            break;
    }
    return {};
}

// ---- data types --------------------------------------------------------------------------
std::optional<BuiltinType> ns0BuiltinType(UInt32 id) {
    if (id >= 1 && id <= 21) return static_cast<BuiltinType>(id);
    switch (id) {
        case ns0::Structure:
            return BuiltinType::ExtensionObject;
        case ns0::DataValue:
            return BuiltinType::DataValue;
        case ns0::BaseDataType:
            return BuiltinType::Variant;
        case ns0::DiagnosticInfo:
            return BuiltinType::DiagnosticInfo;
        case ns0::Enumeration:
            return BuiltinType::Int32;
        default:
            return std::nullopt;
    }
}

// The node on the other end of the first inverse reference of type `referenceType` (exactly,
// no subtypes) of `node` on this server: a DataType's supertype (HasSubtype), an encoding's
// DataType (HasEncoding).
std::optional<NodeId> inverseTarget(uac::Client& c, const NodeId& node, UInt32 referenceType) {
    BrowseDescription d;
    d.nodeId = node;
    d.browseDirection = BrowseDirection::Inverse;
    d.referenceTypeId = NodeId(0, referenceType);
    d.includeSubtypes = false;
    d.resultMask = 0x3F;
    BrowseResult r = c.browse(d);
    if (r.statusCode.isBad() || r.references.empty() || !r.references[0].nodeId.isLocal())
        return std::nullopt;
    return r.references[0].nodeId.nodeId;
}

// The built-in type that carries values of DataType `dataType`: known ids directly, others by
// following HasSubtype upwards. The abstract Number / Integer / UInteger take the type of
// `current` when it has one (a Variable's value), or are Variants (a structure field).
enum class AbstractNumbers { FromValue, AsVariant };
BuiltinType builtinTypeOf(uac::Client& c, NodeId dataType, const Variant& current,
                          AbstractNumbers numbers = AbstractNumbers::FromValue) {
    for (int hop = 0; hop < 32; ++hop) {
        if (dataType.namespaceIndex() == 0 && dataType.isNumeric()) {
            UInt32 id = dataType.numeric();
            if (auto t = ns0BuiltinType(id)) return *t;
            if (id == ns0::Number || id == ns0::Integer || id == ns0::UInteger) {
                if (numbers == AbstractNumbers::AsVariant) return BuiltinType::Variant;
                if (!current.isEmpty() && current.type() != BuiltinType::Variant)
                    return current.type();
                return id == ns0::Number    ? BuiltinType::Double
                       : id == ns0::Integer ? BuiltinType::Int64
                                            : BuiltinType::UInt64;
            }
            if (findCodecByDataTypeId(id) != nullptr) return BuiltinType::ExtensionObject;
        }
        auto supertype = inverseTarget(c, dataType, ns0::HasSubtype);
        if (!supertype) break;
        dataType = *supertype;
    }
    throw UsageError("cannot tell the built-in type of DataType " + dataType.toString() +
                     "; give it with --type");
}

// The name of enumeration value `value` of DataType `dataType`, or "".
std::string enumValueName(uac::Client& c, const NodeId& dataType, Int64 value) {
    if (dataType.namespaceIndex() == 0 && dataType.isNumeric() && dataType.numeric() <= 29)
        return {};
    try {
        DataValue def = c.readAttribute(dataType, AttributeId::DataTypeDefinition);
        if (!def.statusOrGood().isBad() && def.value) {
            if (auto* x = def.value->scalar<ExtensionObject>()) {
                if (auto e = fromExtensionObject<EnumDefinition>(*x)) {
                    for (const auto& f : e->fields)
                        if (f.value == value) return f.name.empty() ? f.displayName.text : f.name;
                    return {};
                }
            }
        }
        // Older models: the EnumStrings (index = value) or EnumValues property.
        for (const char* prop : {"EnumStrings", "EnumValues"}) {
            BrowsePath p;
            p.startingNode = dataType;
            RelativePathElement e;
            e.referenceTypeId = NodeId(0, ns0::HasProperty);
            e.includeSubtypes = true;
            e.targetName = QualifiedName{0, prop};
            p.relativePath.elements.push_back(e);
            auto res = c.translateBrowsePaths({p});
            if (res.empty() || res[0].statusCode.isBad() || res[0].targets.empty()) continue;
            DataValue dv = c.readAttribute(res[0].targets[0].targetId.nodeId, AttributeId::Value);
            if (!dv.value) continue;
            if (auto* texts = dv.value->array<LocalizedText>()) {
                if (value >= 0 && static_cast<std::size_t>(value) < texts->size())
                    return (*texts)[static_cast<std::size_t>(value)].text;
            } else if (auto* values = dv.value->array<ExtensionObject>()) {
                for (const auto& x : *values)
                    if (auto ev = fromExtensionObject<EnumValueType>(x); ev && ev->value == value)
                        return ev->displayName.text;
            }
        }
    } catch (const std::exception&) {
        // The name is a nicety: any failure just leaves the number.
    }
    return {};
}

std::vector<std::string> splitList(const std::string& s) {
    std::vector<std::string> out;
    std::string cur;
    for (char ch : s) {
        if (ch == ',') {
            out.push_back(cur);
            cur.clear();
        } else if (ch != ' ') {
            cur += ch;
        }
    }
    out.push_back(cur);
    return out;
}

// DataType descriptions from the server (DataTypeDefinition, IsAbstract, HasSubtype), so that
// structures given as JSON can be encoded.
class ServerTypeCatalog final : public TypeCatalog {
  public:
    explicit ServerTypeCatalog(uac::Client& c) : c_(c) {}

    DataTypeDescription describe(const NodeId& dataType) override {
        DataTypeDescription d;
        d.builtin = builtinTypeOf(c_, dataType, {}, AbstractNumbers::AsVariant);
        if (d.builtin != BuiltinType::ExtensionObject && d.builtin != BuiltinType::Int32) return d;
        if (dataType.namespaceIndex() == 0 && dataType.isNumeric() &&
            dataType.numeric() <= ns0::Enumeration)
            return d;  // built-in and abstract base types have no definition
        std::vector<ReadValueId> req(2);
        req[0].nodeId = req[1].nodeId = dataType;
        req[0].attributeId = static_cast<UInt32>(AttributeId::DataTypeDefinition);
        req[1].attributeId = static_cast<UInt32>(AttributeId::IsAbstract);
        auto res = c_.read(req, TimestampsToReturn::Neither);
        if (res.size() != 2 || !res[0].value) return d;
        const Boolean* isAbstract = res[1].value ? res[1].value->scalar<Boolean>() : nullptr;
        if (const auto* x = res[0].value->scalar<ExtensionObject>()) {
            if (auto sd = fromExtensionObject<StructureDefinition>(*x)) {
                if (d.builtin == BuiltinType::ExtensionObject && !(isAbstract && *isAbstract))
                    d.structure = std::move(*sd);
            } else if (auto ed = fromExtensionObject<EnumDefinition>(*x)) {
                d.enumeration = std::move(*ed);
            }
        }
        return d;
    }

    NodeId dataTypeOfEncoding(const NodeId& encodingId) override {
        return inverseTarget(c_, encodingId, ns0::HasEncoding).value_or(NodeId());
    }

  private:
    uac::Client& c_;
};

ParseOptions parseOptionsFor(uac::Client& c, TypeCatalog& types) {
    ParseOptions p;
    p.namespaceIndex = [&c](std::string_view uri) { return c.namespaceIndex(uri); };
    p.types = &types;
    return p;
}

std::pair<BuiltinType, Shape> parseTypeOption(const std::string& text) {
    auto t = parseTypeName(text);
    if (!t)
        throw UsageError("unknown type \"" + text +
                         "\" (a built-in type name like Int32, "
                         "Double[], String, LocalizedText, ExtensionObject)");
    return *t;
}

}  // namespace

// ---- endpoints ---------------------------------------------------------------------------
int runEndpoints(const ClientOptions& o) {
    uac::Client client(clientConfig(o));
    std::vector<EndpointDescription> eps = client.getEndpoints(o.url);
    if (o.json) {
        Json list = Json::array();
        for (const auto& e : eps) {
            Json tokens = Json::array();
            for (const auto& t : e.userIdentityTokens)
                tokens.push_back({{"policyId", t.policyId},
                                  {"tokenType", std::string(toString(t.tokenType))},
                                  {"securityPolicyUri", t.securityPolicyUri}});
            list.push_back({{"endpointUrl", e.endpointUrl},
                            {"securityMode", std::string(toString(e.securityMode))},
                            {"securityPolicyUri", e.securityPolicyUri},
                            {"securityLevel", e.securityLevel},
                            {"transportProfileUri", e.transportProfileUri},
                            {"userIdentityTokens", tokens},
                            {"server",
                             {{"applicationUri", e.server.applicationUri},
                              {"productUri", e.server.productUri},
                              {"applicationName", e.server.applicationName.text},
                              {"applicationType", std::string(toString(e.server.applicationType))},
                              {"discoveryUrls", e.server.discoveryUrls}}}});
        }
        printJson({{"url", o.url}, {"endpoints", list}});
        return kExitOk;
    }
    if (eps.empty()) {
        std::cout << "no endpoints\n";
        return kExitOk;
    }
    std::cout << "server  " << eps[0].server.applicationName.text << " ("
              << eps[0].server.applicationUri << ")\n\n";
    Table t({"ENDPOINT", "SECURITY MODE", "SECURITY POLICY", "USER TOKENS", "LEVEL"});
    for (const auto& e : eps) {
        std::string tokens;
        for (const auto& u : e.userIdentityTokens)
            tokens += (tokens.empty() ? "" : ", ") + std::string(toString(u.tokenType));
        std::string policy = e.securityPolicyUri;
        if (auto hash = policy.rfind('#'); hash != std::string::npos)
            policy = policy.substr(hash + 1);
        t.add({e.endpointUrl, std::string(toString(e.securityMode)), policy, tokens,
               std::to_string(e.securityLevel)});
    }
    t.print(std::cout);
    return kExitOk;
}

// ---- browse ------------------------------------------------------------------------------
namespace {
struct BrowseWalker {
    uac::Client& client;
    int maxDepth;
    std::set<NodeId> visited;
    Table table{{"BROWSE NAME", "CLASS", "NODE ID", "TYPE DEFINITION", "REFERENCE"}};

    // The references of `node` (as JSON, children nested) and table rows.
    Json walk(const NodeId& node, int depth) {
        Json out = Json::array();
        visited.insert(node);
        std::vector<ReferenceDescription> refs = client.browse(node);
        for (const auto& r : refs) {
            Json j = {{"referenceType", nodeName(r.referenceTypeId)},
                      {"isForward", r.isForward},
                      {"nodeId", r.nodeId.toString()},
                      {"browseName", r.browseName.toString()},
                      {"displayName", r.displayName.text},
                      {"nodeClass", std::string(toString(r.nodeClass))},
                      {"typeDefinition", r.typeDefinition.nodeId.isNull()
                                             ? Json(nullptr)
                                             : Json(r.typeDefinition.toString())}};
            table.add({std::string(2 * (depth - 1), ' ') + r.browseName.toString(),
                       std::string(toString(r.nodeClass)), r.nodeId.toString(),
                       r.typeDefinition.nodeId.isNull() ? "" : nodeName(r.typeDefinition),
                       nodeName(r.referenceTypeId)});
            if (depth < maxDepth && r.nodeId.isLocal() && !visited.contains(r.nodeId.nodeId))
                j["references"] = walk(r.nodeId.nodeId, depth + 1);
            out.push_back(std::move(j));
        }
        return out;
    }
};
}  // namespace

int runBrowse(const ClientOptions& o, const BrowseOptions& b) {
    if (b.depth < 1) throw UsageError("--depth must be at least 1");
    checkNodeText(b.node);
    auto client = connect(o);
    NodeId start = resolveNode(*client, b.node);
    BrowseWalker w{*client, b.depth, {}};
    Json refs = w.walk(start, 1);
    if (o.json) {
        printJson({{"node", b.node}, {"nodeId", start.toString()}, {"references", refs}});
    } else {
        w.table.print(std::cout);
    }
    return kExitOk;
}

// ---- read --------------------------------------------------------------------------------
int runRead(const ClientOptions& o, const ReadOptions& r) {
    const UInt32 attr = parseAttribute(r.attribute);
    for (const auto& n : r.nodes) checkNodeText(n);
    auto client = connect(o);

    struct Item {
        std::string text;
        NodeId id;
        StatusCode resolveStatus;
        DataValue value;
        NodeId dataType;
    };
    std::vector<Item> items;
    std::vector<ReadValueId> request;
    const bool isValue = attr == static_cast<UInt32>(AttributeId::Value);
    for (const auto& n : r.nodes) {
        Item it{n, {}, {}, {}, {}};
        try {
            it.id = resolveNode(*client, n);
        } catch (const uac::Error& e) {
            if (e.status() == status::BadTimeout || e.status() == status::BadConnectionClosed ||
                e.status() == status::BadNotConnected)
                throw;
            it.resolveStatus = e.status();
        }
        if (!it.resolveStatus.isBad()) {
            ReadValueId rv;
            rv.nodeId = it.id;
            rv.attributeId = attr;
            request.push_back(rv);
            if (isValue) {  // the DataType too, for enumeration names
                rv.attributeId = static_cast<UInt32>(AttributeId::DataType);
                request.push_back(rv);
            }
        }
        items.push_back(std::move(it));
    }
    std::vector<DataValue> values;
    if (!request.empty()) values = client->read(request, TimestampsToReturn::Both);
    std::size_t k = 0;
    for (auto& it : items) {
        if (it.resolveStatus.isBad()) {
            it.value.status = it.resolveStatus;
            continue;
        }
        if (k < values.size()) it.value = values[k++];
        if (isValue && k < values.size()) {
            const DataValue& dt = values[k++];
            if (dt.value && dt.value->scalar<NodeId>()) it.dataType = *dt.value->scalar<NodeId>();
        }
    }

    bool anyBad = false;
    Json results = Json::array();
    Table table({"NODE", "ATTRIBUTE", "STATUS", "TYPE", "VALUE"});
    for (auto& it : items) {
        const StatusCode st = it.value.statusOrGood();
        anyBad = anyBad || st.isBad();
        const Variant empty;
        const Variant& v = it.value.value ? *it.value.value : empty;
        std::string name = attributeValueName(attr, v);
        if (isValue && !it.dataType.isNull() && v.isScalar()) {
            if (auto* i = v.scalar<Int32>()) name = enumValueName(*client, it.dataType, *i);
        }
        Json j = {{"node", it.text},
                  {"nodeId", it.resolveStatus.isBad() ? Json(nullptr) : Json(it.id.toString())},
                  {"attribute", kAttributeNames[attr]},
                  {"status", statusText(st)},
                  {"statusCode", st.value},
                  {"type", typeText(v)},
                  {"value", toJson(v)}};
        if (!name.empty()) j["valueName"] = name;
        if (!v.arrayDimensions().empty()) j["arrayDimensions"] = v.arrayDimensions();
        if (isValue && !it.dataType.isNull()) j["dataType"] = it.dataType.toString();
        if (it.value.sourceTimestamp)
            j["sourceTimestamp"] = dateTimeText(*it.value.sourceTimestamp);
        if (it.value.serverTimestamp)
            j["serverTimestamp"] = dateTimeText(*it.value.serverTimestamp);
        results.push_back(std::move(j));

        std::string text = v.isEmpty() && st.isBad() ? "" : toText(v);
        if (!name.empty()) text = name + " (" + text + ")";
        table.add(
            {it.text, kAttributeNames[attr], statusText(st), v.isEmpty() ? "" : typeText(v), text});
    }
    if (o.json)
        printJson({{"results", results}});
    else
        table.print(std::cout);
    return anyBad ? kExitUaError : kExitOk;
}

// ---- write -------------------------------------------------------------------------------
int runWrite(const ClientOptions& o, const WriteOptions& w) {
    checkNodeText(w.node);
    std::optional<std::pair<BuiltinType, Shape>> type;
    if (!w.type.empty()) type = parseTypeOption(w.type);
    auto client = connect(o);
    NodeId id = resolveNode(*client, w.node);

    if (!type) {
        // The node's DataType, ValueRank and current value decide how to read the text.
        std::vector<ReadValueId> req(3);
        for (auto& r : req) r.nodeId = id;
        req[0].attributeId = static_cast<UInt32>(AttributeId::DataType);
        req[1].attributeId = static_cast<UInt32>(AttributeId::ValueRank);
        req[2].attributeId = static_cast<UInt32>(AttributeId::Value);
        auto res = client->read(req, TimestampsToReturn::Neither);
        if (res.size() != 3)
            throw uac::Error(status::BadUnexpectedError, "Read: wrong result count");
        for (int i = 0; i < 2; ++i) {
            if (res[i].statusOrGood().isBad()) {
                StatusCode st = res[i].statusOrGood();
                throw uac::Error(st, "cannot read the " +
                                         std::string(i == 0 ? "DataType" : "ValueRank") + " of " +
                                         w.node);
            }
        }
        const NodeId* dt = res[0].value ? res[0].value->scalar<NodeId>() : nullptr;
        const Int32* rank = res[1].value ? res[1].value->scalar<Int32>() : nullptr;
        if (dt == nullptr || rank == nullptr)
            throw uac::Error(status::BadTypeMismatch,
                             w.node + " has no DataType / ValueRank (not a Variable?)");
        const Variant current = res[2].value ? *res[2].value : Variant();
        type = {builtinTypeOf(*client, *dt, current), shapeOfValueRank(*rank)};
    }
    ServerTypeCatalog catalog(*client);
    Variant value =
        parseValue(w.value, type->first, type->second, parseOptionsFor(*client, catalog));
    StatusCode st = client->writeValue(id, value);
    if (o.json) {
        printJson({{"node", w.node},
                   {"nodeId", id.toString()},
                   {"status", statusText(st)},
                   {"statusCode", st.value},
                   {"type", typeText(value)},
                   {"value", toJson(value)}});
    } else {
        Table t({"NODE", "STATUS", "TYPE", "VALUE"});
        t.add({w.node, statusText(st), typeText(value), toText(value)});
        t.print(std::cout);
    }
    return st.isBad() ? kExitUaError : kExitOk;
}

// ---- call --------------------------------------------------------------------------------
namespace {
// The InputArguments / OutputArguments properties of a method (empty when absent).
std::pair<std::vector<Argument>, std::vector<Argument>> methodArguments(uac::Client& c,
                                                                        const NodeId& method) {
    std::vector<BrowsePath> paths;
    for (const char* name : {"InputArguments", "OutputArguments"}) {
        BrowsePath p;
        p.startingNode = method;
        RelativePathElement e;
        e.referenceTypeId = NodeId(0, ns0::HasProperty);
        e.includeSubtypes = true;
        e.targetName = QualifiedName{0, name};
        p.relativePath.elements.push_back(e);
        paths.push_back(std::move(p));
    }
    auto res = c.translateBrowsePaths(paths);
    // An unknown method node would otherwise look like a method without arguments.
    if (!res.empty() && (res[0].statusCode == StatusCode(status::BadNodeIdUnknown) ||
                         res[0].statusCode == StatusCode(status::BadNodeIdInvalid)))
        throw uac::Error(res[0].statusCode, "no method node " + method.toString());
    std::vector<ReadValueId> reads;
    std::vector<int> which;
    for (int i = 0; i < 2 && i < static_cast<int>(res.size()); ++i) {
        if (res[i].statusCode.isBad() || res[i].targets.empty()) continue;
        ReadValueId r;
        r.nodeId = c.toNodeId(res[i].targets[0].targetId);
        r.attributeId = static_cast<UInt32>(AttributeId::Value);
        reads.push_back(r);
        which.push_back(i);
    }
    std::pair<std::vector<Argument>, std::vector<Argument>> out;
    if (reads.empty()) return out;
    auto values = c.read(reads, TimestampsToReturn::Neither);
    for (std::size_t k = 0; k < values.size() && k < which.size(); ++k) {
        if (!values[k].value) continue;
        auto& list = which[k] == 0 ? out.first : out.second;
        if (auto* xs = values[k].value->array<ExtensionObject>()) {
            for (const auto& x : *xs)
                if (auto a = fromExtensionObject<Argument>(x)) list.push_back(std::move(*a));
        }
    }
    return out;
}

std::string signature(const std::vector<Argument>& args, uac::Client& c) {
    std::string s;
    for (const auto& a : args) {
        std::string t = nodeName(a.dataType);
        try {
            t = std::string(toString(builtinTypeOf(c, a.dataType, {})));
        } catch (const std::exception&) {
        }
        if (a.valueRank >= 1) t += "[]";
        s += (s.empty() ? "" : ", ") + a.name + ": " + t;
    }
    return "(" + s + ")";
}
}  // namespace

int runCall(const ClientOptions& o, const CallOptions& c) {
    checkNodeText(c.object);
    checkNodeText(c.method);
    std::vector<std::pair<BuiltinType, Shape>> explicitTypes;
    if (!c.types.empty()) {
        for (const auto& t : splitList(c.types)) explicitTypes.push_back(parseTypeOption(t));
        if (explicitTypes.size() != c.args.size())
            throw UsageError("--types names " + std::to_string(explicitTypes.size()) +
                             " type(s) for " + std::to_string(c.args.size()) + " argument(s)");
    }
    auto client = connect(o);
    NodeId object = resolveNode(*client, c.object);
    NodeId method = resolveNode(*client, c.method);
    auto [inArgs, outArgs] = methodArguments(*client, method);

    std::vector<Variant> inputs;
    ServerTypeCatalog catalog(*client);
    ParseOptions po = parseOptionsFor(*client, catalog);
    if (!explicitTypes.empty()) {
        for (std::size_t i = 0; i < c.args.size(); ++i)
            inputs.push_back(
                parseValue(c.args[i], explicitTypes[i].first, explicitTypes[i].second, po));
    } else {
        if (inArgs.size() != c.args.size())
            throw UsageError("the method takes " + std::to_string(inArgs.size()) + " argument(s) " +
                             signature(inArgs, *client) + ", got " + std::to_string(c.args.size()));
        for (std::size_t i = 0; i < c.args.size(); ++i) {
            BuiltinType t = builtinTypeOf(*client, inArgs[i].dataType, {});
            try {
                inputs.push_back(
                    parseValue(c.args[i], t, shapeOfValueRank(inArgs[i].valueRank), po));
            } catch (const ValueError& e) {
                throw ValueError("argument " + std::to_string(i + 1) + " (" + inArgs[i].name +
                                 "): " + e.what());
            }
        }
    }

    uac::CallResult r = client->call(object, method, inputs);
    auto outName = [&](std::size_t i) {
        return i < outArgs.size() && !outArgs[i].name.empty() ? outArgs[i].name
                                                              : "output" + std::to_string(i + 1);
    };
    if (o.json) {
        Json outs = Json::array();
        for (std::size_t i = 0; i < r.outputs.size(); ++i)
            outs.push_back({{"name", outName(i)},
                            {"type", typeText(r.outputs[i])},
                            {"value", toJson(r.outputs[i])}});
        Json j = {{"object", c.object},
                  {"objectId", object.toString()},
                  {"method", c.method},
                  {"methodId", method.toString()},
                  {"status", statusText(r.status)},
                  {"statusCode", r.status.value}};
        if (!r.inputArgumentResults.empty()) {
            Json ir = Json::array();
            for (auto s : r.inputArgumentResults) ir.push_back(statusText(s));
            j["inputArgumentResults"] = ir;
        }
        j["outputs"] = outs;
        printJson(j);
    } else {
        std::cout << "status  " << statusText(r.status) << "\n";
        for (std::size_t i = 0; i < r.inputArgumentResults.size(); ++i) {
            if (r.inputArgumentResults[i].isGood()) continue;
            std::cout << "  input " << i + 1
                      << (i < inArgs.size() ? " (" + inArgs[i].name + ")" : std::string()) << ": "
                      << statusText(r.inputArgumentResults[i]) << "\n";
        }
        if (!r.outputs.empty()) {
            std::cout << "\n";
            Table t({"OUTPUT", "TYPE", "VALUE"});
            for (std::size_t i = 0; i < r.outputs.size(); ++i)
                t.add({outName(i), typeText(r.outputs[i]), toText(r.outputs[i])});
            t.print(std::cout);
        }
    }
    return r.status.isBad() ? kExitUaError : kExitOk;
}

// ---- monitor / events --------------------------------------------------------------------
namespace {

std::atomic<bool> g_interrupted{false};

// Counts notifications and runs the client's event loop on this thread (callbacks print
// from here) until Ctrl-C, --count or --duration.
class NotificationLoop {
  public:
    NotificationLoop(int count, int durationMs) : count_(count) {
        g_interrupted = false;
        std::signal(SIGINT, [](int) { g_interrupted = true; });
        std::signal(SIGTERM, [](int) { g_interrupted = true; });
        if (durationMs > 0) end_ = uac::Clock::now() + std::chrono::milliseconds(durationMs);
    }
    ~NotificationLoop() {
        std::signal(SIGINT, SIG_DFL);
        std::signal(SIGTERM, SIG_DFL);
    }
    // One more notification; false once --count is reached.
    bool note() { return count_ <= 0 || ++seen_ <= count_; }
    void run(uac::Client& client) {
        while (!g_interrupted && (count_ <= 0 || seen_ < count_) && uac::Clock::now() < end_)
            client.runIterate(std::chrono::milliseconds(100));
    }

  private:
    int count_;
    int seen_ = 0;
    uac::Clock::time_point end_ = uac::Clock::time_point::max();
};

uac::SubscriptionStatusCallback statusPrinter() {
    return [](const uac::SubscriptionStatus& s) {
        using K = uac::SubscriptionStatus::Kind;
        if (s.kind == K::KeepAlive) return;
        std::cerr << "subscription: " << static_cast<int>(s.kind) << " " << statusText(s.status)
                  << " " << s.message << "\n";
    };
}

}  // namespace

int runMonitor(const ClientOptions& o, const MonitorOptions& m) {
    for (const auto& n : m.nodes) checkNodeText(n);
    if (m.interval <= 0) throw UsageError("--interval must be positive");
    auto client = connect(o, true);
    std::vector<NodeId> ids;
    for (const auto& n : m.nodes) ids.push_back(resolveNode(*client, n));

    NotificationLoop loop(m.count, m.durationMs);
    uac::Subscription sub(*client, {.publishingInterval = m.interval}, statusPrinter());
    std::vector<StatusCode> statuses;
    auto items = sub.monitorValues(
        ids,
        [&](std::size_t i, const DataValue& v) {
            if (!loop.note()) return;
            const Variant empty;
            const Variant& value = v.value ? *v.value : empty;
            std::string time = v.sourceTimestamp ? dateTimeText(*v.sourceTimestamp) : "";
            if (o.json) {
                Json j = {{"node", m.nodes[i]},
                          {"status", statusText(v.statusOrGood())},
                          {"type", typeText(value)},
                          {"value", toJson(value)}};
                if (!time.empty()) j["sourceTimestamp"] = time;
                std::cout << j.dump(-1, ' ', false, Json::error_handler_t::replace) << std::endl;
            } else {
                std::cout << m.nodes[i] << "\t" << time << "\t" << statusText(v.statusOrGood())
                          << "\t" << toText(value) << std::endl;
            }
        },
        {.samplingInterval = m.interval, .queueSize = 10}, &statuses);
    bool anyBad = false;
    for (std::size_t i = 0; i < statuses.size(); ++i) {
        if (!statuses[i].isBad()) continue;
        anyBad = true;
        std::cerr << "error: " << m.nodes[i] << ": " << statusText(statuses[i]) << "\n";
    }
    if (anyBad && std::none_of(items.begin(), items.end(), [](auto& x) { return x.valid(); }))
        return kExitUaError;
    loop.run(*client);
    return anyBad ? kExitUaError : kExitOk;
}

int runEvents(const ClientOptions& o, const EventsOptions& e) {
    checkNodeText(e.node);
    if (e.interval <= 0) throw UsageError("--interval must be positive");
    std::vector<std::string> fields = splitList(e.select);
    std::erase(fields, std::string());
    if (fields.empty()) throw UsageError("--select names no field");
    auto client = connect(o, true);
    NodeId notifier = resolveNode(*client, e.node);

    NotificationLoop loop(e.count, e.durationMs);
    uac::Subscription sub(*client, {.publishingInterval = e.interval}, statusPrinter());
    uac::EventOptions options;
    options.select = fields;
    auto item = sub.monitorEvents(notifier, options, [&](uac::EventFields& f) {
        if (!loop.note()) return;
        if (o.json) {
            Json j = Json::object();
            for (std::size_t i = 0; i < f.size() && i < fields.size(); ++i)
                j[fields[i]] = toJson(f[i]);
            std::cout << j.dump(-1, ' ', false, Json::error_handler_t::replace) << std::endl;
        } else {
            for (std::size_t i = 0; i < f.size() && i < fields.size(); ++i)
                std::cout << (i ? "\t" : "") << fields[i] << "=" << toText(f[i]);
            std::cout << std::endl;
        }
    });
    loop.run(*client);
    return kExitOk;
}

}  // namespace pnp::cli
