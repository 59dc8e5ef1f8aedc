// Turtle files read with serd (docs/knowledge-base.md): every triple as terms, or a KbError
// "file:line:col: what is wrong" for the first error.
#pragma once

#include <array>
#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "kb/knowledge_base.hpp"

namespace pnp::kb {

// The largest Turtle file read (bytes).
inline constexpr std::size_t kMaxTurtleFileBytes = 16u << 20;

using TermTriple = std::array<Term, 3>;

// Parses `file`. Blank node labels get `blankPrefix` in front, so that two files' _:b1 differ.
std::vector<TermTriple> parseTurtleFile(const std::filesystem::path& file,
                                        const std::string& blankPrefix);

}  // namespace pnp::kb
