// A SPARQL 1.1 endpoint as the knowledge base (SPARQL 1.1 Protocol over HTTP, results as
// application/sparql-results+json). docs/knowledge-base.md notes Virtuoso's behaviour.
#pragma once

#include <cstddef>
#include <memory>
#include <string>

#include "kb/knowledge_base.hpp"

namespace pnp::kb {

// The largest HTTP response body read from an endpoint (bytes).
inline constexpr std::size_t kMaxEndpointResponseBytes = 32u << 20;
// Triples per INSERT DATA request when loading a Turtle file into an endpoint.
inline constexpr std::size_t kTriplesPerInsert = 500;

// `url`: http://host[:port]/path. Throws KbError for a malformed URL (nothing is contacted yet).
std::unique_ptr<KnowledgeBase> openEndpoint(const std::string& url);

}  // namespace pnp::kb
