// NodeSet2 XML loader (see nodeset_xml.hpp). Three passes over one parsed file, all under
// the address space's exclusive lock: (1) create every node, (2) create the references in
// one shared array per file (as the compiled ns0 blob does: no per-node allocation), (3)
// DataTypeDefinitions, then values, which need the DataTypes' supertypes and encodings.
#include "ua/server/nodeset_xml.hpp"

#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <pugixml.hpp>
#include <set>
#include <unordered_set>

#include "ua/server/address_space_impl.hpp"
#include "ua/server/structure_codec.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_types_parameters.hpp"

#ifndef PNP_NODESET_DIR_DEFAULT
#define PNP_NODESET_DIR_DEFAULT ""
#endif

namespace pnp::ua::server {

// Grants the loader the address space's internals (declared a friend of AddressSpace).
struct NodeSetXmlAccess {
    static AddressSpace::Impl& impl(AddressSpace& s) { return *s.impl_; }
    static const AddressSpace::Impl& impl(const AddressSpace& s) { return *s.impl_; }
    static void serveNamespaceArray(AddressSpace& s) { s.serveNamespaceArray(); }
};

namespace {

constexpr std::uintmax_t kMaxFileBytes = 256u << 20;
constexpr int kMaxValueDepth = 32;
constexpr std::string_view kUaUri = "http://opcfoundation.org/UA/";

std::string_view localName(const pugi::xml_node& n) {
    std::string_view s = n.name();
    auto colon = s.find(':');
    return colon == std::string_view::npos ? s : s.substr(colon + 1);
}

pugi::xml_node child(const pugi::xml_node& n, std::string_view name) {
    for (pugi::xml_node c = n.first_child(); c; c = c.next_sibling())
        if (c.type() == pugi::node_element && localName(c) == name) return c;
    return {};
}

std::string_view trim(std::string_view s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
    return s;
}

bool parseBool(std::string_view s) {
    s = trim(s);
    return s == "true" || s == "1";
}

// The <Models> section of a file: its ModelUris and RequiredModels, read from the head of
// the file only (it precedes the nodes), so that a search path is indexed without parsing
// whole files.
struct ModelHeader {
    std::vector<std::string> models;
    std::vector<std::string> required;
};

// The elements <NamespaceUris> and <Models> precede the nodes: the head of the file is read
// until both are complete (or the nodes begin), at most 16 MiB.
ModelHeader readModelHeader(const std::filesystem::path& file) {
    ModelHeader h;
    std::ifstream in(file, std::ios::binary);
    std::string head;
    for (std::size_t chunk = 64 * 1024; in && head.size() < (16u << 20); chunk *= 2) {
        const std::size_t had = head.size();
        head.resize(had + chunk);
        in.read(head.data() + had, static_cast<std::streamsize>(chunk));
        head.resize(had + static_cast<std::size_t>(in.gcount()));
        if (head.find("</Models>") != std::string::npos) break;
        bool nodesBegun = false;  // a node element other than the root <UANodeSet>
        for (auto p = head.find("<UA"); p != std::string::npos && !nodesBegun;
             p = head.find("<UA", p + 3))
            nodesBegun = head.compare(p, 10, "<UANodeSet") != 0;
        if (nodesBegun) break;
    }
    pugi::xml_document doc;  // holds one section at a time
    auto section = [&](std::string_view open, std::string_view close) -> pugi::xml_node {
        auto b = head.find(open);
        auto e = head.find(close);
        if (b == std::string::npos || e == std::string::npos || e < b) return {};
        doc.reset();
        std::string part = head.substr(b, e + close.size() - b);
        return doc.load_buffer(part.data(), part.size()) ? doc.first_child() : pugi::xml_node{};
    };
    for (pugi::xml_node m : section("<Models", "</Models>").children()) {
        if (localName(m) != "Model") continue;
        h.models.emplace_back(m.attribute("ModelUri").value());
        for (pugi::xml_node r : m.children())
            if (localName(r) == "RequiredModel")
                h.required.emplace_back(r.attribute("ModelUri").value());
    }
    // Older files have no <Models>: their first namespace stands for the model.
    if (h.models.empty())
        for (pugi::xml_node u : section("<NamespaceUris", "</NamespaceUris>").children())
            if (u.type() == pugi::node_element) {
                h.models.emplace_back(trim(u.child_value()));
                break;
            }
    return h;
}

using Impl = AddressSpace::Impl;

class FileLoader {
  public:
    FileLoader(Impl& s, const std::filesystem::path& file, NodeSetLoadReport& report)
        : s_(s), file_(file), report_(report) {}

    void load() {
        std::error_code ec;
        auto size = std::filesystem::file_size(file_, ec);
        if (ec) fail("cannot read the file (" + ec.message() + ")");
        if (size > kMaxFileBytes) fail("file larger than 256 MiB");
        pugi::xml_parse_result r =
            doc_.load_file(file_.c_str(), pugi::parse_default, pugi::encoding_utf8);
        if (!r) fail("malformed XML at byte " + std::to_string(r.offset) + ": " + r.description());
        root_ = doc_.document_element();
        if (localName(root_) != "UANodeSet") fail("the root element is not <UANodeSet>");
        const auto first = static_cast<NodeIndex>(s_.nodes.size());
        const std::size_t namespacesBefore = s_.namespaces.size();
        try {
            readNamespaces();
            readAliases();
            createNodes();
            createReferences();
            createDefinitions();
            setValues();
        } catch (...) {
            // A file loads completely or not at all: drop its nodes, their references and
            // the namespaces it added (none of the remaining nodes can use them).
            for (auto i = static_cast<NodeIndex>(s_.nodes.size()); i-- > first;)
                s_.deleteNode(i, false);
            s_.namespaces.resize(namespacesBefore);
            s_.rememberWellKnownRefTypes();
            throw;
        }
    }

