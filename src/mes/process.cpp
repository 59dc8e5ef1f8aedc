#include "mes/process.hpp"

#include <algorithm>
#include <fstream>
#include <set>
#include <sstream>

#include "mes/skill_type_graph.hpp"
#include "skill/model/model.hpp"

namespace pnp::mes {

namespace {

std::string text(const kb::Results& r, std::size_t row, std::string_view var) {
    const kb::Term* t = r.get(row, var);
    return t ? t->value : std::string();
}

// The line (1-based) of the first mention of `needle` in `file`, 0 when not found.
std::size_t lineOf(const std::filesystem::path& file, const std::string& needle) {
    std::ifstream in(file);
    std::string line;
    for (std::size_t n = 1; std::getline(in, line) && n < 1000000; ++n)
        if (line.find(needle) != std::string::npos) return n;
    return 0;
}

std::string localName(const std::string& iri) {
    const auto p = iri.find_last_of("#/:");
    return p == std::string::npos ? iri : iri.substr(p + 1);
}

}  // namespace

Process loadProcess(SharedKb& kb, const std::string& iri, kb::Deadline deadline) {
    Process p;
    p.iri = iri;
    const std::string P = kb::iri(iri);
    const auto head = kb.select(std::string(kPrefixes) + "SELECT ?label WHERE { " + P +
                                    " a pnp:Process . OPTIONAL { " + P + " rdfs:label ?label } }",
                                deadline);
    if (head.rows.empty()) throw ProcessError("no process " + iri + " in the knowledge base");
    p.label = text(head, 0, "label");
    const auto steps = kb.select(std::string(kPrefixes) +
                                     "SELECT ?step ?index ?type ?label WHERE { ?step a pnp:Step ; "
                                     "pnp:process " +
                                     P +
                                     " ; pnp:index ?index ; pnp:skillType ?type . "
                                     "OPTIONAL { ?step rdfs:label ?label } } ORDER BY ?index",
                                 deadline);
    std::map<std::string, std::size_t> byIri;
    for (std::size_t i = 0; i < steps.rows.size(); ++i) {
        Step s;
        s.iri = text(steps, i, "step");
        if (byIri.contains(s.iri))
            throw ProcessError("step " + s.iri + " of " + iri + " has more than one index or type");
        const kb::Term* index = steps.get(i, "index");
        try {
            s.index = static_cast<int>(index->number());
        } catch (const std::exception&) {
            throw ProcessError("step " + s.iri + ": pnp:index is not a number");
        }
        s.skillType = text(steps, i, "type");
        s.label = text(steps, i, "label");
        byIri[s.iri] = p.steps.size();
        p.steps.push_back(std::move(s));
    }
    if (p.steps.empty()) throw ProcessError("process " + iri + " has no steps");
    const auto bindings =
        kb.select(std::string(kPrefixes) +
                      "SELECT ?step ?name ?value ?from ?via ?query WHERE { ?step pnp:process " + P +
                      " ; pnp:binding ?b . ?b pnp:name ?name . OPTIONAL { ?b pnp:value ?value } "
                      "OPTIONAL { ?b pnp:from ?from } OPTIONAL { ?b pnp:via ?via } "
                      "OPTIONAL { ?b pnp:query ?query } }",
                  deadline);
    for (std::size_t i = 0; i < bindings.rows.size(); ++i) {
        auto it = byIri.find(text(bindings, i, "step"));
        if (it == byIri.end()) continue;
        Binding b;
        b.name = text(bindings, i, "name");
        if (const kb::Term* v = bindings.get(i, "value")) b.value = v->value;
        b.from = text(bindings, i, "from");
        b.via = text(bindings, i, "via");
        b.query = text(bindings, i, "query");
        p.steps[it->second].bindings.push_back(std::move(b));
    }
    for (auto& s : p.steps)
        std::sort(s.bindings.begin(), s.bindings.end(),
                  [](const Binding& a, const Binding& b) { return a.name < b.name; });
    return p;
}

std::map<std::string, std::string> typeParameters(SharedKb& kb, const std::string& typeIri,
                                                  kb::Deadline deadline) {
    const auto r =
        kb.select(std::string(kPrefixes) + "SELECT ?name ?dt WHERE { " + kb::iri(typeIri) +
                      " (rdfs:subClassOf|pnp:implements)* ?d . ?d pnp:parameter ?p . "
                      "?p pnp:name ?name ; pnp:dataType ?dt }",
                  deadline);
    std::map<std::string, std::string> out;
    for (std::size_t i = 0; i < r.rows.size(); ++i) out[text(r, i, "name")] = text(r, i, "dt");
    return out;
}

std::vector<std::string> validateProcesses(
    SharedKb& kb, const std::map<std::string, std::filesystem::path>& files,
    kb::Deadline deadline) {
    std::vector<std::string> problems;
    const auto steps = kb.select(
        std::string(kPrefixes) +
            "SELECT ?g ?step ?process ?type ?index WHERE { GRAPH ?g { ?step a pnp:Step } "
            "OPTIONAL { ?step pnp:process ?process } OPTIONAL { ?step pnp:skillType ?type } "
            "OPTIONAL { ?step pnp:index ?index } }",
        deadline);
    const auto types =
        kb.select(std::string(kPrefixes) + "SELECT ?t WHERE { ?t a pnp:SkillType }", deadline);
    std::set<std::string> known;
    for (std::size_t i = 0; i < types.rows.size(); ++i) known.insert(text(types, i, "t"));
    std::map<std::string, std::map<std::string, std::string>> parameterCache;

    auto where = [&](const std::string& graph, const std::string& needle) {
        auto f = files.find(graph);
        if (f == files.end()) return graph + ": ";
        const std::size_t line = lineOf(f->second, needle);
        return f->second.string() + ":" + (line ? std::to_string(line) : std::string("?")) + ": ";
    };
    for (std::size_t i = 0; i < steps.rows.size(); ++i) {
        const std::string g = text(steps, i, "g"), step = text(steps, i, "step"),
                          type = text(steps, i, "type");
        const std::string stepName = localName(step);
        if (!steps.get(i, "process")) {
            problems.push_back(where(g, stepName) + "step " + step + " belongs to no pnp:process");
            continue;
        }
        if (!steps.get(i, "index"))
            problems.push_back(where(g, stepName) + "step " + step + " has no pnp:index");
        if (type.empty()) {
            problems.push_back(where(g, stepName) + "step " + step + " has no pnp:skillType");
            continue;
        }
        if (!known.contains(type)) {
            problems.push_back(where(g, localName(type)) + "step " + stepName +
                               ": unknown skill type " + type);
            continue;
        }
        auto& params = parameterCache[type];
        if (params.empty()) params = typeParameters(kb, type, deadline);
        const auto bindings =
            kb.select(std::string(kPrefixes) + "SELECT ?name ?value ?from ?via ?query WHERE { " +
                          kb::iri(step) +
                          " pnp:binding ?b . OPTIONAL { ?b pnp:name ?name } "
                          "OPTIONAL { ?b pnp:value ?value } OPTIONAL { ?b pnp:from ?from } "
                          "OPTIONAL { ?b pnp:via ?via } OPTIONAL { ?b pnp:query ?query } }",
                      deadline);
        for (std::size_t j = 0; j < bindings.rows.size(); ++j) {
            const std::string name = text(bindings, j, "name");
            if (name.empty()) {
                problems.push_back(where(g, stepName) + "step " + stepName +
                                   ": a binding without pnp:name");
                continue;
            }
            if (!params.contains(name)) {
                std::string list;
                for (const auto& [n, dt] : params) list += (list.empty() ? "" : ", ") + n;
                problems.push_back(where(g, "\"" + name + "\"") + "step " + stepName + ": " +
                                   localName(type) + " has no parameter \"" + name +
                                   "\" (it has: " + (list.empty() ? "none" : list) + ")");
                continue;
            }
            const int forms = (bindings.get(j, "value") ? 1 : 0) +
                              (bindings.get(j, "from") ? 1 : 0) +
                              (bindings.get(j, "query") ? 1 : 0);
            if (forms != 1)
                problems.push_back(where(g, "\"" + name + "\"") + "step " + stepName +
                                   ": parameter " + name +
                                   " needs exactly one of pnp:value, pnp:from (with pnp:via), "
                                   "pnp:query");
            else if (bindings.get(j, "from") && !bindings.get(j, "via"))
                problems.push_back(where(g, "\"" + name + "\"") + "step " + stepName +
                                   ": parameter " + name + ": pnp:from without pnp:via");
        }
    }
    return problems;
}

Resolved resolveBinding(SharedKb& kb, const Binding& b, kb::Deadline deadline) {
    if (b.value) return {*b.value, {}};
    if (!b.from.empty()) {
        const auto r = kb.select(
            "SELECT ?v WHERE { " + kb::iri(b.from) + " " + kb::iri(b.via) + " ?v }", deadline);
        if (r.rows.empty() || !r.get(0, "v"))
            throw ProcessError(b.name + ": " + b.from + " has no " + b.via);
        if (r.rows.size() > 1)
            throw ProcessError(b.name + ": " + b.from + " has " + std::to_string(r.rows.size()) +
                               " values of " + b.via);
        return {r.get(0, "v")->value, b.from};
    }
    if (!b.query.empty()) {
        kb::Results r;
        try {
            r = kb.select(std::string(kPrefixes) + b.query, deadline);
        } catch (const kb::KbError& e) {
            throw ProcessError(b.name + ": its query is wrong: " + e.what());
        }
        if (r.rows.empty() || !r.get(0, "value"))
            throw ProcessError(b.name + ": its query has no ?value now");
        return {r.get(0, "value")->value, {}};
    }
    throw ProcessError(b.name + ": no value");
}

void loadKnowledge(SharedKb& kb, const std::vector<std::filesystem::path>& turtleFiles,
                   kb::Deadline deadline) {
    const auto triples = skillTypeTriples(skillModelFiles());
    kb.update("CLEAR GRAPH " + kb::iri(kSkillTypesGraph), deadline);
    for (std::size_t i = 0; i < triples.size(); i += 400) {
        std::string u = "INSERT DATA { GRAPH " + kb::iri(kSkillTypesGraph) + " {\n";
        for (std::size_t j = i; j < std::min(triples.size(), i + 400); ++j) u += triples[j] + "\n";
        kb.update(u + "} }", deadline);
    }
    std::map<std::string, std::filesystem::path> files;
    std::vector<std::string> problems;
    for (const auto& f : turtleFiles) {
        const auto abs = std::filesystem::absolute(f).lexically_normal();
        const std::string graph = "file://" + abs.string();
        try {
            kb.update("CLEAR GRAPH " + kb::iri(graph), deadline);
            kb.loadTurtle(abs, graph, deadline);
            files[graph] = abs;
        } catch (const kb::KbError& e) {
            problems.emplace_back(e.what());
        }
    }
    if (problems.empty()) {
        auto more = validateProcesses(kb, files, deadline);
        problems.insert(problems.end(), more.begin(), more.end());
    }
    if (!problems.empty()) {
        std::string all;
        for (const auto& p : problems) all += "\n  " + p;
        throw ProcessError("the knowledge base was refused:" + all);
    }
}

std::vector<std::filesystem::path> defaultKnowledgeFiles() {
    std::vector<std::filesystem::path> out;
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(skill::modelsDirectory() / "kb", ec))
        if (e.path().extension() == ".ttl") out.push_back(e.path());
    std::sort(out.begin(), out.end());
    return out;
}

}  // namespace pnp::mes
