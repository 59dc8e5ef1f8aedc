#include "ua/types/builtin.hpp"

#include <time.h>

#include <charconv>
#include <chrono>
#include <cstdio>
#include <ctime>

namespace pnp::ua {

namespace {
constexpr std::string_view kBuiltinNames[kBuiltinTypeCount] = {
    "Null",          "Boolean",       "SByte",           "Byte",           "Int16",
    "UInt16",        "Int32",         "UInt32",          "Int64",          "UInt64",
    "Float",         "Double",        "String",          "DateTime",       "Guid",
    "ByteString",    "XmlElement",    "NodeId",          "ExpandedNodeId", "StatusCode",
    "QualifiedName", "LocalizedText", "ExtensionObject", "DataValue",      "Variant",
    "DiagnosticInfo"};

template <class T>
struct IsVector : std::false_type {};
template <class T>
struct IsVector<std::vector<T>> : std::true_type {};

template <class T>
bool parseNumber(std::string_view s, T& out, int base = 10) {
    if (s.empty()) return false;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), out, base);
    return ec == std::errc() && p == s.data() + s.size();
}

int hexValue(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}
}  // namespace

std::string_view toString(BuiltinType t) {
    auto i = static_cast<std::size_t>(t);
    return i < kBuiltinTypeCount ? kBuiltinNames[i] : std::string_view("Unknown");
}

std::optional<BuiltinType> builtinTypeFromName(std::string_view name) {
    for (int i = 0; i < kBuiltinTypeCount; ++i)
        if (kBuiltinNames[i] == name) return static_cast<BuiltinType>(i);
    return std::nullopt;
}

// ---- DateTime --------------------------------------------------------------------------
DateTime DateTime::now() {
    auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                  std::chrono::system_clock::now().time_since_epoch())
                  .count();
    return fromUnixNanos(ns);
}

