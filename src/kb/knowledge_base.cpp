#include "kb/knowledge_base.hpp"

#include <charconv>
#include <cmath>
#include <mutex>
#include <shared_mutex>

#include "kb/endpoint.hpp"
#include "kb/sparql.hpp"
#include "kb/store.hpp"
#include "kb/turtle.hpp"

namespace pnp::kb {

double Term::number() const {
    static const std::string xsd = "http://www.w3.org/2001/XMLSchema#";
    static const char* const numeric[] = {"integer",
                                          "decimal",
                                          "double",
                                          "float",
                                          "int",
                                          "long",
                                          "short",
                                          "byte",
                                          "nonNegativeInteger",
                                          "positiveInteger",
                                          "negativeInteger",
                                          "nonPositiveInteger",
                                          "unsignedInt",
                                          "unsignedLong",
                                          "unsignedShort",
                                          "unsignedByte"};
    bool isNumber = false;
    if (kind == Kind::Literal && datatype.starts_with(xsd)) {
        for (const char* n : numeric)
            isNumber = isNumber || datatype.compare(xsd.size(), std::string::npos, n) == 0;
    }
    if (!isNumber) throw KbError("not a numeric literal: " + value);
    std::string_view text = value;
    while (!text.empty() && text.front() == ' ') text.remove_prefix(1);
    while (!text.empty() && text.back() == ' ') text.remove_suffix(1);
    if (!text.empty() && text.front() == '+') text.remove_prefix(1);
    if (text == "INF") return HUGE_VAL;
    if (text == "-INF") return -HUGE_VAL;
    double d = 0;
    auto r = std::from_chars(text.data(), text.data() + text.size(), d);
    if (text.empty() || r.ec != std::errc() || r.ptr != text.data() + text.size()) {
        throw KbError("not a valid number: \"" + value + "\"");
    }
    return d;
}

const Term* Results::get(std::size_t row, std::string_view variable) const {
    if (row >= rows.size()) return nullptr;
    for (std::size_t j = 0; j < variables.size() && j < rows[row].size(); ++j) {
        if (variables[j] == variable) return rows[row][j] ? &*rows[row][j] : nullptr;
    }
    return nullptr;
}

std::string iri(std::string_view s) {
    if (s.empty()) throw KbError("an empty IRI");
    for (unsigned char c : s) {
        if (c <= 0x20 || c == '<' || c == '>' || c == '"' || c == '{' || c == '}' || c == '|' ||
            c == '^' || c == '`' || c == '\\') {
            throw KbError("a character an IRI may not hold in '" + std::string(s) + "'");
        }
    }
    return "<" + std::string(s) + ">";
}

std::string literal(std::string_view s) { return "\"" + escapeString(s) + "\""; }

namespace {

// The in-process store: readers share it, updates and loads take it alone.
class EmbeddedKnowledgeBase final : public KnowledgeBase {
  public:
    Results select(std::string_view query, Deadline deadline) override {
        std::shared_lock lock(mutex_);
        return runSelect(store_, query, deadline);
    }
    bool ask(std::string_view query, Deadline deadline) override {
        std::shared_lock lock(mutex_);
        return runAsk(store_, query, deadline);
    }
    void update(std::string_view update, Deadline deadline) override {
        std::unique_lock lock(mutex_);
        runUpdate(store_, update, deadline, blankCounter_);
    }
    std::size_t loadTurtle(const std::filesystem::path& file, const std::string& graph,
                           Deadline deadline) override {
        iri(graph);  // validates the graph name
        std::string prefix;
        {
            std::unique_lock lock(mutex_);
            prefix = "f" + std::to_string(++blankCounter_) + "_";
        }
        auto triples = parseTurtleFile(file, prefix);
        if (std::chrono::steady_clock::now() > deadline) {
            throw KbError(file.string() + ": deadline exceeded while loading");
        }
        std::unique_lock lock(mutex_);
        TermId g = store_.intern(Term{Term::Kind::Iri, graph, "", ""});
        for (const auto& t : triples) {
            store_.insert({store_.intern(t[0]), store_.intern(t[1]), store_.intern(t[2]), g});
        }
        return triples.size();
    }
    std::string describe() const override {
        std::shared_lock lock(mutex_);
        return "embedded (" + std::to_string(store_.size()) + " triples)";
    }

  private:
    mutable std::shared_mutex mutex_;
    QuadStore store_;
    std::uint64_t blankCounter_ = 0;
};

}  // namespace

std::unique_ptr<KnowledgeBase> open(const std::string& location) {
    if (location.empty() || location == "embedded")
        return std::make_unique<EmbeddedKnowledgeBase>();
    if (location.starts_with("http://")) return openEndpoint(location);
    if (location.starts_with("https://")) {
        throw KbError("knowledge base '" + location + "': https is not supported, use http://");
    }
    throw KbError("knowledge base '" + location +
                  "': expected \"\", \"embedded\" or an http://host:port/path SPARQL endpoint");
}

}  // namespace pnp::kb
