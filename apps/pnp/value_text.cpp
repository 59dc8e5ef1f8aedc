#include "value_text.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <type_traits>
#include <variant>
#include <vector>

#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::cli {

using json = Json;

namespace {

template <class T>
struct Tag {
    using type = T;
};

template <class T>
struct IsVector : std::false_type {};
template <class T>
struct IsVector<std::vector<T>> : std::true_type {};

// Calls f(Tag<T>{}) for the C++ type T that holds a scalar of built-in type t.
template <class F>
decltype(auto) withType(BuiltinType t, F&& f) {
    switch (t) {
        case BuiltinType::Boolean:
            return f(Tag<Boolean>{});
        case BuiltinType::SByte:
            return f(Tag<SByte>{});
        case BuiltinType::Byte:
            return f(Tag<Byte>{});
        case BuiltinType::Int16:
            return f(Tag<Int16>{});
        case BuiltinType::UInt16:
            return f(Tag<UInt16>{});
        case BuiltinType::Int32:
            return f(Tag<Int32>{});
        case BuiltinType::UInt32:
            return f(Tag<UInt32>{});
        case BuiltinType::Int64:
            return f(Tag<Int64>{});
        case BuiltinType::UInt64:
            return f(Tag<UInt64>{});
        case BuiltinType::Float:
            return f(Tag<Float>{});
        case BuiltinType::Double:
            return f(Tag<Double>{});
        case BuiltinType::String:
            return f(Tag<String>{});
        case BuiltinType::DateTime:
            return f(Tag<DateTime>{});
        case BuiltinType::Guid:
            return f(Tag<Guid>{});
        case BuiltinType::ByteString:
            return f(Tag<ByteString>{});
        case BuiltinType::XmlElement:
            return f(Tag<XmlElement>{});
        case BuiltinType::NodeId:
            return f(Tag<NodeId>{});
        case BuiltinType::ExpandedNodeId:
            return f(Tag<ExpandedNodeId>{});
        case BuiltinType::StatusCode:
            return f(Tag<StatusCode>{});
        case BuiltinType::QualifiedName:
            return f(Tag<QualifiedName>{});
        case BuiltinType::LocalizedText:
            return f(Tag<LocalizedText>{});
        case BuiltinType::ExtensionObject:
            return f(Tag<ExtensionObject>{});
        case BuiltinType::DataValue:
            return f(Tag<DataValue>{});
        case BuiltinType::Variant:
            return f(Tag<Variant>{});
        case BuiltinType::DiagnosticInfo:
            return f(Tag<DiagnosticInfo>{});
        case BuiltinType::Null:
            break;
    }
    throw ValueError("a value cannot be of type Null");
}

std::string lower(std::string_view s) {
    std::string out(s);
    for (auto& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return out;
}

std::string_view trim(std::string_view s) {
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
    while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
    return s;
}

[[noreturn]] void fail(BuiltinType t, std::string_view text, std::string_view why = {}) {
    std::string msg = "cannot convert \"" + std::string(text.substr(0, 200)) + "\" to " +
                      std::string(toString(t));
    if (!why.empty()) msg += ": " + std::string(why);
    throw ValueError(msg);
}

int hexDigit(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

// ---- numbers ---------------------------------------------------------------------------
template <class T>
T parseInteger(std::string_view text) {
    constexpr BuiltinType bt = BuiltinTypeOf<T>::value;
    std::string_view s = trim(text);
    bool negative = false;
    if (!s.empty() && (s[0] == '+' || s[0] == '-')) {
        negative = s[0] == '-';
        s.remove_prefix(1);
    }
    int base = 10;
    if (s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X')) {
        base = 16;
        s.remove_prefix(2);
    }
    if (s.empty() || s[0] == '+' || s[0] == '-') fail(bt, text, "not an integer");
    unsigned long long magnitude = 0;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), magnitude, base);
    if (ec == std::errc::result_out_of_range) fail(bt, text, "out of range");
    if (ec != std::errc() || p != s.data() + s.size()) fail(bt, text, "not an integer");
    if constexpr (std::is_signed_v<T>) {
        using L = std::numeric_limits<T>;
        unsigned long long limit = negative ? static_cast<unsigned long long>(L::max()) + 1
                                            : static_cast<unsigned long long>(L::max());
        if (magnitude > limit) fail(bt, text, "out of range");
        if (!negative) return static_cast<T>(magnitude);
        return static_cast<T>(-static_cast<long long>(magnitude - 1) - 1);
    } else {
        if (negative && magnitude != 0) fail(bt, text, "out of range");
        if (magnitude > std::numeric_limits<T>::max()) fail(bt, text, "out of range");
        return static_cast<T>(magnitude);
    }
}

template <class T>
T parseFloating(std::string_view text) {
    constexpr BuiltinType bt = BuiltinTypeOf<T>::value;
    std::string_view s = trim(text);
    std::string l = lower(s);
    if (l == "nan") return std::numeric_limits<T>::quiet_NaN();
    if (l == "inf" || l == "infinity" || l == "+inf" || l == "+infinity")
        return std::numeric_limits<T>::infinity();
    if (l == "-inf" || l == "-infinity") return -std::numeric_limits<T>::infinity();
    if (!s.empty() && s[0] == '+') s.remove_prefix(1);
    T v{};
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (ec == std::errc::result_out_of_range) fail(bt, text, "out of range");
    if (s.empty() || ec != std::errc() || p != s.data() + s.size()) fail(bt, text, "not a number");
    return v;
}

template <class T>
std::string floatText(T v) {
    if (std::isnan(v)) return "NaN";
    if (std::isinf(v)) return v > 0 ? "Infinity" : "-Infinity";
    char buf[64];
    auto [p, ec] = std::to_chars(buf, buf + sizeof buf, v);
    (void)ec;
    return std::string(buf, p);
}

template <class T>
json floatJson(T v) {
    if (std::isnan(v) || std::isinf(v)) return floatText(v);
    // The shortest text of the float, read back as a double: 0.1f -> 0.1, not 0.100000001.
    std::string s = floatText(v);
    double d = 0;
    std::from_chars(s.data(), s.data() + s.size(), d);
    return d;
}

// ---- DateTime --------------------------------------------------------------------------
// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's days_from_civil).
long long daysFromCivil(long long y, unsigned m, unsigned d) {
    y -= m <= 2;
    const long long era = (y >= 0 ? y : y - 399) / 400;
    const unsigned yoe = static_cast<unsigned>(y - era * 400);
    const unsigned doy = (153 * (m + (m > 2 ? -3 : 9)) + 2) / 5 + d - 1;
    const unsigned doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    return era * 146097 + static_cast<long long>(doe) - 719468;
}

bool digits(std::string_view s, std::size_t pos, std::size_t n, int& out) {
    if (pos + n > s.size()) return false;
    out = 0;
    for (std::size_t i = pos; i < pos + n; ++i) {
        if (s[i] < '0' || s[i] > '9') return false;
        out = out * 10 + (s[i] - '0');
    }
    return true;
}

// ---- ByteString ------------------------------------------------------------------------
std::optional<ByteString> parseHex(std::string_view s) {
    std::string out;
    std::string digitsOnly;
    for (char c : s)
        if (c != ' ' && c != ':' && c != '_') digitsOnly += c;
    if (digitsOnly.size() % 2 != 0) return std::nullopt;
    for (std::size_t i = 0; i < digitsOnly.size(); i += 2) {
        int hi = hexDigit(digitsOnly[i]), lo = hexDigit(digitsOnly[i + 1]);
        if (hi < 0 || lo < 0) return std::nullopt;
        out += static_cast<char>(hi * 16 + lo);
    }
    return ByteString(std::move(out));
}

std::optional<ByteString> parseBase64(std::string_view s) {
    // Strict enough to reject typos: only the base64 alphabets (standard and URL-safe),
    // padding only at the end, and a length that leaves no dangling bits.
    std::size_t n = 0, pad = 0;
    for (char c : s) {
        if (c == '\n' || c == '\r' || c == ' ') continue;
        if (c == '=') {
            ++pad;
            continue;
        }
        if (pad != 0) return std::nullopt;
        if (!std::isalnum(static_cast<unsigned char>(c)) && c != '+' && c != '/' && c != '-' &&
            c != '_')
            return std::nullopt;
        ++n;
    }
    if (pad > 2 || n % 4 == 1) return std::nullopt;
    return ByteString::fromBase64(s);
}

// ---- scalar parsing from text ----------------------------------------------------------
template <class T>
T parseScalar(std::string_view text, const ParseOptions& opt);

Variant inferFromJson(const json& j, const ParseOptions& opt);
Variant variantFromJson(const json& j, const ParseOptions& opt);
DataValue dataValueFromJson(const json& j, const ParseOptions& opt);
DiagnosticInfo diagnosticInfoFromJson(const json& j, const ParseOptions& opt);
ExtensionObject extensionObjectFromJson(const json& j, const ParseOptions& opt);
template <class T>
T scalarFromJson(const json& j, const ParseOptions& opt);
LocalizedText localizedTextFromJson(const json& j);

json parseJsonText(BuiltinType t, std::string_view text) {
    try {
        return json::parse(text);
    } catch (const json::parse_error&) {
        fail(t, text, "not valid JSON");
    }
}

NodeId parseNodeIdText(std::string_view text, const ParseOptions& opt) {
    std::string_view s = trim(text);
    if (s.starts_with("nsu=") || s.starts_with("svr=")) {
        auto x = ExpandedNodeId::parse(s);
        if (!x) fail(BuiltinType::NodeId, text, "not a NodeId");
        if (x->serverIndex != 0) fail(BuiltinType::NodeId, text, "a NodeId has no server index");
        if (!opt.namespaceIndex)
            fail(BuiltinType::NodeId, text, "namespace URIs cannot be resolved here");
        NodeId n = x->nodeId;
        n.setNamespaceIndex(opt.namespaceIndex(x->namespaceUri));
        return n;
    }
    auto n = NodeId::parse(s);
    if (!n) fail(BuiltinType::NodeId, text, "expected i=85, ns=1;s=Name, ns=1;g=..., ns=1;b=...");
    return *n;
}

template <class T>
T parseScalar(std::string_view text, const ParseOptions& opt) {
    constexpr BuiltinType bt = BuiltinTypeOf<T>::value;
    if constexpr (std::is_same_v<T, Boolean>) {
        std::string l = lower(trim(text));
        if (l == "true" || l == "1") return true;
        if (l == "false" || l == "0") return false;
        fail(bt, text, "expected true or false");
    } else if constexpr (std::is_integral_v<T>) {
        return parseInteger<T>(text);
    } else if constexpr (std::is_floating_point_v<T>) {
        return parseFloating<T>(text);
    } else if constexpr (std::is_same_v<T, String>) {
        return String(text);
    } else if constexpr (std::is_same_v<T, XmlElement>) {
        return XmlElement{std::string(text)};
    } else if constexpr (std::is_same_v<T, DateTime>) {
        auto t = parseDateTime(text);
        if (!t) fail(bt, text, "expected ISO-8601 like 2024-05-06T07:08:09.123Z");
        return *t;
    } else if constexpr (std::is_same_v<T, Guid>) {
        auto g = Guid::parse(trim(text));
        if (!g) fail(bt, text, "expected 72962B91-FA75-4AE6-8D28-B404DC7DAF63");
        return *g;
    } else if constexpr (std::is_same_v<T, ByteString>) {
        std::string_view s = trim(text);
        std::optional<ByteString> b;
        if (s.starts_with("0x") || s.starts_with("0X"))
            b = parseHex(s.substr(2));
        else
            b = parseBase64(s);
        if (!b) fail(bt, text, "expected 0x-hex or base64");
        return *b;
    } else if constexpr (std::is_same_v<T, NodeId>) {
        return parseNodeIdText(text, opt);
    } else if constexpr (std::is_same_v<T, ExpandedNodeId>) {
        auto x = ExpandedNodeId::parse(trim(text));
        if (!x) fail(bt, text, "expected i=85, ns=1;s=Name, nsu=urn:x;s=Name, svr=1;i=85");
        return *x;
    } else if constexpr (std::is_same_v<T, StatusCode>) {
        std::string_view s = trim(text);
        if (auto c = statusCodeFromName(s)) return *c;
        // "BadTimeout (0x800A0000)", the form of StatusCode::toString()
        if (auto open = s.find(" (0x"); open != std::string_view::npos && s.ends_with(")"))
            return StatusCode{parseInteger<UInt32>(s.substr(open + 2, s.size() - open - 3))};
        if (!s.empty() && (std::isdigit(static_cast<unsigned char>(s[0]))))
            return StatusCode{parseInteger<UInt32>(s)};
        fail(bt, text, "expected a status name (BadTimeout) or number (0x800A0000)");
    } else if constexpr (std::is_same_v<T, QualifiedName>) {
        return QualifiedName::parse(text);
    } else if constexpr (std::is_same_v<T, LocalizedText>) {
        std::string_view s = trim(text);
        if (s.starts_with("{")) return localizedTextFromJson(parseJsonText(bt, s));
        if (s.starts_with("\"")) {
            // "text"@locale (the form toText prints)
            auto at = s.rfind("\"@");
            if (at != std::string_view::npos && at > 0) {
                try {
                    auto t = json::parse(s.substr(0, at + 1));
                    if (t.is_string())
                        return LocalizedText(std::string(s.substr(at + 2)), t.get<std::string>());
                } catch (const json::parse_error&) {
                }
            }
        }
        return LocalizedText("", std::string(text));
    } else if constexpr (std::is_same_v<T, ExtensionObject>) {
        return extensionObjectFromJson(parseJsonText(bt, text), opt);
    } else if constexpr (std::is_same_v<T, DataValue>) {
        return dataValueFromJson(parseJsonText(bt, text), opt);
    } else if constexpr (std::is_same_v<T, DiagnosticInfo>) {
        return diagnosticInfoFromJson(parseJsonText(bt, text), opt);
    } else {
        static_assert(std::is_same_v<T, Variant>);
        // A scalar of BaseDataType: JSON when it is JSON, else a String.
        json j;
        try {
            j = json::parse(text);
        } catch (const json::parse_error&) {
            return Variant(String(text));
        }
        return inferFromJson(j, opt);
    }
}

// ---- scalar conversion from JSON -------------------------------------------------------
std::string jsonTextForError(const json& j) { return j.dump().substr(0, 200); }

template <class T>
T scalarFromJson(const json& j, const ParseOptions& opt) {
    constexpr BuiltinType bt = BuiltinTypeOf<T>::value;
    if constexpr (std::is_same_v<T, Variant>) {
        return variantFromJson(j, opt);
    } else if constexpr (std::is_same_v<T, DataValue>) {
        return dataValueFromJson(j, opt);
    } else if constexpr (std::is_same_v<T, DiagnosticInfo>) {
        return diagnosticInfoFromJson(j, opt);
    } else if constexpr (std::is_same_v<T, ExtensionObject>) {
        return extensionObjectFromJson(j, opt);
    } else if constexpr (std::is_same_v<T, LocalizedText>) {
        return localizedTextFromJson(j);
    } else {
        if (j.is_string()) return parseScalar<T>(j.get_ref<const std::string&>(), opt);
        if constexpr (std::is_same_v<T, Boolean>) {
            if (j.is_boolean()) return j.get<bool>();
            if (j.is_number_integer() && (j == 0 || j == 1)) return j == 1;
        } else if constexpr (std::is_integral_v<T>) {
            if (j.is_number_integer() || j.is_number_unsigned()) return parseInteger<T>(j.dump());
            if (j.is_number_float()) {
                double d = j.get<double>();
                if (std::floor(d) == d && std::fabs(d) < 1.9e19) {
                    char buf[32];
                    std::snprintf(buf, sizeof buf, "%.0f", d);
                    return parseInteger<T>(buf);
                }
                fail(bt, jsonTextForError(j), "not an integer");
            }
        } else if constexpr (std::is_floating_point_v<T>) {
            if (j.is_number()) {
                double d = j.get<double>();
                if constexpr (std::is_same_v<T, Float>) {
                    if (std::isfinite(d) && std::fabs(d) > std::numeric_limits<Float>::max())
                        fail(bt, jsonTextForError(j), "out of range");
                }
                return static_cast<T>(d);
            }
        } else if constexpr (std::is_same_v<T, StatusCode>) {
            if (j.is_number_unsigned() || j.is_number_integer())
                return StatusCode{parseInteger<UInt32>(j.dump())};
        }
        fail(bt, jsonTextForError(j), "unexpected JSON value");
    }
}

LocalizedText localizedTextFromJson(const json& j) {
    if (j.is_string()) return parseScalar<LocalizedText>(j.get_ref<const std::string&>(), {});
    if (!j.is_object()) fail(BuiltinType::LocalizedText, jsonTextForError(j));
    LocalizedText t;
    for (const auto& [k, v] : j.items()) {
        std::string key = lower(k);
        if (!v.is_string()) fail(BuiltinType::LocalizedText, jsonTextForError(j), k);
        if (key == "locale")
            t.locale = v.get<std::string>();
        else if (key == "text")
            t.text = v.get<std::string>();
        else
            fail(BuiltinType::LocalizedText, jsonTextForError(j), "unknown field " + k);
    }
    return t;
}

// ---- structures given as JSON -------------------------------------------------------------
// Encodes {"Low":1,"High":2} as the binary body of a structure, field by field, driven by
// the DataType's StructureDefinition (Part 6 §5.2.6 - §5.2.8).
class StructureEncoder {
  public:
    StructureEncoder(TypeCatalog& types, const ParseOptions& opt) : types_(types), opt_(opt) {}

