#include "mes/kb_feed.hpp"

#include "mes/skill_type_graph.hpp"

namespace pnp::mes {

namespace {

// Percent-encodes everything but unreserved characters: any ApplicationUri or NodeId text
// becomes part of a valid IRI.
std::string encode(std::string_view s) {
    static const char* hex = "0123456789ABCDEF";
    std::string out;
    for (unsigned char c : s) {
        if (std::isalnum(c) || c == '-' || c == '.' || c == '_' || c == '~') {
            out += static_cast<char>(c);
        } else {
            out += '%';
            out += hex[c >> 4];
            out += hex[c & 15];
        }
    }
    return out;
}

}  // namespace

KbFeed::KbFeed(SharedKb& kb, std::chrono::milliseconds timeout) : kb_(kb), timeout_(timeout) {
    kb_.update(std::string("CLEAR GRAPH ") + kb::iri(kLiveGraph),
               std::chrono::steady_clock::now() + timeout_);
}

std::string KbFeed::componentIri(const std::string& applicationUri) {
    return "urn:pnp:kb:component:" + encode(applicationUri);
}

std::string KbFeed::skillIri(const skill::detector::DetectedSkill& s) {
    return "urn:pnp:kb:skill:" + encode(s.componentUri) + ":" + encode(s.nodeText);
}

void KbFeed::run(const std::string& update) {
    try {
        kb_.update(update, std::chrono::steady_clock::now() + timeout_);
    } catch (const std::exception& e) {
        std::lock_guard l(mutex_);
        ++errors_;
        if (log) log(std::string("knowledge base feed: ") + e.what());
    }
}

void KbFeed::changed(const skill::detector::DetectedSkill& s, bool added) {
    const std::string skill = kb::iri(skillIri(s));
    const std::string comp = kb::iri(componentIri(s.componentUri));
    const std::string graph = kb::iri(kLiveGraph);
    bool lastOfComponent = false;
    {
        std::lock_guard l(mutex_);
        const std::string key = skillIri(s);
        if (added) {
            if (skills_.contains(key)) return;
            skills_[key] = s;
            ++perComponent_[componentIri(s.componentUri)];
        } else {
            if (skills_.erase(key) == 0) return;
            auto it = perComponent_.find(componentIri(s.componentUri));
            if (it != perComponent_.end() && --it->second == 0) {
                perComponent_.erase(it);
                lastOfComponent = true;
            }
        }
    }
    if (added) {
        std::string u = std::string(kPrefixes) + "INSERT DATA { GRAPH " + graph + " {\n";
        u += comp + " a pnp:Component ; pnp:applicationUri " + kb::literal(s.componentUri) +
             " ; pnp:name " + kb::literal(s.componentName) + " ; pnp:endpoint " +
             kb::literal(s.endpointUrl) + " ; pnp:offers " + skill + " .\n";
        u += skill + " a pnp:Skill ; pnp:name " + kb::literal(s.name) + " ; pnp:skillType " +
             kb::iri(typeIri(s.type.uri, s.type.name)) + " ; pnp:node " + kb::literal(s.nodeText) +
             " ; pnp:controller " + kb::literal(s.controllerName) + " .\n} }";
        run(u);
        return;
    }
    run("DELETE WHERE { GRAPH " + graph + " { " + skill + " ?p ?o } }");
    run("DELETE WHERE { GRAPH " + graph + " { ?c <urn:pnp:kb#offers> " + skill + " } }");
    if (lastOfComponent) run("DELETE WHERE { GRAPH " + graph + " { " + comp + " ?p ?o } }");
}

std::optional<skill::detector::DetectedSkill> KbFeed::skill(const std::string& iri) const {
    std::lock_guard l(mutex_);
    auto it = skills_.find(iri);
    if (it == skills_.end()) return std::nullopt;
    return it->second;
}

std::size_t KbFeed::skills() const {
    std::lock_guard l(mutex_);
    return skills_.size();
}

std::size_t KbFeed::errors() const {
    std::lock_guard l(mutex_);
    return errors_;
}

}  // namespace pnp::mes
