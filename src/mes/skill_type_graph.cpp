#include "mes/skill_type_graph.hpp"

#include <algorithm>
#include <map>
#include <pugixml.hpp>
#include <stdexcept>

#include "kb/knowledge_base.hpp"
#include "skill/model/model.hpp"

namespace pnp::mes {

namespace {

constexpr const char* kRdfType = "<http://www.w3.org/1999/02/22-rdf-syntax-ns#type>";
constexpr const char* kSubClassOf = "<http://www.w3.org/2000/01/rdf-schema#subClassOf>";
constexpr const char* kLabel = "<http://www.w3.org/2000/01/rdf-schema#label>";
constexpr const char* kXsdInteger = "^^<http://www.w3.org/2001/XMLSchema#integer>";
constexpr const char* kXsdBoolean = "^^<http://www.w3.org/2001/XMLSchema#boolean>";
constexpr std::string_view kNs0 = "http://opcfoundation.org/UA/";
std::string pnp(std::string_view local) { return "<urn:pnp:kb#" + std::string(local) + ">"; }

// A node of a file, by namespace URI and identifier text ("i=1001").
struct Ref {
    std::string uri, id;
    auto operator<=>(const Ref&) const = default;
};

struct TypeNode {
    std::string uri, name;
    std::string numericId;  // "" for non-numeric ids
    bool isAbstract = false;
    std::vector<Ref> supertypes, interfaces;
    struct Param {
        std::string name, dataType;
        int valueRank = -1;
    };
    std::vector<Param> parameters;
};

struct FileParser {
    std::vector<std::string> uris;  // NamespaceUris (index 1..)
    std::map<std::string, std::string> aliases;

    std::string nsUri(int index) const {
        if (index == 0) return std::string(kNs0);
        if (index < 1 || static_cast<std::size_t>(index) > uris.size())
            throw std::runtime_error("namespace index " + std::to_string(index) + " not declared");
        return uris[index - 1];
    }
    Ref ref(std::string text) const {
        if (auto a = aliases.find(text); a != aliases.end()) text = a->second;
        int ns = 0;
        if (text.starts_with("ns=")) {
            const auto semi = text.find(';');
            if (semi == std::string::npos) throw std::runtime_error("bad NodeId " + text);
            ns = std::stoi(text.substr(3, semi - 3));
            text = text.substr(semi + 1);
        }
        return {nsUri(ns), text};
    }
    // "1:Name" -> Name.
    static std::string browseName(const char* qualified) {
        std::string s = qualified;
        if (auto c = s.find(':'); c != std::string::npos && c < 4) return s.substr(c + 1);
        return s;
    }
};

}  // namespace

std::string typeIri(std::string_view namespaceUri, std::string_view name) {
    std::string s(namespaceUri);
    s += '#';
    s += name;
    return s;
}

std::vector<std::filesystem::path> skillModelFiles() {
    std::vector<std::filesystem::path> files;
    const auto dir = skill::modelsDirectory();
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
        const std::string n = e.path().filename().string();
        if (n.starts_with("Pnp.Skills") && n.ends_with(".NodeSet2.xml")) files.push_back(e.path());
    }
    std::sort(files.begin(), files.end());
    return files;
}

