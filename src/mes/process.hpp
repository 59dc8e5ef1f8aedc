// A process as the knowledge base describes it (docs/kb-vocabulary.md): ordered steps, each a
// skill type and parameter bindings, read with SPARQL; and the load-time check of every
// process in the knowledge base (unknown skill type, unknown parameter, a binding without a
// value) with the file and line it came from.
#pragma once

#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "mes/shared_kb.hpp"

namespace pnp::mes {

class ProcessError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

// A parameter's value in a step: exactly one of
//   value             the text itself (coerced to the parameter's DataType when run),
//   from + via        the value of property `via` of resource `from`,
//   query             a SPARQL SELECT whose first solution's ?value is the value.
struct Binding {
    std::string name;
    std::optional<std::string> value;
    std::string from, via, query;
};

struct Step {
    std::string iri;
    int index = 0;
    std::string label;
    std::string skillType;  // IRI
    std::vector<Binding> bindings;
};

struct Process {
    std::string iri;
    std::string label;
    std::vector<Step> steps;  // by index
};

// Reads the process; throws ProcessError when there is no such process or it has no steps.
Process loadProcess(SharedKb& kb, const std::string& iri, kb::Deadline deadline);

// Every process in the knowledge base checked against the skill types (graph
// urn:pnp:kb:skill-types): one line per problem, "file:line: what is wrong", where the file is
// the Turtle file of the graph the step came from (`files`: graph IRI -> file) and the line is
// that of the offending name's first mention in it.
std::vector<std::string> validateProcesses(
    SharedKb& kb, const std::map<std::string, std::filesystem::path>& files, kb::Deadline deadline);

// The parameters (name -> DataType name) of a skill type, its supertypes' and interfaces'.
std::map<std::string, std::string> typeParameters(SharedKb& kb, const std::string& typeIri,
                                                  kb::Deadline deadline);

// What a binding resolves to now: the text, and the resource it came from ("" for a literal
// value or a query). Throws ProcessError saying why it does not resolve.
struct Resolved {
    std::string text;
    std::string source;
};
Resolved resolveBinding(SharedKb& kb, const Binding& binding, kb::Deadline deadline);

// Loads the knowledge: the skill types from the NodeSet2 models, then each Turtle file into
// a graph of its own (file:// IRI), then validateProcesses(). Throws ProcessError listing
// every problem (Turtle syntax: file:line:col).
void loadKnowledge(SharedKb& kb, const std::vector<std::filesystem::path>& turtleFiles,
                   kb::Deadline deadline);

// models/kb/*.ttl (the vocabulary, the thesis cell, the thesis process).
std::vector<std::filesystem::path> defaultKnowledgeFiles();

}  // namespace pnp::mes
