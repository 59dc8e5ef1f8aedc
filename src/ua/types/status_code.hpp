// StatusCode (Part 4 §7.39, Part 6 §5.2.2.11). Named constants are generated at build time
// from the official StatusCode table into ua/types/status_codes.hpp (namespace pnp::ua::status).
#pragma once

#include <compare>
#include <cstdint>
#include <string>
#include <string_view>

namespace pnp::ua {

struct StatusCode {
    std::uint32_t value = 0;

    constexpr StatusCode() = default;
    constexpr StatusCode(std::uint32_t v)
        : value(v) {}  // NOLINT: codes are plain numbers on the wire

    constexpr bool isGood() const { return (value & 0xC0000000u) == 0; }
    constexpr bool isUncertain() const { return (value & 0xC0000000u) == 0x40000000u; }
    constexpr bool isBad() const { return (value & 0x80000000u) != 0; }
    // The code without the info bits (limit bits, overflow, ...).
    constexpr std::uint32_t code() const { return value & 0xFFFF0000u; }
    // "BadNodeIdUnknown (0x80340000)"; unknown codes print as hex.
    std::string toString() const;
    // Symbolic name only, "" when unknown.
    std::string_view name() const;

    constexpr bool operator==(const StatusCode&) const = default;
    constexpr auto operator<=>(const StatusCode&) const = default;
};

}  // namespace pnp::ua