    void structure(BinaryEncoder& e, const NodeId& dataType, const StructureDefinition& def,
                   const json& body) {
        if (++depth_ > 16) fail(BuiltinType::ExtensionObject, "", "structures nested too deeply");
        const std::string where = "structure " + dataType.toString();
        if (!body.is_object())
            fail(BuiltinType::ExtensionObject, jsonTextForError(body),
                 where + ": expected an object");
        // Every key must name a field (typos are errors, not silently default values).
        for (const auto& [k, v] : body.items())
            if (field(def, k) == nullptr)
                fail(BuiltinType::ExtensionObject, jsonTextForError(body),
                     where + " has no field " + k);
        const bool subtyped = def.structureType == StructureType::StructureWithSubtypedValues ||
                              def.structureType == StructureType::UnionWithSubtypedValues;
        switch (def.structureType) {
            case StructureType::Union:
            case StructureType::UnionWithSubtypedValues: {
                if (body.size() > 1)
                    fail(BuiltinType::ExtensionObject, jsonTextForError(body),
                         where + " is a union: give one field");
                UInt32 index = 0;
                for (UInt32 i = 0; i < def.fields.size(); ++i)
                    if (!body.empty() && value(body, def.fields[i].name) != nullptr) index = i + 1;
                e.number<UInt32>(index);
                if (index != 0)
                    fieldValue(e, def.fields[index - 1], *value(body, def.fields[index - 1].name),
                               subtyped);
                break;
            }
            case StructureType::StructureWithOptionalFields: {
                UInt32 mask = 0, bit = 0;
                for (const auto& f : def.fields) {
                    if (!f.isOptional) continue;
                    const json* v = value(body, f.name);
                    if (v != nullptr && !v->is_null()) mask |= 1u << bit;
                    ++bit;
                }
                e.number<UInt32>(mask);
                for (const auto& f : def.fields) {
                    const json* v = value(body, f.name);
                    if (f.isOptional && (v == nullptr || v->is_null())) continue;
                    fieldValue(e, f, v == nullptr ? json() : *v, false);
                }
                break;
            }
            default:
                for (const auto& f : def.fields) {
                    const json* v = value(body, f.name);
                    fieldValue(e, f, v == nullptr ? json() : *v, subtyped && f.isOptional);
                }
        }
        --depth_;
    }

