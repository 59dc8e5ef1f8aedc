#pragma once

#include <cstddef>
#include <filesystem>
#include <string_view>

#include "world/cell_description.hpp"
#include "world/result.hpp"

namespace pnp::world {

// The cell file format (docs/cell-file.md): YAML, `pnp-cell: 1`.
inline constexpr int kCellFormatVersion = 1;

// Bounds that keep a hostile or broken file from costing much memory or time.
inline constexpr std::size_t kMaxCellFileBytes = 1024 * 1024;
inline constexpr std::size_t kMaxRobots = 16;
inline constexpr std::size_t kMaxTables = 64;
inline constexpr std::size_t kMaxTools = 64;
inline constexpr std::size_t kMaxDocks = 64;
inline constexpr std::size_t kMaxObjects = 1024;

// Reads and validates a cell file. Stops at the first problem; its message is
// "FILE:LINE: problem". Never throws.
Result<CellDescription> loadCellFile(const std::filesystem::path& file);

// The same for a text already in memory; fileNameForErrors is the FILE of the messages.
Result<CellDescription> parseCellDescription(std::string_view text,
                                             std::string_view fileNameForErrors);

}  // namespace pnp::world