DateTime DateTime::nowCoarse() {
    timespec ts{};
    ::clock_gettime(CLOCK_REALTIME_COARSE, &ts);
    return fromUnixNanos(Int64{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec);
}

std::string DateTime::toIso8601() const {
    // Part 6 §5.2.2.5: earlier than 1601 is the minimum, later than 9999 the maximum date.
    // Clamping also keeps the subtraction from overflowing for ticks from the wire.
    constexpr Int64 kMaxTicks = 2650467743999999999LL;  // 9999-12-31T23:59:59.9999999Z
    const Int64 clamped = ticks < 0 ? 0 : ticks > kMaxTicks ? kMaxTicks : ticks;
    Int64 unix100ns = clamped - kUnixEpochTicks;
    Int64 secs = unix100ns / 10000000;
    Int64 frac = unix100ns % 10000000;
    if (frac < 0) {
        frac += 10000000;
        secs -= 1;
    }
    std::time_t t = static_cast<std::time_t>(secs);
    std::tm tm{};
    gmtime_r(&t, &tm);
    char buf[64];
    std::snprintf(buf, sizeof buf, "%04d-%02d-%02dT%02d:%02d:%02d.%07lldZ", tm.tm_year + 1900,
                  tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec,
                  static_cast<long long>(frac));
    return buf;
}

std::optional<DateTime> DateTime::parseIso8601(std::string_view s) {
    int y, mo, d, h, mi, sec;
    char tail[32] = {0};
    std::string str(s.substr(0, 60));
    if (std::sscanf(str.c_str(), "%4d-%2d-%2dT%2d:%2d:%2d%31s", &y, &mo, &d, &h, &mi, &sec, tail) <
        6)
        return std::nullopt;
    std::tm tm{};
    tm.tm_year = y - 1900;
    tm.tm_mon = mo - 1;
    tm.tm_mday = d;
    tm.tm_hour = h;
    tm.tm_min = mi;
    tm.tm_sec = sec;
    Int64 secs = timegm(&tm);
    Int64 frac = 0;
    std::string_view rest(tail);
    if (!rest.empty() && rest[0] == '.') {
        Int64 scale = 1000000;
        std::size_t i = 1;
        for (; i < rest.size() && rest[i] >= '0' && rest[i] <= '9'; ++i) {
            if (scale > 0) frac += (rest[i] - '0') * scale;
            scale /= 10;
        }
        rest.remove_prefix(i);
    }
    if (!rest.empty() && rest != "Z") return std::nullopt;
    return DateTime{kUnixEpochTicks + secs * 10000000 + frac};
}

// ---- Guid ------------------------------------------------------------------------------
std::string Guid::toString() const {
    char buf[40];
    std::snprintf(buf, sizeof buf, "%08X-%04X-%04X-%02X%02X-%02X%02X%02X%02X%02X%02X", data1, data2,
                  data3, data4[0], data4[1], data4[2], data4[3], data4[4], data4[5], data4[6],
                  data4[7]);
    return buf;
}

std::optional<Guid> Guid::parse(std::string_view s) {
    if (s.size() == 38 && s.front() == '{' && s.back() == '}') s = s.substr(1, 36);
    if (s.size() != 36 || s[8] != '-' || s[13] != '-' || s[18] != '-' || s[23] != '-')
        return std::nullopt;
    Guid g;
    if (!parseNumber(s.substr(0, 8), g.data1, 16) || !parseNumber(s.substr(9, 4), g.data2, 16) ||
        !parseNumber(s.substr(14, 4), g.data3, 16))
        return std::nullopt;
    std::string hex = std::string(s.substr(19, 4)) + std::string(s.substr(24, 12));
    for (int i = 0; i < 8; ++i) {
        int hi = hexValue(hex[2 * i]), lo = hexValue(hex[2 * i + 1]);
        if (hi < 0 || lo < 0) return std::nullopt;
        g.data4[i] = static_cast<Byte>(hi * 16 + lo);
    }
    return g;
}

// ---- ByteString base64 -------------------------------------------------------------------
namespace {
constexpr char kB64[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
int b64Value(char c) {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    if (c == '+' || c == '-') return 62;
    if (c == '/' || c == '_') return 63;
    return -1;
}
}  // namespace

ByteString::ByteString(const Byte* p, std::size_t n) : ByteString() {
    if (n > static_cast<std::size_t>(INT32_MAX)) throw std::length_error("ByteString too long");
    if (n <= kInline) {
        if (n != 0) std::memcpy(small_, p, n);
    } else {
        ByteBlock* b = ByteBlock::create(n);
        std::memcpy(b->data(), p, n);
        heap_ = Heap{b->data(), b};
        far_ = true;
    }
    size_ = static_cast<UInt32>(n);
}

void ByteString::assign(const Byte* p, std::size_t n) {
    if (far_ && n > kInline && heap_.block->unique() && heap_.data == heap_.block->data() &&
        heap_.block->capacity() >= n) {
        std::memmove(heap_.block->data(), p, n);
        size_ = static_cast<UInt32>(n);
        return;
    }
    *this = ByteString(p, n);
}

std::string ByteString::toBase64() const {
    const std::string_view bytes = view();
    std::string out;
    out.reserve((bytes.size() + 2) / 3 * 4);
    std::size_t i = 0;
    auto at = [&](std::size_t k) { return static_cast<unsigned>(static_cast<Byte>(bytes[k])); };
    for (; i + 2 < bytes.size(); i += 3) {
        unsigned v = at(i) << 16 | at(i + 1) << 8 | at(i + 2);
        out += kB64[v >> 18];
        out += kB64[(v >> 12) & 63];
        out += kB64[(v >> 6) & 63];
        out += kB64[v & 63];
    }
    if (i + 1 == bytes.size()) {
        unsigned v = at(i) << 16;
        out += kB64[v >> 18];
        out += kB64[(v >> 12) & 63];
        out += "==";
    } else if (i + 2 == bytes.size()) {
        unsigned v = at(i) << 16 | at(i + 1) << 8;
        out += kB64[v >> 18];
        out += kB64[(v >> 12) & 63];
        out += kB64[(v >> 6) & 63];
        out += '=';
    }
    return out;
}

std::optional<ByteString> ByteString::fromBase64(std::string_view s) {
    std::string out;
    unsigned acc = 0;
    int bits = 0;
    for (char c : s) {
        if (c == '=' || c == '\n' || c == '\r' || c == ' ') continue;
        int v = b64Value(c);
        if (v < 0) return std::nullopt;
        acc = (acc << 6) | static_cast<unsigned>(v);
        bits += 6;
        if (bits >= 8) {
            bits -= 8;
            out += static_cast<char>((acc >> bits) & 0xFF);
        }
    }
    return ByteString(out);
}

// ---- NodeId ------------------------------------------------------------------------------
bool NodeId::isNull() const {
    if (ns_ != 0) return false;
    switch (idType()) {
        case IdType::Numeric:
            return numeric() == 0;
        case IdType::String:
            return string().empty();
        case IdType::Guid:
            return guid() == Guid{};
        case IdType::Opaque:
            return opaque().empty();
    }
    return false;
}

std::string NodeId::toString() const {
    std::string out;
    if (ns_ != 0) out = "ns=" + std::to_string(ns_) + ";";
    switch (idType()) {
        case IdType::Numeric:
            out += "i=" + std::to_string(numeric());
            break;
        case IdType::String:
            out += "s=" + string();
            break;
        case IdType::Guid:
            out += "g=" + guid().toString();
            break;
        case IdType::Opaque:
            out += "b=" + opaque().toBase64();
            break;
    }
    return out;
}

std::optional<NodeId> NodeId::parse(std::string_view s) {
    UInt16 ns = 0;
    if (s.starts_with("ns=")) {
        auto semi = s.find(';');
        if (semi == std::string_view::npos || !parseNumber(s.substr(3, semi - 3), ns))
            return std::nullopt;
        s.remove_prefix(semi + 1);
    }
    if (s.size() < 2 || s[1] != '=') return std::nullopt;
    std::string_view v = s.substr(2);
    switch (s[0]) {
        case 'i': {
            UInt32 id;
            if (!parseNumber(v, id)) return std::nullopt;
            return NodeId(ns, id);
        }
        case 's':
            return NodeId(ns, std::string(v));
        case 'g': {
            auto g = Guid::parse(v);
            if (!g) return std::nullopt;
            return NodeId(ns, *g);
        }
        case 'b': {
            auto b = ByteString::fromBase64(v);
            if (!b) return std::nullopt;
            return NodeId(ns, std::move(*b));
        }
    }
    return std::nullopt;
}

std::size_t NodeId::hash() const {
    std::size_t h = std::hash<UInt16>()(ns_) * 0x9E3779B97F4A7C15ull;
    switch (idType()) {
        case IdType::Numeric:
            return h ^ std::hash<UInt32>()(numeric());
        case IdType::String:
            return h ^ std::hash<std::string>()(string());
        case IdType::Guid:
            return h ^
                   std::hash<std::string_view>()(
                       std::string_view(reinterpret_cast<const char*>(&guid().data1), 4)) ^
                   guid().data4[7];
        case IdType::Opaque:
            return h ^ std::hash<std::string_view>()(opaque().view()) ^ 0x55;
    }
    return h;
}

std::string ExpandedNodeId::toString() const {
    std::string out;
    if (serverIndex != 0) out += "svr=" + std::to_string(serverIndex) + ";";
    if (!namespaceUri.empty()) {
        out += "nsu=" + namespaceUri + ";";
        NodeId local = nodeId;
        local.setNamespaceIndex(0);
        return out + local.toString();
    }
    return out + nodeId.toString();
}

std::optional<ExpandedNodeId> ExpandedNodeId::parse(std::string_view s) {
    ExpandedNodeId out;
    if (s.starts_with("svr=")) {
        auto semi = s.find(';');
        if (semi == std::string_view::npos || !parseNumber(s.substr(4, semi - 4), out.serverIndex))
            return std::nullopt;
        s.remove_prefix(semi + 1);
    }
    if (s.starts_with("nsu=")) {
        // The URI ends at the last ';' before the identifier ("nsu=urn:x;s=a;b" keeps "a;b").
        auto idPos = s.find(";i=");
        for (auto k : {";s=", ";g=", ";b="}) idPos = std::min(idPos, s.find(k));
        if (idPos == std::string_view::npos) return std::nullopt;
        out.namespaceUri = std::string(s.substr(4, idPos - 4));
        s.remove_prefix(idPos + 1);
    }
    auto id = NodeId::parse(s);
    if (!id) return std::nullopt;
    out.nodeId = std::move(*id);
    return out;
}

std::string QualifiedName::toString() const {
    return namespaceIndex == 0 ? name : std::to_string(namespaceIndex) + ":" + name;
}

QualifiedName QualifiedName::parse(std::string_view s) {
    auto colon = s.find(':');
    UInt16 ns = 0;
    if (colon != std::string_view::npos && parseNumber(s.substr(0, colon), ns))
        return {ns, std::string(s.substr(colon + 1))};
    return {0, std::string(s)};
}

bool DiagnosticInfo::operator==(const DiagnosticInfo& o) const {
    if (symbolicId != o.symbolicId || namespaceUri != o.namespaceUri ||
        localizedText != o.localizedText || locale != o.locale ||
        additionalInfo != o.additionalInfo || innerStatusCode != o.innerStatusCode)
        return false;
    if (!innerDiagnosticInfo || !o.innerDiagnosticInfo)
        return !innerDiagnosticInfo && !o.innerDiagnosticInfo;
    return *innerDiagnosticInfo == *o.innerDiagnosticInfo;
}

// ---- Variant -----------------------------------------------------------------------------
// The storage's special members and alternative switches, compiled here once (builtin.hpp).
Variant::Variant() noexcept = default;
Variant::Variant(const Variant& o) = default;
Variant::Variant(Variant&& o) noexcept = default;
Variant& Variant::operator=(const Variant& o) = default;
Variant& Variant::operator=(Variant&& o) noexcept = default;
Variant::~Variant() = default;
Variant::Variant(const char* s) : data_(String(s)) {}

#define PNP_UA_VARIANT_ASSIGN(T)                              \
    void Variant::assignScalar(T&& v) {                       \
        data_.template emplace<Slot<T>>(std::move(v));        \
        dims_.clear();                                        \
    }                                                         \
    void Variant::assignArray(std::vector<T>&& v) {           \
        data_.template emplace<std::vector<T>>(std::move(v)); \
        dims_.clear();                                        \
    }
PNP_UA_FOR_EACH_SCALAR_TYPE(PNP_UA_VARIANT_ASSIGN)
#undef PNP_UA_VARIANT_ASSIGN
void Variant::assignArray(std::vector<Variant>&& v) {
    data_.template emplace<std::vector<Variant>>(std::move(v));
    dims_.clear();
}

std::size_t Variant::arrayLength() const {
    return std::visit(
        [](const auto& x) -> std::size_t {
            using X = std::decay_t<decltype(x)>;
            if constexpr (IsVector<X>::value)
                return x.size();
            else
                return 0;
        },
        data_);
}

bool Variant::operator==(const Variant& o) const { return data_ == o.data_ && dims_ == o.dims_; }

namespace {
std::string scalarToString(const Boolean& v) { return v ? "true" : "false"; }
template <class T>
std::string scalarToString(const T& v) requires std::is_arithmetic_v<T> {
    if constexpr (sizeof(T) == 1)
        return std::to_string(static_cast<int>(v));
    else if constexpr (std::is_floating_point_v<T>) {
        char buf[64];
        std::snprintf(buf, sizeof buf, "%.17g", static_cast<double>(v));
        return buf;
    } else
        return std::to_string(v);
}
std::string scalarToString(const String& v) { return "\"" + v + "\""; }
std::string scalarToString(const DateTime& v) { return v.toIso8601(); }
std::string scalarToString(const Guid& v) { return v.toString(); }
std::string scalarToString(const ByteString& v) {
    return "0x" + [&] {
        std::string h;
        static const char* d = "0123456789abcdef";
        for (Byte b : v) {
            h += d[b >> 4];
            h += d[b & 15];
        }
        return h;
    }();
}
std::string scalarToString(const XmlElement& v) { return v.xml; }
std::string scalarToString(const NodeId& v) { return v.toString(); }
std::string scalarToString(const ExpandedNodeId& v) { return v.toString(); }
std::string scalarToString(const StatusCode& v) { return v.toString(); }
std::string scalarToString(const QualifiedName& v) { return v.toString(); }
std::string scalarToString(const LocalizedText& v) {
    return v.locale.empty() ? "\"" + v.text + "\"" : "\"" + v.text + "\"@" + v.locale;
}
std::string scalarToString(const ExtensionObject& v) {
    return "ExtensionObject(" + v.typeId.toString() + ", " + std::to_string(v.body.size()) +
           " bytes)";
}
std::string scalarToString(const DiagnosticInfo&) { return "DiagnosticInfo"; }
std::string scalarToString(const Variant& v) { return v.toString(); }
std::string scalarToString(const DataValue& v) {
    std::string s = v.value ? v.value->toString() : "null";
    if (v.status) s += " (" + v.status->toString() + ")";
    return s;
}
template <class T>
std::string scalarToString(const Box<T>& v) {
    return scalarToString(*v);
}
}  // namespace

std::string Variant::toString() const {
    return std::visit(
        [&](const auto& x) -> std::string {
            using X = std::decay_t<decltype(x)>;
            if constexpr (std::is_same_v<X, std::monostate>) {
                return "null";
            } else if constexpr (std::is_same_v<X, detail::NoScalarVariant>) {
                return "invalid";
            } else if constexpr (IsVector<X>::value) {
                std::string s = "[";
                for (std::size_t i = 0; i < x.size(); ++i) {
                    if (i) s += ", ";
                    if (i == 32) {
                        s += "... (" + std::to_string(x.size()) + " elements)";
                        break;
                    }
                    s += scalarToString(static_cast<typename X::value_type>(x[i]));
                }
                return s + "]";
            } else {
                return scalarToString(x);
            }
        },
        data_);
}

}  // namespace pnp::ua
