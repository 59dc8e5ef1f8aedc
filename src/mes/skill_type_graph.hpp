// The skill types as knowledge: every ObjectType of our skill models (the NodeSet2 files the
// servers load, skill::modelsDirectory()) as triples — its IRI <namespace URI#BrowseName>,
// rdfs:subClassOf its supertype, pnp:implements its interfaces, pnp:parameter for each
// variable of its ParameterSet (name, data type, value rank). Derived from the same files the
// servers load, so the knowledge base can never disagree with them.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

namespace pnp::mes {

inline constexpr const char* kSkillTypesGraph = "urn:pnp:kb:skill-types";

// The IRI of an OPC UA type: "<namespace URI>#<BrowseName name>".
std::string typeIri(std::string_view namespaceUri, std::string_view name);

// N-Triples lines (one statement per line, no graph) for the given NodeSet2 files; throws
// std::runtime_error naming the file on an unreadable or malformed one.
std::vector<std::string> skillTypeTriples(const std::vector<std::filesystem::path>& nodesetFiles);

// The skill model files: models/Pnp.Skills*.NodeSet2.xml.
std::vector<std::filesystem::path> skillModelFiles();

}  // namespace pnp::mes