  private:
    [[noreturn]] void fail(const std::string& what) const {
        throw NodeSetError(status::BadDecodingError, file_.string() + ": " + what);
    }
    [[noreturn]] void failAt(const pugi::xml_node& el, const std::string& what) const {
        std::string id = el.attribute("NodeId").value();
        throw NodeSetError(status::BadDecodingError, file_.string() + ": node " + id + " (" +
                                                         std::string(localName(el)) + "): " + what);
    }

    // ---- namespaces and ids ---------------------------------------------------------------
    void readNamespaces() {
        nsMap_.assign(1, 0);
        for (pugi::xml_node u : child(root_, "NamespaceUris").children()) {
            if (u.type() != pugi::node_element) continue;
            std::string uri(trim(u.child_value()));
            UInt16 idx = 0;
            bool found = false;
            for (std::size_t i = 0; i < s_.namespaces.size(); ++i)
                if (s_.namespaces[i] == uri) {
                    idx = static_cast<UInt16>(i);
                    found = true;
                    break;
                }
            if (!found) {
                if (s_.namespaces.size() >= 0xFFFF) fail("too many namespaces");
                s_.namespaces.push_back(uri);
                idx = static_cast<UInt16>(s_.namespaces.size() - 1);
            }
            nsMap_.push_back(idx);
        }
    }
    UInt16 mapNs(std::uint64_t ns, const pugi::xml_node& el) const {
        if (ns >= nsMap_.size())
            failAt(el, "namespace index " + std::to_string(ns) + " is not in <NamespaceUris>");
        return nsMap_[ns];
    }
    void readAliases() {
        for (pugi::xml_node a : child(root_, "Aliases").children()) {
            if (a.type() != pugi::node_element) continue;
            std::string_view text = trim(a.child_value());
            auto id = NodeId::parse(text);
            if (!id)
                fail("alias " + std::string(a.attribute("Alias").value()) + ": bad NodeId '" +
                     std::string(text) + "'");
            id->setNamespaceIndex(mapNs(id->namespaceIndex(), a));
            aliases_[a.attribute("Alias").value()] = std::move(*id);
        }
    }
    NodeId nodeId(std::string_view text, const pugi::xml_node& el) const {
        text = trim(text);
        if (auto a = aliases_.find(std::string(text)); a != aliases_.end()) return a->second;
        auto id = NodeId::parse(text);
        if (!id) failAt(el, "bad NodeId or unknown alias '" + std::string(text) + "'");
        id->setNamespaceIndex(mapNs(id->namespaceIndex(), el));
        return std::move(*id);
    }
    QualifiedName qualifiedName(std::string_view text, const pugi::xml_node& el) const {
        QualifiedName q;
        auto colon = text.find(':');
        std::uint32_t ns = 0;
        if (colon != std::string_view::npos && colon > 0 &&
            std::from_chars(text.data(), text.data() + colon, ns).ptr == text.data() + colon) {
            q.namespaceIndex = mapNs(ns, el);
            q.name = std::string(text.substr(colon + 1));
        } else {
            q.name = std::string(text);
        }
        return q;
    }
    template <class T>
    T number(std::string_view text, const pugi::xml_node& el, std::string_view what) const {
        text = trim(text);
        T v{};
        if constexpr (std::is_floating_point_v<T>) {
            if (text == "INF") return std::numeric_limits<T>::infinity();
            if (text == "-INF") return -std::numeric_limits<T>::infinity();
            if (text == "NaN") return std::numeric_limits<T>::quiet_NaN();
            std::string s(text);
            char* end = nullptr;
            double d = std::strtod(s.c_str(), &end);
            if (s.empty() || end != s.c_str() + s.size())
                failAt(el, std::string(what) + ": bad number '" + s + "'");
            return static_cast<T>(d);
        } else {
            if (text.empty()) return v;
            auto [p, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
            if (ec != std::errc() || p != text.data() + text.size())
                failAt(el, std::string(what) + ": bad number '" + std::string(text) + "'");
            return v;
        }
    }
    StrId str(std::string_view s) { return s.empty() ? 0 : s_.strings.intern(s); }

    // ---- pass 1: nodes --------------------------------------------------------------------
    static NodeClassBits classOf(std::string_view tag) {
        if (tag == "UAObject") return NodeClassBits::Object;
        if (tag == "UAVariable") return NodeClassBits::Variable;
        if (tag == "UAMethod") return NodeClassBits::Method;
        if (tag == "UAObjectType") return NodeClassBits::ObjectType;
        if (tag == "UAVariableType") return NodeClassBits::VariableType;
        if (tag == "UAReferenceType") return NodeClassBits::ReferenceType;
        if (tag == "UADataType") return NodeClassBits::DataType;
        if (tag == "UAView") return NodeClassBits::View;
        return NodeClassBits::Unspecified;
    }

    void createNodes() {
        for (pugi::xml_node el = root_.first_child(); el; el = el.next_sibling()) {
            if (el.type() != pugi::node_element) continue;
            const NodeClassBits cls = classOf(localName(el));
            if (cls == NodeClassBits::Unspecified) continue;
            ++elementCount_;
        }
        s_.nodes.reserve(s_.nodes.size() + elementCount_);
        elements_.reserve(elementCount_);
        for (pugi::xml_node el = root_.first_child(); el; el = el.next_sibling()) {
            if (el.type() != pugi::node_element) continue;
            const NodeClassBits cls = classOf(localName(el));
            if (cls == NodeClassBits::Unspecified) continue;
            createNode(el, cls);
        }
        report_.nodes = elements_.size();
    }

    void createNode(const pugi::xml_node& el, NodeClassBits cls) {
        const pugi::xml_attribute idAttr = el.attribute("NodeId");
        if (!idAttr) failAt(el, "no NodeId");
        NodeId id = nodeId(idAttr.value(), el);
        if (s_.find(id) != kNoNode) failAt(el, "NodeId already exists in the address space");
        const pugi::xml_attribute bnAttr = el.attribute("BrowseName");
        if (!bnAttr || !*bnAttr.value()) failAt(el, "no BrowseName");
        QualifiedName bn = qualifiedName(bnAttr.value(), el);

        const auto index = static_cast<NodeIndex>(s_.nodes.size());
        Node& n = s_.nodes.emplace_back();
        n.nodeClass = cls;
        n.flags = Node::kAlive;
        s_.registerId(index, id);
        ++s_.liveNodes;  // counted at once: a failure below rolls the node back
        n.browseNs = bn.namespaceIndex;
        n.browseName = str(bn.name);
        if (pugi::xml_node dn = child(el, "DisplayName")) {
            n.displayLocale = str(dn.attribute("Locale").value());
            n.displayText = str(dn.child_value());
        } else {
            n.displayText = n.browseName;
        }
        if (pugi::xml_node d = child(el, "Description")) {
            n.descriptionLocale = str(d.attribute("Locale").value());
            n.descriptionText = str(d.child_value());
        }
        n.writeMask = number<UInt32>(el.attribute("WriteMask").value(), el, "WriteMask");
        n.userWriteMask =
            el.attribute("UserWriteMask")
                ? number<UInt32>(el.attribute("UserWriteMask").value(), el, "UserWriteMask")
                : n.writeMask;
        n.set(Node::kIsAbstract, parseBool(el.attribute("IsAbstract").value()));
        n.set(Node::kSymmetric, parseBool(el.attribute("Symmetric").value()));
        n.set(Node::kContainsNoLoops, parseBool(el.attribute("ContainsNoLoops").value()));
        n.set(Node::kHistorizing, parseBool(el.attribute("Historizing").value()));
        const bool executable = parseBool(el.attribute("Executable").as_string("true"));
        n.set(Node::kExecutable, executable);
        n.set(Node::kUserExecutable,
              parseBool(el.attribute("UserExecutable").as_string(executable ? "true" : "false")));
        switch (cls) {
            case NodeClassBits::Object:
            case NodeClassBits::View:
                n.eventNotifier =
                    number<Byte>(el.attribute("EventNotifier").value(), el, "EventNotifier");
                break;
            case NodeClassBits::Variable:
            case NodeClassBits::VariableType: {
                auto x = std::make_unique<NodeExtra>();
                x->dataType = s_.compact(nodeId(el.attribute("DataType").as_string("i=24"), el));
                x->valueRank =
                    number<Int32>(el.attribute("ValueRank")
                                      .as_string(cls == NodeClassBits::Variable ? "-1" : "-2"),
                                  el, "ValueRank");
                std::string_view dims = el.attribute("ArrayDimensions").value();
                while (!trim(dims).empty()) {
                    auto comma = dims.find(',');
                    x->arrayDimensions.push_back(
                        number<UInt32>(dims.substr(0, comma), el, "ArrayDimensions"));
                    dims = comma == std::string_view::npos ? std::string_view{}
                                                           : dims.substr(comma + 1);
                }
                if (cls == NodeClassBits::Variable) {
                    x->accessLevel =
                        number<Byte>(el.attribute("AccessLevel").as_string("1"), el, "AccessLevel");
                    x->userAccessLevel = el.attribute("UserAccessLevel")
                                             ? number<Byte>(el.attribute("UserAccessLevel").value(),
                                                            el, "UserAccessLevel")
                                             : x->accessLevel;
                    x->minimumSamplingInterval =
                        number<double>(el.attribute("MinimumSamplingInterval").as_string("0"), el,
                                       "MinimumSamplingInterval");
                }
                n.extra = std::move(x);
                break;
            }
            case NodeClassBits::ReferenceType: {
                auto x = std::make_unique<NodeExtra>();
                if (pugi::xml_node inv = child(el, "InverseName")) {
                    x->inverseLocale = str(inv.attribute("Locale").value());
                    x->inverseText = str(inv.child_value());
                    x->hasInverseName = true;
                }
                s_.nodes[index].extra = std::move(x);
                s_.addRefType(index);
                break;
            }
            default:
                break;
        }
        elements_.push_back({el, index});
    }

    // ---- pass 2: references ---------------------------------------------------------------
    struct Triple {
        NodeIndex source;
        std::uint16_t type;
        NodeIndex target;
        bool operator==(const Triple&) const = default;
    };
    struct TripleHash {
        std::size_t operator()(const Triple& t) const {
            return std::hash<std::uint64_t>()((std::uint64_t(t.source) << 32) ^ t.target ^
                                              (std::uint64_t(t.type) << 48));
        }
    };

    void createReferences() {
        std::vector<Triple> refs;
        std::unordered_set<Triple, TripleHash> seen;
        std::unordered_map<std::string, std::uint16_t> typeCache;
        for (const auto& [el, index] : elements_) {
            for (pugi::xml_node r : child(el, "References").children()) {
                if (r.type() != pugi::node_element) continue;
                std::string typeText(trim(r.attribute("ReferenceType").value()));
                auto tc = typeCache.find(typeText);
                std::uint16_t type;
                if (tc != typeCache.end()) {
                    type = tc->second;
                } else {
                    type = s_.refTypeIndexOf(s_.find(nodeId(typeText, el)));
                    if (type == kNoRefType)
                        failAt(el, "reference type '" + typeText + "' is not a ReferenceType");
                    typeCache.emplace(typeText, type);
                }
                const NodeId targetId = nodeId(r.child_value(), el);
                const NodeIndex target = s_.find(targetId);
                if (target == kNoNode) {
                    report_.warnings.push_back("node " +
                                               std::string(el.attribute("NodeId").value()) +
                                               ": reference target " + targetId.toString() +
                                               " does not exist (reference skipped)");
                    continue;
                }
                const bool forward = parseBool(r.attribute("IsForward").as_string("true"));
                Triple t = forward ? Triple{index, type, target} : Triple{target, type, index};
                if (seen.insert(t).second) refs.push_back(t);
            }
        }
        // Ends on nodes of this file go into one shared array; ends on nodes that existed
        // before are appended to their own lists.
        const NodeIndex first = elements_.empty() ? 0 : elements_.front().second;
        const std::size_t count = s_.nodes.size() - first;
        std::vector<std::uint32_t> slot(count + 1, 0);
        std::size_t pooled = 0;
        for (const Triple& t : refs) {
            if (t.source >= first) ++slot[t.source - first + 1], ++pooled;
            if (t.target >= first) ++slot[t.target - first + 1], ++pooled;
        }
        for (std::size_t k = 0; k < count; ++k) slot[k + 1] += slot[k];
        std::vector<std::uint32_t> fill(slot.begin(), slot.end() - 1);
        std::unique_ptr<Ref[]> pool(new Ref[pooled == 0 ? 1 : pooled]);
        for (const Triple& t : refs) {
            const Ref fwd{t.target, t.type, 0}, inv{t.source, t.type, Ref::kInverse};
            if (t.source >= first)
                pool[fill[t.source - first]++] = fwd;
            else
                s_.nodes[t.source].refs.push_back(fwd);
            if (t.target >= first)
                pool[fill[t.target - first]++] = inv;
            else
                s_.nodes[t.target].refs.push_back(inv);
        }
        for (std::size_t k = 0; k < count; ++k)
            if (slot[k + 1] != slot[k])
                s_.nodes[first + k].refs = RefList(pool.get() + slot[k], slot[k + 1] - slot[k]);
        s_.referenceCount += refs.size();
        s_.refPoolBytes += pooled * sizeof(Ref);
        s_.refPools.push_back(std::move(pool));
        report_.references = refs.size();
        s_.rememberWellKnownRefTypes();
        s_.rebuildSubtypeClosure();
    }

    // ---- pass 3a: DataTypeDefinitions -------------------------------------------------------
    NodeIndex ns0(std::uint32_t id) const { return s_.find(id); }
    bool isSubtypeOfNs0(NodeIndex t, std::uint32_t base) const {
        NodeIndex b = ns0(base);
        return b != kNoNode && s_.isSubtype(t, b);
    }
    NodeIndex encodingOf(NodeIndex dt, std::string_view name) const {
        for (const Ref& r : s_.nodes[dt].refs)
            if (r.type == s_.rtHasEncoding && r.isForward() && !r.isExternal() &&
                s_.strings.get(s_.nodes[r.target].browseName) == name)
                return r.target;
        return kNoNode;
    }

    void createDefinitions() {
        for (const auto& [el, index] : elements_)
            if (s_.nodes[index].nodeClass == NodeClassBits::DataType && child(el, "Definition"))
                pendingDefinitions_.emplace(index, el);
        while (!pendingDefinitions_.empty()) definitionOf(pendingDefinitions_.begin()->first, 0);
    }

    // Builds (once) the DataTypeDefinition of a DataType of this file; the supertype's first,
    // because a StructureDefinition lists the inherited fields too.
    void definitionOf(NodeIndex dt, int depth) {
        auto it = pendingDefinitions_.find(dt);
        if (it == pendingDefinitions_.end()) return;
        const pugi::xml_node el = it->second;
        pendingDefinitions_.erase(it);
        if (depth > 64) failAt(el, "DataType supertype chain too deep");
        const pugi::xml_node def = child(el, "Definition");
        const NodeIndex super = s_.supertypeOf(dt);
        ExtensionObject body;
        if (isSubtypeOfNs0(dt, ns0::Enumeration) ||
            parseBool(def.attribute("IsOptionSet").value())) {
            EnumDefinition e;
            for (pugi::xml_node f : def.children()) {
                if (localName(f) != "Field") continue;
                EnumField ef;
                ef.name = f.attribute("Name").value();
                ef.value = number<Int64>(f.attribute("Value").as_string("0"), el, "Field Value");
                if (pugi::xml_node dn = child(f, "DisplayName"))
                    ef.displayName =
                        LocalizedText(dn.attribute("Locale").value(), dn.child_value());
                else
                    ef.displayName = LocalizedText("", ef.name);
                if (pugi::xml_node d = child(f, "Description"))
                    ef.description = LocalizedText(d.attribute("Locale").value(), d.child_value());
                e.fields.push_back(std::move(ef));
            }
            body = toExtensionObject(e);
        } else {
            StructureDefinition sd;
            if (!s_.nodes[dt].has(Node::kIsAbstract)) {
                NodeIndex enc = encodingOf(dt, "Default Binary");
                if (enc != kNoNode) sd.defaultEncodingId = s_.idOf(enc);
            }
            sd.baseDataType = super != kNoNode ? s_.idOf(super) : NodeId(0, ns0::Structure);
            std::vector<StructureField> inherited;
            if (super != kNoNode) {
                definitionOf(super, depth + 1);
                if (auto base = structureDefinitionOf(super)) inherited = std::move(base->fields);
            }
            std::vector<StructureField> own;
            bool subtyped = false;
            for (pugi::xml_node f : def.children()) {
                if (localName(f) != "Field") continue;
                StructureField sf;
                sf.name = f.attribute("Name").value();
                if (pugi::xml_node d = child(f, "Description"))
                    sf.description = LocalizedText(d.attribute("Locale").value(), d.child_value());
                sf.dataType = nodeId(f.attribute("DataType").as_string("i=24"), el);
                sf.valueRank =
                    number<Int32>(f.attribute("ValueRank").as_string("-1"), el, "ValueRank");
                std::string_view dims = f.attribute("ArrayDimensions").value();
                while (!trim(dims).empty()) {
                    auto comma = dims.find(',');
                    sf.arrayDimensions.push_back(
                        number<UInt32>(dims.substr(0, comma), el, "ArrayDimensions"));
                    dims = comma == std::string_view::npos ? std::string_view{}
                                                           : dims.substr(comma + 1);
                }
                sf.maxStringLength = number<UInt32>(f.attribute("MaxStringLength").as_string("0"),
                                                    el, "MaxStringLength");
                const bool allowSubTypes = parseBool(f.attribute("AllowSubTypes").value());
                subtyped = subtyped || allowSubTypes;
                sf.isOptional = parseBool(f.attribute("IsOptional").value()) || allowSubTypes;
                own.push_back(std::move(sf));
            }
            // Some files repeat the inherited fields in <Definition>, most do not.
            bool repeats = own.size() >= inherited.size();
            for (std::size_t k = 0; repeats && k < inherited.size(); ++k)
                repeats = own[k].name == inherited[k].name;
            if (!repeats) own.insert(own.begin(), inherited.begin(), inherited.end());
            sd.fields = std::move(own);
            const bool optional = std::any_of(sd.fields.begin(), sd.fields.end(),
                                              [](const StructureField& f) { return f.isOptional; });
            const bool isUnion =
                parseBool(def.attribute("IsUnion").value()) || isSubtypeOfNs0(dt, ns0::Union);
            sd.structureType =
                isUnion ? (subtyped ? StructureType::UnionWithSubtypedValues : StructureType::Union)
                : subtyped ? StructureType::StructureWithSubtypedValues
                : optional ? StructureType::StructureWithOptionalFields
                           : StructureType::Structure;
            body = toExtensionObject(sd);
        }
        auto& extra = s_.nodes[dt].extra;
        if (!extra) extra = std::make_unique<NodeExtra>();
        extra->value.owned = std::make_unique<DataValue>(Variant(std::move(body)));
    }

    std::optional<StructureDefinition> structureDefinitionOf(NodeIndex dt) const {
        const Node& n = s_.nodes[dt];
        if (n.nodeClass != NodeClassBits::DataType || !n.extra) return std::nullopt;
        Variant v = s_.decodeDefinition(n);
        const ExtensionObject* x = v.scalar<ExtensionObject>();
        if (x == nullptr) return std::nullopt;
        try {
            return fromExtensionObject<StructureDefinition>(*x);
        } catch (const DecodeError&) {
            return std::nullopt;
        }
    }

    // ---- structure layouts --------------------------------------------------------------------
  public:
    std::shared_ptr<const StructureLayout> layoutOf(NodeIndex dt) {
        if (auto it = layouts_.find(dt); it != layouts_.end()) return it->second;
        auto layout = buildLayout(s_, dt);
        layouts_.emplace(dt, layout);
        return layout;
    }

    static std::shared_ptr<const StructureLayout> buildLayout(const Impl& s, NodeIndex dt) {
        const Node& n = s.nodes[dt];
        if (n.nodeClass != NodeClassBits::DataType || !n.extra) return nullptr;
        Variant v = s.decodeDefinition(n);
        const ExtensionObject* x = v.scalar<ExtensionObject>();
        if (x == nullptr) return nullptr;
        std::optional<StructureDefinition> sd;
        try {
            sd = fromExtensionObject<StructureDefinition>(*x);
        } catch (const DecodeError&) {
        }
        if (!sd) return nullptr;
        auto layout = std::make_shared<StructureLayout>();
        layout->dataType = s.idOf(dt);
        layout->binaryEncoding = sd->defaultEncodingId;
        if (layout->binaryEncoding.isNull()) {
            for (const Ref& r : n.refs)
                if (r.type == s.rtHasEncoding && r.isForward() && !r.isExternal() &&
                    s.strings.get(s.nodes[r.target].browseName) == "Default Binary")
                    layout->binaryEncoding = s.idOf(r.target);
        }
        const bool subtyped = sd->structureType == StructureType::StructureWithSubtypedValues ||
                              sd->structureType == StructureType::UnionWithSubtypedValues;
        layout->form = (sd->structureType == StructureType::Union ||
                        sd->structureType == StructureType::UnionWithSubtypedValues)
                           ? StructureLayout::Form::Union
                       : sd->structureType == StructureType::StructureWithOptionalFields
                           ? StructureLayout::Form::WithOptionalFields
                           : StructureLayout::Form::Plain;
        for (const StructureField& f : sd->fields) {
            StructureFieldLayout fl;
            fl.name = f.name;
            fl.dataType = f.dataType;
            fl.valueRank = f.valueRank;
            fl.isOptional = f.isOptional && !subtyped;
            classifyField(s, fl, subtyped && f.isOptional);
            layout->fields.push_back(std::move(fl));
        }
        return layout;
    }

    // How a field of DataType fl.dataType is encoded: walk up to the first type of ns0 that
    // decides it (a built-in type, Structure, Enumeration or BaseDataType).
    static void classifyField(const Impl& s, StructureFieldLayout& fl, bool allowSubtypes) {
        NodeIndex t = s.find(fl.dataType);
        const bool abstract = t != kNoNode && s.nodes[t].has(Node::kIsAbstract);
        for (int depth = 0; t != kNoNode && depth < 64; ++depth, t = s.supertypeOf(t)) {
            const Node& n = s.nodes[t];
            if (n.ns != 0 || n.idKind != 0) continue;
            const std::uint32_t id = n.idValue;
            if (id == ns0::Structure) {
                fl.kind = (abstract || allowSubtypes) ? StructureFieldLayout::Kind::ExtensionObject
                                                      : StructureFieldLayout::Kind::Structure;
                return;
            }
            if (id == ns0::Enumeration) {
                fl.kind = StructureFieldLayout::Kind::Builtin;
                fl.builtin = BuiltinType::Int32;
                return;
            }
            if (id == ns0::BaseDataType || id == ns0::Number || id == ns0::Integer ||
                id == ns0::UInteger || id == ns0::Decimal) {
                fl.kind = StructureFieldLayout::Kind::Variant;
                return;
            }
            if (id >= 1 && id <= 25) {
                fl.kind = StructureFieldLayout::Kind::Builtin;
                fl.builtin = static_cast<BuiltinType>(id);
                return;
            }
        }
        fl.kind = StructureFieldLayout::Kind::Variant;  // unknown type: the most general
    }

  private:
    // ---- pass 3b: values ---------------------------------------------------------------------
    void setValues() {
        for (const auto& [el, index] : elements_) {
            const NodeClassBits cls = s_.nodes[index].nodeClass;
            if (cls != NodeClassBits::Variable && cls != NodeClassBits::VariableType) continue;
            pugi::xml_node v = child(el, "Value");
            if (!v) continue;
            pugi::xml_node inner;
            for (pugi::xml_node c = v.first_child(); c; c = c.next_sibling())
                if (c.type() == pugi::node_element) {
                    inner = c;
                    break;
                }
            if (!inner) continue;
            current_ = el;
            Variant value = variant(inner, 0);
            s_.nodes[index].extra->value.owned = std::make_unique<DataValue>(std::move(value));
        }
    }

    [[noreturn]] void badValue(const std::string& what) const {
        failAt(current_, "<Value>: " + what);
    }

    // A Variant from a typed element: <Int32>, <ListOfString>, <Matrix>, <ExtensionObject>...
    Variant variant(const pugi::xml_node& el, int depth) {
        if (depth > kMaxValueDepth) badValue("nested too deeply");
        std::string_view name = localName(el);
        if (name == "Matrix") {
            std::vector<Int32> dims;
            for (pugi::xml_node d : child(el, "Dimensions").children())
                if (d.type() == pugi::node_element)
                    dims.push_back(number<Int32>(d.child_value(), current_, "Matrix dimension"));
            pugi::xml_node elements = child(el, "Elements");
            pugi::xml_node firstEl = elements.find_child(
                [](pugi::xml_node c) { return c.type() == pugi::node_element; });
            if (!firstEl) return Variant();
            auto b = builtinTypeFromName(localName(firstEl));
            if (!b) badValue("unknown type " + std::string(localName(firstEl)));
            Variant v = list(*b, elements, depth);
            v.setArrayDimensions(std::move(dims));
            return v;
        }
        if (name.starts_with("ListOf")) {
            auto b = builtinTypeFromName(name.substr(6));
            if (!b) badValue("unknown type " + std::string(name));
            return list(*b, el, depth);
        }
        auto b = builtinTypeFromName(name);
        if (!b) badValue("unknown type " + std::string(name));
        return scalar(*b, el, depth);
    }

    Variant list(BuiltinType b, const pugi::xml_node& el, int depth) {
        std::vector<Variant> items;
        for (pugi::xml_node c : el.children())
            if (c.type() == pugi::node_element)
                items.push_back(b == BuiltinType::Variant ? variantField(c, depth + 1)
                                                          : scalar(b, c, depth + 1));
        if (b == BuiltinType::Variant) return Variant(std::move(items));
        try {
            return arrayOf(b, std::move(items));
        } catch (const std::invalid_argument& e) {
            badValue(e.what());
        }
    }

    // A BaseDataType field or list element: <Value><Int32>..</Int32></Value> or <Int32> itself.
    Variant variantField(const pugi::xml_node& el, int depth) {
        pugi::xml_node inner = el;
        if (localName(inner) == "Variant" || localName(inner) == "Value" ||
            !builtinTypeFromName(localName(inner)))
            inner =
                inner.find_child([](pugi::xml_node c) { return c.type() == pugi::node_element; });
        if (inner && localName(inner) == "Value")
            inner =
                inner.find_child([](pugi::xml_node c) { return c.type() == pugi::node_element; });
        if (!inner) return Variant();
        return variant(inner, depth + 1);
    }

    NodeId valueNodeId(const pugi::xml_node& el) {
        std::string_view text = trim(child(el, "Identifier").child_value());
        if (text.empty()) return NodeId();
        return nodeId(text, current_);
    }

    // The scalar of built-in type b held by element el (whose own name may be a field name).
    Variant scalar(BuiltinType b, const pugi::xml_node& el, int depth) {
        std::string_view text = el.child_value();
        switch (b) {
            case BuiltinType::Boolean:
                return Variant(Boolean(parseBool(text)));
            case BuiltinType::SByte:
                return Variant(number<SByte>(text, current_, "SByte"));
            case BuiltinType::Byte:
                return Variant(number<Byte>(text, current_, "Byte"));
            case BuiltinType::Int16:
                return Variant(number<Int16>(text, current_, "Int16"));
            case BuiltinType::UInt16:
                return Variant(number<UInt16>(text, current_, "UInt16"));
            case BuiltinType::Int32:
                return Variant(number<Int32>(text, current_, "Int32"));
            case BuiltinType::UInt32:
                return Variant(number<UInt32>(text, current_, "UInt32"));
            case BuiltinType::Int64:
                return Variant(number<Int64>(text, current_, "Int64"));
            case BuiltinType::UInt64:
                return Variant(number<UInt64>(text, current_, "UInt64"));
            case BuiltinType::Float:
                return Variant(number<Float>(text, current_, "Float"));
            case BuiltinType::Double:
                return Variant(number<Double>(text, current_, "Double"));
            case BuiltinType::String:
                return Variant(String(text));
            case BuiltinType::DateTime: {
                if (trim(text).empty()) return Variant(DateTime{});
                auto t = DateTime::parseIso8601(trim(text));
                if (!t) badValue("bad DateTime '" + std::string(text) + "'");
                return Variant(*t);
            }
            case BuiltinType::Guid: {
                std::string_view g =
                    trim(child(el, "String") ? child(el, "String").child_value() : text);
                if (g.empty()) return Variant(Guid{});
                auto guid = Guid::parse(g);
                if (!guid) badValue("bad Guid '" + std::string(g) + "'");
                return Variant(*guid);
            }
            case BuiltinType::ByteString: {
                std::string compact;
                for (char c : text)
                    if (!std::isspace(static_cast<unsigned char>(c))) compact.push_back(c);
                auto bytes = ByteString::fromBase64(compact);
                if (!bytes) badValue("bad base64 in a ByteString");
                return Variant(std::move(*bytes));
            }
            case BuiltinType::XmlElement: {
                std::ostringstream out;
                for (pugi::xml_node c : el.children()) c.print(out, "", pugi::format_raw);
                return Variant(XmlElement{out.str()});
            }
            case BuiltinType::NodeId:
                return Variant(valueNodeId(el));
            case BuiltinType::ExpandedNodeId:
                return Variant(ExpandedNodeId(valueNodeId(el)));
            case BuiltinType::StatusCode: {
                std::string_view code = trim(child(el, "Code").child_value());
                UInt32 v = 0;
                if (code.starts_with("0x") || code.starts_with("0X")) {
                    auto [p, ec] =
                        std::from_chars(code.data() + 2, code.data() + code.size(), v, 16);
                    if (ec != std::errc() || p != code.data() + code.size())
                        badValue("bad StatusCode");
                } else {
                    v = number<UInt32>(code, current_, "StatusCode");
                }
                return Variant(StatusCode{v});
            }
            case BuiltinType::QualifiedName: {
                QualifiedName q;
                q.namespaceIndex = mapNs(number<UInt16>(child(el, "NamespaceIndex").child_value(),
                                                        current_, "NamespaceIndex"),
                                         current_);
                q.name = child(el, "Name").child_value();
                return Variant(std::move(q));
            }
            case BuiltinType::LocalizedText:
                return Variant(LocalizedText(std::string(trim(child(el, "Locale").child_value())),
                                             child(el, "Text").child_value()));
            case BuiltinType::ExtensionObject:
                return Variant(extensionObject(el, depth));
            case BuiltinType::Variant:
                return variantField(el, depth);
            default:
                badValue("values of type " + std::string(toString(b)) + " are not supported");
        }
    }

    NodeIndex dataTypeOfEncoding(const NodeId& typeId) const {
        NodeIndex enc = s_.find(typeId);
        if (enc == kNoNode) return kNoNode;
        if (s_.nodes[enc].nodeClass == NodeClassBits::DataType) return enc;
        for (const Ref& r : s_.nodes[enc].refs)
            if (r.type == s_.rtHasEncoding && !r.isForward() && !r.isExternal()) return r.target;
        return kNoNode;
    }

    ExtensionObject extensionObject(const pugi::xml_node& el, int depth) {
        pugi::xml_node typeEl = child(el, "TypeId");
        pugi::xml_node body = child(el, "Body");
        pugi::xml_node structEl =
            body.find_child([](pugi::xml_node c) { return c.type() == pugi::node_element; });
        std::string_view typeText = trim(child(typeEl, "Identifier").child_value());
        if (typeText.empty() || !structEl) return ExtensionObject{};
        const NodeId typeId = nodeId(typeText, current_);
        const NodeIndex dt = dataTypeOfEncoding(typeId);
        if (dt == kNoNode) badValue("ExtensionObject TypeId " + typeId.toString() + " is unknown");
        auto layout = layoutOf(dt);
        if (!layout)
            badValue("ExtensionObject of DataType " + s_.idOf(dt).toString() +
                     " which has no StructureDefinition");
        if (layout->binaryEncoding.isNull())
            badValue("DataType " + s_.idOf(dt).toString() + " has no Default Binary encoding");
        ExtensionObject x;
        x.typeId = layout->binaryEncoding;
        x.encoding = ExtensionObject::Encoding::Binary;
        x.body = encodeBody(*layout, structEl, depth);
        return x;
    }

    std::string encodeBody(const StructureLayout& layout, const pugi::xml_node& el, int depth) {
        if (depth > kMaxValueDepth) badValue("nested too deeply");
        StructureValue value;
        for (const StructureFieldLayout& f : layout.fields) {
            pugi::xml_node fe = child(el, f.name);
            if (!fe) continue;  // absent: optional, not chosen, or the default value
            value.fields.emplace_back(f.name, fieldValue(f, fe, depth + 1));
        }
        try {
            return encodeStructure(layout, value, lookup_);
        } catch (const std::invalid_argument& e) {
            badValue("DataType " + layout.dataType.toString() + ": " + e.what());
        }
    }

    Variant fieldValue(const StructureFieldLayout& f, const pugi::xml_node& fe, int depth) {
        auto one = [&](const pugi::xml_node& e) -> Variant {
            switch (f.kind) {
                case StructureFieldLayout::Kind::Variant:
                    return variantField(e, depth);
                case StructureFieldLayout::Kind::ExtensionObject:
                    return Variant(extensionObject(e, depth));
                case StructureFieldLayout::Kind::Structure: {
                    NodeIndex dt = s_.find(f.dataType);
                    auto nested = dt == kNoNode ? nullptr : layoutOf(dt);
                    if (!nested)
                        badValue("field " + f.name + ": no layout for " + f.dataType.toString());
                    ExtensionObject x;
                    x.typeId = nested->binaryEncoding;
                    x.encoding = ExtensionObject::Encoding::Binary;
                    x.body = encodeBody(*nested, e, depth);
                    return Variant(std::move(x));
                }
                case StructureFieldLayout::Kind::Builtin:
                    break;
            }
            if (f.builtin == BuiltinType::Int32 && s_.find(f.dataType) != kNoNode &&
                isSubtypeOfNs0(s_.find(f.dataType), ns0::Enumeration)) {
                // Enumerations are written "Name_Value".
                std::string_view t = trim(e.child_value());
                auto us = t.rfind('_');
                return Variant(number<Int32>(us == std::string_view::npos ? t : t.substr(us + 1),
                                             current_, "enumeration"));
            }
            return scalar(f.builtin, e, depth);
        };
        if (f.valueRank < 1) return one(fe);
        std::vector<Variant> items;
        for (pugi::xml_node c : fe.children())
            if (c.type() == pugi::node_element) items.push_back(one(c));
        return joinArray(f, std::move(items));
    }

    // Elements parsed one by one into an array Variant of the field's type.
    Variant joinArray(const StructureFieldLayout& f, std::vector<Variant> items) {
        if (f.kind == StructureFieldLayout::Kind::Variant) return Variant(std::move(items));
        try {
            return arrayOf(f.kind == StructureFieldLayout::Kind::Builtin
                               ? f.builtin
                               : BuiltinType::ExtensionObject,
                           std::move(items));
        } catch (const std::invalid_argument& e) {
            badValue("field " + f.name + ": " + e.what());
        }
    }

    Impl& s_;
    const std::filesystem::path& file_;
    NodeSetLoadReport& report_;
    pugi::xml_document doc_;
    pugi::xml_node root_;
    pugi::xml_node current_;
    std::vector<UInt16> nsMap_;
    std::unordered_map<std::string, NodeId> aliases_;
    std::size_t elementCount_ = 0;
    std::vector<std::pair<pugi::xml_node, NodeIndex>> elements_;
    std::map<NodeIndex, pugi::xml_node> pendingDefinitions_;
    std::unordered_map<NodeIndex, std::shared_ptr<const StructureLayout>> layouts_;
    StructureLayoutLookup lookup_ =
        [this](const NodeId& id) -> std::shared_ptr<const StructureLayout> {
        NodeIndex dt = s_.find(id);
        return dt == kNoNode ? nullptr : layoutOf(dt);
    };
};

// Recursively loads `file` after the models it requires.
class Session {
  public:
    Session(AddressSpace& space, const std::vector<std::filesystem::path>& searchPath)
        : space_(space), searchPath_(searchPath) {}

