// StatusCode names, from the StatusCode table generated at build time
// (ua/types/status_code_table.inc, see tools/codegen/gen_ns0.py).
#include "ua/types/status_code.hpp"

#include <algorithm>
#include <cstdio>
#include <iterator>

#include "ua/types/status_codes.hpp"

namespace pnp::ua {
namespace {

constexpr StatusCodeInfo kStatusCodes[] = {
#include "ua/types/status_code_table.inc"
};

constexpr bool byValue(const StatusCodeInfo& a, const StatusCodeInfo& b) {
    return a.value < b.value;
}
static_assert(std::size(kStatusCodes) == kStatusCodeCount);
static_assert(std::is_sorted(std::begin(kStatusCodes), std::end(kStatusCodes), byValue));
static_assert(std::adjacent_find(std::begin(kStatusCodes), std::end(kStatusCodes),
                                 [](const StatusCodeInfo& a, const StatusCodeInfo& b) {
                                     return a.value == b.value;
                                 }) == std::end(kStatusCodes),
              "status code values must be unique");

std::string hex(std::uint32_t v) {
    char buf[16];
    std::snprintf(buf, sizeof buf, "0x%08X", static_cast<unsigned>(v));
    return buf;
}

}  // namespace

std::span<const StatusCodeInfo> allStatusCodes() { return kStatusCodes; }

const StatusCodeInfo* findStatusCode(StatusCode s) {
    const std::uint32_t code = s.code();
    auto it =
        std::lower_bound(std::begin(kStatusCodes), std::end(kStatusCodes), code,
                         [](const StatusCodeInfo& e, std::uint32_t v) { return e.value < v; });
    return it != std::end(kStatusCodes) && it->value == code ? &*it : nullptr;
}

std::optional<StatusCode> statusCodeFromName(std::string_view name) {
    for (const auto& e : kStatusCodes)
        if (e.name == name) return StatusCode{e.value};
    return std::nullopt;
}

std::string_view StatusCode::name() const {
    const StatusCodeInfo* e = findStatusCode(*this);
    return e != nullptr ? e->name : std::string_view{};
}

std::string StatusCode::toString() const {
    std::string_view n = name();
    if (n.empty()) return hex(value);
    std::string s(n);
    s += " (";
    s += hex(value);
    s += ')';
    return s;
}

}  // namespace pnp::ua