    const DataTypeDescription& describe(const NodeId& dataType) {
        auto it = cache_.find(dataType);
        if (it == cache_.end()) it = cache_.emplace(dataType, types_.describe(dataType)).first;
        return it->second;
    }

  private:
    static const StructureField* field(const StructureDefinition& def, std::string_view key) {
        for (const auto& f : def.fields)
            if (f.name == key) return &f;
        for (const auto& f : def.fields)
            if (lower(f.name) == lower(key)) return &f;
        return nullptr;
    }
    static const json* value(const json& body, const std::string& name) {
        if (auto it = body.find(name); it != body.end()) return &*it;
        for (const auto& [k, v] : body.items())
            if (lower(k) == lower(name)) return &v;
        return nullptr;
    }

    // One field: an array (ValueRank >= 0 : length + elements) or one value.
    void fieldValue(BinaryEncoder& e, const StructureField& f, const json& v, bool subtyped) {
        if (f.valueRank >= 0) {
            if (v.is_null()) {
                e.number<Int32>(-1);
                return;
            }
            if (!v.is_array())
                fail(BuiltinType::ExtensionObject, jsonTextForError(v),
                     "field " + f.name + " is an array");
            e.number<Int32>(static_cast<Int32>(v.size()));
            for (const auto& x : v) one(e, f.dataType, x, subtyped, f.name);
            return;
        }
        one(e, f.dataType, v, subtyped, f.name);
    }