    void load(const std::filesystem::path& file, int depth) {
        if (depth > 32)
            throw NodeSetError(status::BadDecodingError,
                               file.string() + ": RequiredModels nested too deeply");
        ModelHeader h = readModelHeader(file);
        if (!h.models.empty() &&
            std::all_of(h.models.begin(), h.models.end(),
                        [&](const std::string& uri) { return isModelLoaded(space_, uri); }))
            return;  // already there (e.g. namespace 0, compiled in)
        for (const std::string& uri : h.models)
            if (!inProgress_.insert(uri).second)
                throw NodeSetError(status::BadDecodingError,
                                   file.string() + ": model " + uri + " requires itself");
        for (const std::string& req : h.required) {
            if (isModelLoaded(space_, req)) continue;
            load(find(req, file), depth + 1);
        }
        NodeSetLoadReport report;
        report.file = file;
        if (!h.models.empty()) report.modelUri = h.models.front();
        auto& impl = NodeSetXmlAccess::impl(space_);
        {
            auto t0 = std::chrono::steady_clock::now();
            auto lock = impl.lockForChange();
            FileLoader(impl, file, report).load();
            for (const std::string& uri : h.models) impl.loadedModels.push_back(uri);
            report.loadMs =
                std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                    .count();
        }
        if (std::find(h.models.begin(), h.models.end(), kUaUri) != h.models.end())
            NodeSetXmlAccess::serveNamespaceArray(space_);
        reports_.push_back(std::move(report));
    }

