// The knowledge base (docs/knowledge-base.md): RDF triples queried with SPARQL 1.1, either
// embedded (an in-process store, the default: no server to start) or any SPARQL 1.1
// endpoint by URL (a plant's shared knowledge base). Callers send the same query text to
// both: the default graph is the union of all graphs on both sides.
//
//   auto kb = pnp::kb::open("");                       // or "http://host:8890/sparql"
//   kb->loadTurtle("models/kb/pnp.ttl", "urn:pnp:kb:vocabulary", deadline);
//   auto r = kb->select("SELECT ?s WHERE { ?s a <urn:pnp:kb#Object> }", deadline);
//   for (std::size_t i = 0; i < r.rows.size(); ++i) use(r.get(i, "s")->value);
#pragma once

#include <chrono>
#include <filesystem>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace pnp::kb {

// An RDF term.
struct Term {
    enum class Kind { Iri, Literal, Blank };
    Kind kind = Kind::Iri;
    std::string value;     // the IRI, the literal's lexical form, or the blank node's label
    std::string datatype;  // literals: datatype IRI ("" = xsd:string)
    std::string lang;      // literals: language tag
    bool operator==(const Term&) const = default;
    // A numeric literal's value; throws KbError for anything else.
    double number() const;
};

// A SELECT's solutions.
struct Results {
    std::vector<std::string> variables;
    std::vector<std::vector<std::optional<Term>>> rows;  // rows[i][j] binds variables[j]
    // The binding of `variable` in row `row`; nullptr when unbound or not a variable.
    const Term* get(std::size_t row, std::string_view variable) const;
};

// A bad query, update, file or endpoint answer; what() says where ("file:line:col: ...").
class KbError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

using Deadline = std::chrono::steady_clock::time_point;

class KnowledgeBase {
  public:
    virtual ~KnowledgeBase() = default;
    // SPARQL 1.1 Query: SELECT / ASK. Throws KbError.
    virtual Results select(std::string_view query, Deadline deadline) = 0;
    virtual bool ask(std::string_view query, Deadline deadline) = 0;
    // SPARQL 1.1 Update. Throws KbError.
    virtual void update(std::string_view update, Deadline deadline) = 0;
    // Parses a Turtle file and adds its triples to graph `graph`; returns how many. An invalid
    // file adds nothing and throws KbError "file:line:col: what is wrong".
    virtual std::size_t loadTurtle(const std::filesystem::path& file, const std::string& graph,
                                   Deadline deadline) = 0;
    // "embedded (N triples)" or the endpoint's URL.
    virtual std::string describe() const = 0;
};

// "" or "embedded": the in-process store; "http://host:port/path": a SPARQL 1.1 endpoint
// (SPARQL 1.1 Protocol). Throws KbError for anything else.
std::unique_ptr<KnowledgeBase> open(const std::string& location);

// Query-building helpers: "<iri>" (throws KbError on characters an IRI may not hold) and a
// quoted, escaped string literal.
std::string iri(std::string_view s);
std::string literal(std::string_view s);

}  // namespace pnp::kb
