// The embedded knowledge base's quad store: dictionary-encoded terms and three sorted indexes
// (SPOG, POSG, OSPG) over every quad. The graph is the last key of each index, so the default
// graph (the union of all graphs) is one range per pattern with duplicates next to each other.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <set>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "kb/knowledge_base.hpp"

namespace pnp::kb {

using TermId = std::uint32_t;
inline constexpr TermId kNoTerm = 0;  // "unbound" / "any"

// The graph of triples written without GRAPH (INSERT DATA { <s> <p> <o> }): part of the union.
inline constexpr std::string_view kDefaultGraphName = "urn:pnp:kb:default-graph";

struct Quad {
    TermId s = kNoTerm, p = kNoTerm, o = kNoTerm, g = kNoTerm;
    bool operator==(const Quad&) const = default;
};

// A term written in N-Triples / SPARQL syntax: <iri>, "lexical"^^<dt>, "lexical"@lang, _:label.
std::string toNTriples(const Term& term);
// The N-Triples escape of a string literal's or IRI's content.
std::string escapeString(std::string_view s);

class QuadStore {
  public:
    QuadStore();

    // The id of `term`, added to the dictionary when new.
    TermId intern(const Term& term);
    // The id of `term`, or kNoTerm when the store has never seen it.
    TermId find(const Term& term) const;
    const Term& term(TermId id) const { return terms_[id]; }
    std::size_t termCount() const { return terms_.size(); }

    // Adds / removes one quad; true when the store changed.
    bool insert(const Quad& quad);
    bool erase(const Quad& quad);
    // Removes every quad of graph `g`; returns how many.
    std::size_t clearGraph(TermId g);
    void clearAll();

    // Calls `visit` for every quad matching the pattern (kNoTerm = any) until it returns false.
    // g == kNoTerm: the union of all graphs, each triple once (its first graph is reported).
    void match(TermId s, TermId p, TermId o, TermId g,
               const std::function<bool(const Quad&)>& visit) const;
    // The graphs that hold at least one quad.
    std::vector<TermId> graphs() const;
    std::size_t size() const { return spog_.size(); }

  private:
    using Key = std::array<TermId, 4>;
    std::vector<Term> terms_;  // terms_[0] is the "no term" placeholder
    std::unordered_map<std::string, TermId> ids_;
    std::set<Key> spog_, posg_, ospg_;
    std::unordered_map<TermId, std::size_t> graphSizes_;
};

// The dictionary key of a term: kind, value, datatype and language in one string.
std::string termKey(const Term& term);

}  // namespace pnp::kb