    std::vector<NodeSetLoadReport> take() { return std::move(reports_); }

  private:
    std::filesystem::path find(const std::string& uri, const std::filesystem::path& requiredBy) {
        if (!indexed_) {
            indexed_ = true;
            for (const auto& dir : searchPath_) {
                std::error_code ec;
                for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
                    if (!entry.is_regular_file() || entry.path().extension() != ".xml") continue;
                    for (const std::string& m : readModelHeader(entry.path()).models)
                        index_.emplace(m, entry.path());  // first directory wins
                }
            }
        }
        auto it = index_.find(uri);
        if (it == index_.end())
            throw NodeSetError(status::BadNotFound,
                               requiredBy.string() + ": required model " + uri +
                                   " is neither loaded nor found in the NodeSet search path");
        return it->second;
    }

    AddressSpace& space_;
    const std::vector<std::filesystem::path>& searchPath_;
    bool indexed_ = false;
    std::map<std::string, std::filesystem::path> index_;
    std::set<std::string> inProgress_;
    std::vector<NodeSetLoadReport> reports_;
};

}  // namespace

std::vector<std::filesystem::path> defaultNodeSetSearchPath() {
    std::vector<std::filesystem::path> path;
    if (*PNP_NODESET_DIR_DEFAULT) path.emplace_back(PNP_NODESET_DIR_DEFAULT);
    if (const char* env = std::getenv("PNP_NODESET_PATH")) {
        std::string_view rest = env;
        while (!rest.empty()) {
            auto colon = rest.find(':');
            if (colon != 0) path.emplace_back(std::string(rest.substr(0, colon)));
            if (colon == std::string_view::npos) break;
            rest.remove_prefix(colon + 1);
        }
    }
    return path;
}

bool isModelLoaded(const AddressSpace& space, std::string_view modelUri) {
    const auto& impl = NodeSetXmlAccess::impl(space);
    std::shared_lock lock(impl.mutex);
    return std::find(impl.loadedModels.begin(), impl.loadedModels.end(), modelUri) !=
           impl.loadedModels.end();
}

std::vector<NodeSetLoadReport> loadNodeSetXml(
    AddressSpace& space, const std::filesystem::path& file,
    const std::vector<std::filesystem::path>& searchPath) {
    Session session(space, searchPath);
    session.load(file, 0);
    return session.take();
}

std::shared_ptr<const StructureLayout> AddressSpace::Impl::structureLayoutOf(NodeIndex dt) const {
    return FileLoader::buildLayout(*this, dt);
}

bool AddressSpace::Impl::bodyFits(const ExtensionObject& x, NodeIndex dt) const {
    if (x.encoding != ExtensionObject::Encoding::Binary || nodes[dt].ns == 0) return true;
    auto layout = structureLayoutOf(dt);
    if (!layout) return true;
    StructureLayoutLookup lookup = [this](const NodeId& id) {
        NodeIndex i = find(id);
        return i == kNoNode ? nullptr : structureLayoutOf(i);
    };
    try {
        decodeStructure(*layout, reinterpret_cast<const Byte*>(x.body.data()), x.body.size(),
                        lookup);
        return true;
    } catch (const DecodeError&) {
        return false;
    }
}

std::shared_ptr<const StructureLayout> AddressSpace::structureLayout(const NodeId& dataType) const {
    std::shared_lock lock(impl_->mutex);
    NodeIndex dt = impl_->find(dataType);
    if (dt == kNoNode) return nullptr;
    return impl_->structureLayoutOf(dt);
}

}  // namespace pnp::ua::server
