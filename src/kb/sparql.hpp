// The embedded SPARQL 1.1 engine over a QuadStore (docs/knowledge-base.md lists the subset).
// Anything outside it is a KbError "SPARQL line:col: unsupported: <feature>".
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>

#include "kb/knowledge_base.hpp"
#include "kb/store.hpp"

namespace pnp::kb {

// Bounds of the engine.
inline constexpr std::size_t kMaxQueryBytes = 64u << 10;
inline constexpr std::size_t kMaxResultRows = 100000;
inline constexpr std::size_t kMaxIntermediateRows = 1000000;
inline constexpr std::size_t kMaxPathNodes = 100000;  // nodes one property path search visits

Results runSelect(const QuadStore& store, std::string_view query, Deadline deadline);
bool runAsk(const QuadStore& store, std::string_view query, Deadline deadline);
// `blankCounter` numbers the fresh blank nodes the update creates (unique per store).
void runUpdate(QuadStore& store, std::string_view update, Deadline deadline,
               std::uint64_t& blankCounter);

}  // namespace pnp::kb