    void one(BinaryEncoder& e, const NodeId& dataType, const json& v, bool subtyped,
             const std::string& name) {
        const DataTypeDescription& d = describe(dataType);
        if (d.structure && !subtyped) {  // a concrete structure is encoded inline
            structure(e, dataType, *d.structure, v.is_null() ? json::object() : v);
            return;
        }
        if (d.enumeration && v.is_string()) {
            const std::string& n = v.get_ref<const std::string&>();
            for (const auto& ef : d.enumeration->fields) {
                if (ef.name == n || ef.displayName.text == n) {
                    e.number<Int32>(static_cast<Int32>(ef.value));
                    return;
                }
            }
        }
        try {
            withType(d.builtin, [&](auto tag) {
                using T = typename decltype(tag)::type;
                if (v.is_null()) {
                    encode(e, T{});
                } else if constexpr (std::is_same_v<T, ExtensionObject>) {
                    encode(e, extensionObjectFromJson(v, opt_));
                } else {
                    encode(e, scalarFromJson<T>(v, opt_));
                }
            });
        } catch (const ValueError& x) {
            throw ValueError("field " + name + ": " + x.what());
        }
    }

    TypeCatalog& types_;
    const ParseOptions& opt_;
    std::map<NodeId, DataTypeDescription> cache_;
    int depth_ = 0;
};

// {"TypeId":"i=886","Body":"<base64>"}, {"Type":"Range","Body":{...}} or
// {"TypeId":"i=886","Type":"Range","Body":{...}} (the form toJson prints).
ExtensionObject extensionObjectFromJson(const json& j, const ParseOptions& opt) {
    constexpr BuiltinType bt = BuiltinType::ExtensionObject;
    if (j.is_null()) return ExtensionObject{};
    if (!j.is_object()) fail(bt, jsonTextForError(j), "expected {\"TypeId\":..,\"Body\":..}");
    ExtensionObject x;
    x.encoding = ExtensionObject::Encoding::Binary;
    const json* body = nullptr;
    std::string typeName;
    bool haveTypeId = false;
    for (const auto& [k, v] : j.items()) {
        std::string key = lower(k);
        if (key == "typeid" && v.is_string()) {
            auto id = NodeId::parse(v.get<std::string>());
            if (!id) fail(bt, jsonTextForError(j), "bad TypeId");
            x.typeId = *id;
            haveTypeId = true;
        } else if (key == "encoding" && v.is_string()) {
            std::string e = lower(v.get<std::string>());
            if (e == "xml")
                x.encoding = ExtensionObject::Encoding::Xml;
            else if (e != "binary")
                fail(bt, jsonTextForError(j), "Encoding must be Binary or Xml");
        } else if (key == "body") {
            body = &v;
        } else if (key == "type" && v.is_string()) {
            typeName = v.get<std::string>();
        } else {
            fail(bt, jsonTextForError(j), "unknown field " + k);
        }
    }
    if (body != nullptr && (body->is_object() || body->is_array())) {
        // A decoded structure: encode it from the DataType's definition.
        if (opt.types == nullptr)
            fail(bt, jsonTextForError(j),
                 "a decoded structure needs the DataType's definition (only available "
                 "against a server); give {\"TypeId\":..,\"Body\":\"<base64>\"} instead");
        NodeId dataType;
        if (haveTypeId) {
            if (x.typeId.namespaceIndex() == 0 && x.typeId.isNumeric())
                if (const DataTypeCodec* c = findCodecByEncodingId(x.typeId.numeric()))
                    dataType = NodeId(0, c->dataTypeId);
            if (dataType.isNull()) dataType = opt.types->dataTypeOfEncoding(x.typeId);
        } else if (!typeName.empty()) {
            for (const auto& c : allDataTypeCodecs())
                if (c.name == typeName) dataType = NodeId(0, c.dataTypeId);
        }
        if (dataType.isNull())
            fail(bt, jsonTextForError(j),
                 haveTypeId ? "unknown TypeId" : "give TypeId (the encoding node) or a known Type");
        StructureEncoder enc(*opt.types, opt);
        const DataTypeDescription& d = enc.describe(dataType);
        if (!d.structure)
            fail(bt, jsonTextForError(j), dataType.toString() + " is not a concrete structure");
        Buffer buf;
        BinaryEncoder e(buf);
        enc.structure(e, dataType, *d.structure, *body);
        if (!d.structure->defaultEncodingId.isNull()) x.typeId = d.structure->defaultEncodingId;
        x.encoding = ExtensionObject::Encoding::Binary;
        x.body.assign(reinterpret_cast<const char*>(buf.data()), buf.size());
        // Namespace 0: check the result with the generated codec.
        if (x.typeId.namespaceIndex() == 0 && x.typeId.isNumeric()) {
            if (const DataTypeCodec* c = findCodecByEncodingId(x.typeId.numeric())) {
                try {
                    BinaryDecoder d2(buf.data(), buf.size());
                    Buffer again;
                    BinaryEncoder e2(again);
                    c->reencode(d2, e2);
                    if (d2.remaining() != 0) throw DecodeError(status::BadDecodingError, "size");
                } catch (const DecodeError&) {
                    fail(bt, jsonTextForError(j),
                         "the encoded structure does not decode as " + std::string(c->name));
                }
            }
        }
        return x;
    }
    if (!haveTypeId) fail(bt, jsonTextForError(j), "TypeId missing");
    if (body == nullptr || body->is_null()) {
        x.encoding = ExtensionObject::Encoding::None;
        return x;
    }
    if (!body->is_string()) fail(bt, jsonTextForError(j), "Body must be an object or base64");
    if (x.encoding == ExtensionObject::Encoding::Xml) {
        x.body = body->get<std::string>();
    } else {
        auto b = parseBase64(body->get<std::string>());
        if (!b) fail(bt, jsonTextForError(j), "Body is not base64");
        x.body = b->str();
    }
    return x;
}

std::optional<Int32> optionalInt32(const json& v, std::string_view field, BuiltinType bt) {
    if (v.is_null()) return std::nullopt;
    try {
        return scalarFromJson<Int32>(v, {});
    } catch (const ValueError&) {
        fail(bt, jsonTextForError(v), std::string(field) + " is not an Int32");
    }
}

DiagnosticInfo diagnosticInfoFromJson(const json& j, const ParseOptions& opt) {
    constexpr BuiltinType bt = BuiltinType::DiagnosticInfo;
    if (j.is_null()) return DiagnosticInfo{};
    if (!j.is_object()) fail(bt, jsonTextForError(j), "expected a JSON object");
    DiagnosticInfo d;
    for (const auto& [k, v] : j.items()) {
        std::string key = lower(k);
        if (key == "symbolicid")
            d.symbolicId = optionalInt32(v, k, bt);
        else if (key == "namespaceuri")
            d.namespaceUri = optionalInt32(v, k, bt);
        else if (key == "localizedtext")
            d.localizedText = optionalInt32(v, k, bt);
        else if (key == "locale")
            d.locale = optionalInt32(v, k, bt);
        else if (key == "additionalinfo") {
            if (!v.is_null()) {
                if (!v.is_string()) fail(bt, jsonTextForError(j), "AdditionalInfo");
                d.additionalInfo = v.get<std::string>();
            }
        } else if (key == "innerstatuscode") {
            if (!v.is_null()) d.innerStatusCode = scalarFromJson<StatusCode>(v, opt);
        } else if (key == "innerdiagnosticinfo") {
            if (!v.is_null())
                d.innerDiagnosticInfo =
                    std::make_shared<const DiagnosticInfo>(diagnosticInfoFromJson(v, opt));
        } else {
            fail(bt, jsonTextForError(j), "unknown field " + k);
        }
    }
    return d;
}

DataValue dataValueFromJson(const json& j, const ParseOptions& opt) {
    constexpr BuiltinType bt = BuiltinType::DataValue;
    if (j.is_null()) return DataValue{};
    if (!j.is_object()) fail(bt, jsonTextForError(j), "expected a JSON object");
    DataValue d;
    auto time = [&](const json& v, std::string_view k) -> std::optional<DateTime> {
        if (v.is_null()) return std::nullopt;
        if (!v.is_string()) fail(bt, jsonTextForError(j), std::string(k));
        return scalarFromJson<DateTime>(v, opt);
    };
    auto pico = [&](const json& v, std::string_view k) -> std::optional<UInt16> {
        if (v.is_null()) return std::nullopt;
        try {
            return scalarFromJson<UInt16>(v, opt);
        } catch (const ValueError&) {
            fail(bt, jsonTextForError(j), std::string(k) + " is not a UInt16");
        }
    };
    for (const auto& [k, v] : j.items()) {
        std::string key = lower(k);
        if (key == "value") {
            if (!v.is_null()) d.value = variantFromJson(v, opt);
        } else if (key == "status" || key == "statuscode") {
            if (!v.is_null()) d.status = scalarFromJson<StatusCode>(v, opt);
        } else if (key == "sourcetimestamp") {
            d.sourceTimestamp = time(v, k);
        } else if (key == "sourcepicoseconds") {
            d.sourcePicoseconds = pico(v, k);
        } else if (key == "servertimestamp") {
            d.serverTimestamp = time(v, k);
        } else if (key == "serverpicoseconds") {
            d.serverPicoseconds = pico(v, k);
        } else {
            fail(bt, jsonTextForError(j), "unknown field " + k);
        }
    }
    return d;
}

template <class T>
Variant arrayFromJson(const json& j, const ParseOptions& opt) {
    std::vector<T> out;
    out.reserve(j.size());
    for (const auto& e : j) out.push_back(scalarFromJson<T>(e, opt));
    Variant v;
    v.setArray(std::move(out));
    return v;
}

std::vector<Int32> dimensionsFromJson(const json& j) {
    std::vector<Int32> out;
    if (!j.is_array()) throw ValueError("Dimensions must be an array of integers");
    for (const auto& e : j) out.push_back(scalarFromJson<Int32>(e, {}));
    return out;
}

// {"Type":"Int16","Body":5}, null, or a bare JSON value whose type is inferred.
Variant variantFromJson(const json& j, const ParseOptions& opt) {
    if (j.is_null()) return Variant{};
    if (j.is_object()) {
        const json* type = nullptr;
        const json* body = nullptr;
        const json* dims = nullptr;
        for (const auto& [k, v] : j.items()) {
            std::string key = lower(k);
            if (key == "type")
                type = &v;
            else if (key == "body")
                body = &v;
            else if (key == "dimensions")
                dims = &v;
            else
                fail(BuiltinType::Variant, jsonTextForError(j), "unknown field " + k);
        }
        if (type == nullptr || !type->is_string())
            fail(BuiltinType::Variant, jsonTextForError(j), "expected {\"Type\":..,\"Body\":..}");
        auto t = parseTypeName(type->get<std::string>());
        if (!t) fail(BuiltinType::Variant, jsonTextForError(j), "unknown Type");
        if (body == nullptr || body->is_null()) return Variant{};
        Shape shape = body->is_array() && t->first != BuiltinType::ExtensionObject ? Shape::Array
                                                                                   : Shape::Scalar;
        if (t->second == Shape::Array) shape = Shape::Array;
        if (t->first == BuiltinType::Variant && shape == Shape::Scalar)
            fail(BuiltinType::Variant, jsonTextForError(j), "a Variant cannot hold a Variant");
        Variant v = valueFromJson(*body, t->first, shape, opt);
        if (dims != nullptr) {
            if (!v.isArray()) fail(BuiltinType::Variant, jsonTextForError(j), "Dimensions");
            v.setArrayDimensions(dimensionsFromJson(*dims));
        }
        return v;
    }
    return inferFromJson(j, opt);
}

// A bare JSON value as a Variant: bool -> Boolean, integer -> Int32 (Int64 / UInt64 when it
// does not fit), other numbers -> Double, string -> String, array -> Variant[].
Variant inferFromJson(const json& j, const ParseOptions& opt) {
    if (j.is_null()) return Variant{};
    if (j.is_boolean()) return Variant(j.get<bool>());
    if (j.is_number_unsigned()) {
        auto u = j.get<std::uint64_t>();
        if (u <= static_cast<std::uint64_t>(std::numeric_limits<Int32>::max()))
            return Variant(static_cast<Int32>(u));
        if (u <= static_cast<std::uint64_t>(std::numeric_limits<Int64>::max()))
            return Variant(static_cast<Int64>(u));
        return Variant(static_cast<UInt64>(u));
    }
    if (j.is_number_integer()) {
        auto i = j.get<std::int64_t>();
        if (i >= std::numeric_limits<Int32>::min() && i <= std::numeric_limits<Int32>::max())
            return Variant(static_cast<Int32>(i));
        return Variant(static_cast<Int64>(i));
    }
    if (j.is_number_float()) return Variant(j.get<double>());
    if (j.is_string()) return Variant(j.get<std::string>());
    if (j.is_array()) return arrayFromJson<Variant>(j, opt);
    return variantFromJson(j, opt);
}

// ---- value -> JSON -----------------------------------------------------------------------
json scalarJson(Boolean v) { return v; }
template <class T>
requires(std::is_integral_v<T> && !std::is_same_v<T, Boolean>) json scalarJson(T v) {
    if constexpr (std::is_signed_v<T>)
        return static_cast<std::int64_t>(v);
    else
        return static_cast<std::uint64_t>(v);
}
json scalarJson(Float v) { return floatJson(v); }
json scalarJson(Double v) { return floatJson(v); }
json scalarJson(const String& v) { return v; }
json scalarJson(const DateTime& v) { return dateTimeText(v); }
json scalarJson(const Guid& v) { return v.toString(); }
json scalarJson(const ByteString& v) { return v.toBase64(); }
json scalarJson(const XmlElement& v) { return v.xml; }
json scalarJson(const NodeId& v) { return v.toString(); }
json scalarJson(const ExpandedNodeId& v) { return v.toString(); }
json scalarJson(const StatusCode& v) { return statusText(v); }
json scalarJson(const QualifiedName& v) { return v.toString(); }
json scalarJson(const LocalizedText& v) {
    json o = json::object();
    if (!v.locale.empty()) o["Locale"] = v.locale;
    o["Text"] = v.text;
    return o;
}
json scalarJson(const ExtensionObject& v) {
    if (v.empty()) return nullptr;
    try {
        return json::parse(ua::toJson(v));  // decoded by the ns0 codec registry when known
    } catch (const std::exception&) {
        json o = json::object();
        o["TypeId"] = v.typeId.toString();
        o["Encoding"] = v.encoding == ExtensionObject::Encoding::Xml ? "Xml" : "Binary";
        o["Body"] =
            v.encoding == ExtensionObject::Encoding::Xml ? v.body : ByteString(v.body).toBase64();
        return o;
    }
}
json scalarJson(const DataValue& v);
json scalarJson(const Variant& v);
json scalarJson(const DiagnosticInfo& v) {
    json o = json::object();
    if (v.symbolicId) o["SymbolicId"] = *v.symbolicId;
    if (v.namespaceUri) o["NamespaceUri"] = *v.namespaceUri;
    if (v.localizedText) o["LocalizedText"] = *v.localizedText;
    if (v.locale) o["Locale"] = *v.locale;
    if (v.additionalInfo) o["AdditionalInfo"] = *v.additionalInfo;
    if (v.innerStatusCode) o["InnerStatusCode"] = statusText(*v.innerStatusCode);
    if (v.innerDiagnosticInfo) o["InnerDiagnosticInfo"] = scalarJson(*v.innerDiagnosticInfo);
    return o;
}
template <class T>
json scalarJson(const Box<T>& v) {
    return scalarJson(*v);
}

// The value without its type: a JSON scalar / object, or an array of them.
json bodyJson(const Variant& v) {
    return std::visit(
        [](const auto& x) -> json {
            using X = std::decay_t<decltype(x)>;
            if constexpr (std::is_same_v<X, std::monostate> ||
                          std::is_same_v<X, ua::detail::NoScalarVariant>) {
                return nullptr;
            } else if constexpr (IsVector<X>::value) {
                json a = json::array();
                for (const auto& e : x)
                    a.push_back(scalarJson(static_cast<typename X::value_type>(e)));
                return a;
            } else {
                return scalarJson(x);
            }
        },
        v.storage());
}

json scalarJson(const Variant& v) {
    if (v.isEmpty()) return nullptr;
    json o = json::object();
    o["Type"] = std::string(toString(v.type()));
    o["Body"] = bodyJson(v);
    if (!v.arrayDimensions().empty()) o["Dimensions"] = v.arrayDimensions();
    return o;
}

json scalarJson(const DataValue& v) {
    json o = json::object();
    if (v.value) o["Value"] = scalarJson(*v.value);
    if (v.status) o["Status"] = statusText(*v.status);
    if (v.sourceTimestamp) o["SourceTimestamp"] = dateTimeText(*v.sourceTimestamp);
    if (v.sourcePicoseconds) o["SourcePicoseconds"] = *v.sourcePicoseconds;
    if (v.serverTimestamp) o["ServerTimestamp"] = dateTimeText(*v.serverTimestamp);
    if (v.serverPicoseconds) o["ServerPicoseconds"] = *v.serverPicoseconds;
    return o;
}

// ---- value -> human text ---------------------------------------------------------------
std::string compact(const json& j) {
    return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

template <class T>
std::string scalarText(const T& v) {
    if constexpr (std::is_same_v<T, Boolean>) {
        return v ? "true" : "false";
    } else if constexpr (std::is_integral_v<T>) {
        return std::to_string(
            static_cast<std::conditional_t<std::is_signed_v<T>, long long, unsigned long long>>(v));
    } else if constexpr (std::is_floating_point_v<T>) {
        return floatText(v);
    } else if constexpr (std::is_same_v<T, String>) {
        return v;
    } else if constexpr (std::is_same_v<T, XmlElement>) {
        return v.xml;
    } else if constexpr (std::is_same_v<T, ByteString>) {
        return hexText(v.view());
    } else if constexpr (std::is_same_v<T, LocalizedText>) {
        if (v.locale.empty()) return v.text;
        return compact(json(v.text)) + "@" + v.locale;
    } else if constexpr (std::is_same_v<T, ExtensionObject>) {
        json j = scalarJson(v);
        if (j.is_object() && j.contains("Type") && j.contains("Body"))
            return j["Type"].get<std::string>() + " " + compact(j["Body"]);
        return compact(j);
    } else if constexpr (std::is_same_v<T, DataValue> || std::is_same_v<T, DiagnosticInfo> ||
                         std::is_same_v<T, Variant>) {
        return compact(scalarJson(v));
    } else {
        json j = scalarJson(v);
        return j.is_string() ? j.get<std::string>() : compact(j);
    }
}

}  // namespace

// ---- public API --------------------------------------------------------------------------
Shape shapeOfValueRank(Int32 valueRank) {
    if (valueRank == -1) return Shape::Scalar;
    if (valueRank >= 1) return Shape::Array;
    return Shape::Auto;
}

std::optional<std::pair<BuiltinType, Shape>> parseTypeName(std::string_view name) {
    Shape shape = Shape::Auto;
    name = trim(name);
    if (name.ends_with("[]")) {
        shape = Shape::Array;
        name.remove_suffix(2);
    }
    std::string l = lower(name);
    if (l == "bool") return std::pair{BuiltinType::Boolean, shape};
    if (l == "structure") return std::pair{BuiltinType::ExtensionObject, shape};
    if (l == "basedatatype") return std::pair{BuiltinType::Variant, shape};
    for (int i = 1; i < kBuiltinTypeCount; ++i) {
        auto t = static_cast<BuiltinType>(i);
        if (lower(toString(t)) == l) return std::pair{t, shape};
    }
    return std::nullopt;
}

Variant parseValue(std::string_view text, BuiltinType type, Shape shape,
                   const ParseOptions& options) {
    if (shape == Shape::Auto) {
        std::string_view s = trim(text);
        shape = Shape::Scalar;
        if (s.starts_with("[")) {
            try {
                if (json::parse(s).is_array()) shape = Shape::Array;
            } catch (const json::parse_error&) {
            }
        }
    }
    if (shape == Shape::Array) {
        json j;
        try {
            j = json::parse(text);
        } catch (const json::parse_error&) {
            fail(type, text, "an array is written as a JSON array, e.g. [1,2,3]");
        }
        if (!j.is_array()) fail(type, text, "an array is written as a JSON array, e.g. [1,2,3]");
        return valueFromJson(j, type, Shape::Array, options);
    }
    return withType(type, [&](auto tag) -> Variant {
        using T = typename decltype(tag)::type;
        if constexpr (std::is_same_v<T, Variant>)
            return parseScalar<Variant>(text, options);
        else
            return Variant(parseScalar<T>(text, options));
    });
}

Variant valueFromJson(const json& j, BuiltinType type, Shape shape, const ParseOptions& options) {
    if (shape == Shape::Auto) shape = j.is_array() ? Shape::Array : Shape::Scalar;
    return withType(type, [&](auto tag) -> Variant {
        using T = typename decltype(tag)::type;
        if (shape == Shape::Array) {
            if (!j.is_array()) fail(type, jsonTextForError(j), "expected a JSON array");
            return arrayFromJson<T>(j, options);
        }
        if constexpr (std::is_same_v<T, Variant>)
            return inferFromJson(j, options);
        else
            return Variant(scalarFromJson<T>(j, options));
    });
}

json toJson(const Variant& value) { return bodyJson(value); }

json toJson(const DataValue& value) { return scalarJson(value); }

std::string toText(const Variant& value) {
    return std::visit(
        [](const auto& x) -> std::string {
            using X = std::decay_t<decltype(x)>;
            if constexpr (std::is_same_v<X, std::monostate> ||
                          std::is_same_v<X, ua::detail::NoScalarVariant>) {
                return "null";
            } else if constexpr (IsVector<X>::value) {
                json a = json::array();
                for (const auto& e : x)
                    a.push_back(scalarJson(static_cast<typename X::value_type>(e)));
                return compact(a);
            } else if constexpr (std::is_same_v<X, Box<DataValue>> ||
                                 std::is_same_v<X, Box<DiagnosticInfo>>) {
                return scalarText(*x);
            } else {
                return scalarText(x);
            }
        },
        value.storage());
}

std::string typeText(const Variant& value) {
    if (value.isEmpty()) return "null";
    std::string t(toString(value.type()));
    if (!value.isArray()) return t;
    if (value.arrayDimensions().empty()) return t + "[" + std::to_string(value.arrayLength()) + "]";
    std::string dims;
    for (Int32 d : value.arrayDimensions()) dims += (dims.empty() ? "" : "x") + std::to_string(d);
    return t + "[" + dims + "]";
}

std::string statusText(StatusCode status) {
    std::string_view n = status.name();
    if (!n.empty() && (status.value & 0xFFFFu) == 0) return std::string(n);
    char buf[16];
    std::snprintf(buf, sizeof buf, "0x%08X", status.value);
    if (!n.empty()) return std::string(n) + " (" + buf + ")";
    return buf;
}

std::string dateTimeText(DateTime t) {
    std::string s = t.toIso8601();  // ....SS.fffffffZ
    auto dot = s.find('.');
    if (dot == std::string::npos) return s;
    std::size_t end = s.size() - 1;  // 'Z'
    std::size_t last = end;
    while (last > dot + 1 && s[last - 1] == '0') --last;
    if (last == dot + 1) return s.substr(0, dot) + "Z";
    return s.substr(0, last) + "Z";
}

std::optional<DateTime> parseDateTime(std::string_view text) {
    std::string_view s = trim(text);
    if (lower(s) == "now") return DateTime::now();
    int y, mo, d, h = 0, mi = 0, sec = 0;
    if (!digits(s, 0, 4, y) || s.size() < 10 || s[4] != '-' || !digits(s, 5, 2, mo) ||
        s[7] != '-' || !digits(s, 8, 2, d))
        return std::nullopt;
    std::size_t p = 10;
    long long frac = 0;  // 100 ns units
    long long offsetSeconds = 0;
    if (p < s.size() && (s[p] == 'T' || s[p] == 't' || s[p] == ' ')) {
        if (!digits(s, p + 1, 2, h) || p + 3 >= s.size() || s[p + 3] != ':' ||
            !digits(s, p + 4, 2, mi))
            return std::nullopt;
        p += 6;
        if (p < s.size() && s[p] == ':') {
            if (!digits(s, p + 1, 2, sec)) return std::nullopt;
            p += 3;
            if (p < s.size() && (s[p] == '.' || s[p] == ',')) {
                ++p;
                long long scale = 1000000;
                std::size_t start = p;
                for (; p < s.size() && s[p] >= '0' && s[p] <= '9'; ++p) {
                    frac += (s[p] - '0') * scale;
                    scale /= 10;
                }
                if (p == start) return std::nullopt;
            }
        }
        if (p < s.size() && (s[p] == 'Z' || s[p] == 'z')) {
            ++p;
        } else if (p < s.size() && (s[p] == '+' || s[p] == '-')) {
            int oh = 0, om = 0;
            int sign = s[p] == '-' ? -1 : 1;
            if (!digits(s, p + 1, 2, oh)) return std::nullopt;
            p += 3;
            if (p < s.size() && s[p] == ':') ++p;
            if (p < s.size()) {
                if (!digits(s, p, 2, om)) return std::nullopt;
                p += 2;
            }
            if (oh > 23 || om > 59) return std::nullopt;
            offsetSeconds = sign * (oh * 3600LL + om * 60LL);
        }
    }
    if (p != s.size()) return std::nullopt;
    if (mo < 1 || mo > 12 || d < 1 || d > 31 || h > 23 || mi > 59 || sec > 60) return std::nullopt;
    long long days = daysFromCivil(y, static_cast<unsigned>(mo), static_cast<unsigned>(d));
    long long unixSeconds = days * 86400LL + h * 3600LL + mi * 60LL + sec - offsetSeconds;
    return DateTime{DateTime::kUnixEpochTicks + unixSeconds * 10000000LL + frac};
}

std::string hexText(std::string_view bytes) {
    static constexpr char kDigits[] = "0123456789abcdef";
    std::string out = "0x";
    out.reserve(2 + 2 * bytes.size());
    for (char c : bytes) {
        auto b = static_cast<unsigned char>(c);
        out += kDigits[b >> 4];
        out += kDigits[b & 15];
    }
    return out;
}

}  // namespace pnp::cli