std::vector<std::string> skillTypeTriples(const std::vector<std::filesystem::path>& files) {
    std::map<Ref, TypeNode> types;
    for (const auto& file : files) {
        pugi::xml_document doc;
        if (auto r = doc.load_file(file.c_str()); !r)
            throw std::runtime_error(file.string() + ": " + r.description());
        const auto set = doc.child("UANodeSet");
        FileParser p;
        for (auto u : set.child("NamespaceUris").children("Uri"))
            p.uris.emplace_back(u.text().get());
        for (auto a : set.child("Aliases").children("Alias"))
            p.aliases[a.attribute("Alias").value()] = a.text().get();
        try {
            // ParameterSet objects by id -> their type, then variables below them.
            std::map<Ref, Ref> parameterSets;
            for (auto t : set.children("UAObjectType")) {
                const Ref id = p.ref(t.attribute("NodeId").value());
                TypeNode& n = types[id];
                n.uri = id.uri;
                n.name = FileParser::browseName(t.attribute("BrowseName").value());
                if (id.id.starts_with("i=")) n.numericId = id.id.substr(2);
                n.isAbstract = t.attribute("IsAbstract").as_bool();
                for (auto r : t.child("References").children("Reference")) {
                    const std::string type = r.attribute("ReferenceType").value();
                    const bool forward = r.attribute("IsForward").as_bool(true);
                    const Ref target = p.ref(r.text().get());
                    if ((type == "HasSubtype" || type == "i=45") && !forward)
                        n.supertypes.push_back(target);
                    if ((type == "HasInterface" || type == "i=17603") && forward)
                        n.interfaces.push_back(target);
                }
            }
            for (auto o : set.children("UAObject")) {
                if (FileParser::browseName(o.attribute("BrowseName").value()) != "ParameterSet")
                    continue;
                const char* parent = o.attribute("ParentNodeId").value();
                if (*parent == 0) continue;
                const Ref parentRef = p.ref(parent);
                if (types.contains(parentRef))
                    parameterSets[p.ref(o.attribute("NodeId").value())] = parentRef;
            }
            for (auto v : set.children("UAVariable")) {
                const char* parent = v.attribute("ParentNodeId").value();
                if (*parent == 0) continue;
                auto ps = parameterSets.find(p.ref(parent));
                if (ps == parameterSets.end()) continue;
                std::string dt = v.attribute("DataType").value();
                if (dt.empty()) dt = "BaseDataType";
                types[ps->second].parameters.push_back(
                    {FileParser::browseName(v.attribute("BrowseName").value()), dt,
                     v.attribute("ValueRank").as_int(-1)});
            }
        } catch (const std::exception& e) {
            throw std::runtime_error(file.string() + ": " + e.what());
        }
    }
    // A skill type: SkillType itself or a (transitive) subtype of it; an interface: a subtype
    // of BaseInterfaceType (i=17602).
    const Ref skillType{std::string(skill::kBaseUri), "i=1001"};
    const Ref baseInterface{std::string(kNs0), "i=17602"};
    auto reaches = [&](Ref r, const Ref& root) {
        for (int depth = 0; depth < 32; ++depth) {
            if (r == root) return true;
            auto it = types.find(r);
            if (it == types.end() || it->second.supertypes.empty()) return false;
            r = it->second.supertypes.front();
        }
        return false;
    };
    auto nameOf = [&](const Ref& r) -> std::string {
        if (auto it = types.find(r); it != types.end())
            return kb::iri(typeIri(r.uri, it->second.name));
        return kb::iri(r.uri + "#" + r.id);
    };
    std::vector<std::string> out;
    for (const auto& [id, n] : types) {
        const bool isSkill = reaches(id, skillType);
        const bool isInterface = reaches(id, baseInterface) ||
                                 (!n.supertypes.empty() && n.supertypes.front() == baseInterface);
        if (!isSkill && !isInterface) continue;
        const std::string s = kb::iri(typeIri(n.uri, n.name));
        out.push_back(s + " " + kRdfType + " " + pnp(isSkill ? "SkillType" : "Interface") + " .");
        out.push_back(s + " " + kLabel + " " + kb::literal(n.name) + " .");
        out.push_back(s + " " + pnp("name") + " " + kb::literal(n.name) + " .");
        out.push_back(s + " " + pnp("uaNamespace") + " " + kb::literal(n.uri) + " .");
        if (!n.numericId.empty())
            out.push_back(s + " " + pnp("uaId") + " \"" + n.numericId + "\"" + kXsdInteger + " .");
        out.push_back(s + " " + pnp("abstract") + " \"" + (n.isAbstract ? "true" : "false") + "\"" +
                      kXsdBoolean + " .");
        for (const auto& sup : n.supertypes)
            if (types.contains(sup))
                out.push_back(s + " " + kSubClassOf + " " + nameOf(sup) + " .");
        for (const auto& i : n.interfaces)
            out.push_back(s + " " + pnp("implements") + " " + nameOf(i) + " .");
        for (const auto& par : n.parameters) {
            const std::string pi = kb::iri(typeIri(n.uri, n.name) + "/" + par.name);
            out.push_back(s + " " + pnp("parameter") + " " + pi + " .");
            out.push_back(pi + " " + kRdfType + " " + pnp("Parameter") + " .");
            out.push_back(pi + " " + pnp("name") + " " + kb::literal(par.name) + " .");
            out.push_back(pi + " " + pnp("dataType") + " " + kb::literal(par.dataType) + " .");
            out.push_back(pi + " " + pnp("valueRank") + " \"" + std::to_string(par.valueRank) +
                          "\"" + kXsdInteger + " .");
        }
    }
    return out;
}

}  // namespace pnp::mes
