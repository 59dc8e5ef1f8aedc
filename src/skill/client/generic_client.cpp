#include "skill/client/generic_client.hpp"

#include <cerrno>
#include <cstdlib>
#include <limits>
#include <sstream>

#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::skill::client {

namespace {

namespace status = ua::status;

std::string_view trim(std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
    return s;
}

// "[1, 2,3]" / "1,2,3" / "[[0,1],[2,3]]" -> the comma-separated items, brackets dropped.
std::vector<std::string> items(std::string_view text) {
    std::vector<std::string> out;
    std::string cur;
    bool any = false;
    for (char c : text) {
        if (c == '[' || c == ']') continue;
        if (c == ',') {
            out.emplace_back(trim(cur));
            cur.clear();
            continue;
        }
        cur += c;
        any = any || (c != ' ' && c != '\t');
    }
    if (any || !out.empty()) out.emplace_back(trim(cur));
    return out;
}

std::optional<double> toDouble(std::string_view s) {
    std::string t(trim(s));
    if (t.empty()) return std::nullopt;
    char* e = nullptr;
    errno = 0;
    double d = std::strtod(t.c_str(), &e);
    if (e != t.c_str() + t.size() || errno == ERANGE) return std::nullopt;
    return d;
}

std::optional<std::int64_t> toInt(std::string_view s) {
    std::string t(trim(s));
    if (t.empty()) return std::nullopt;
    char* e = nullptr;
    errno = 0;
    long long v = std::strtoll(t.c_str(), &e, 0);
    if (e != t.c_str() + t.size() || errno == ERANGE) return std::nullopt;
    return v;
}

std::optional<std::uint64_t> toUInt(std::string_view s) {
    std::string t(trim(s));
    if (t.empty() || t[0] == '-') return std::nullopt;
    char* e = nullptr;
    errno = 0;
    unsigned long long v = std::strtoull(t.c_str(), &e, 0);
    if (e != t.c_str() + t.size() || errno == ERANGE) return std::nullopt;
    return v;
}

std::optional<bool> toBool(std::string_view s) {
    s = trim(s);
    if (s == "true" || s == "True" || s == "1") return true;
    if (s == "false" || s == "False" || s == "0") return false;
    return std::nullopt;
}

template <class T, class Parse>
bool scalarInto(std::string_view s, Parse parse, ua::Variant& out) {
    auto v = parse(s);
    if (!v) return false;
    if constexpr (std::is_integral_v<T> && !std::is_same_v<T, bool>) {
        using V = std::remove_cvref_t<decltype(*v)>;
        if (*v < static_cast<V>(std::numeric_limits<T>::min()) ||
            *v > static_cast<V>(std::numeric_limits<T>::max()))
            return false;
    }
    out = ua::Variant(static_cast<T>(*v));
    return true;
}

template <class T, class Parse>
bool arrayInto(const std::vector<std::string>& xs, Parse parse, ua::Variant& out) {
    std::vector<T> values;
    for (const auto& x : xs) {
        ua::Variant one;
        if (!scalarInto<T>(x, parse, one)) return false;
        values.push_back(*one.scalar<T>());
    }
    out = ua::Variant(std::move(values));
    return true;
}

// The numbers of a structure (flat list), chunked by `n` into ExtensionObjects.
template <class Make>
bool structsInto(std::string_view text, std::size_t n, bool array, Make make, ua::Variant& out) {
    std::vector<double> numbers;
    for (const auto& x : items(text)) {
        auto d = toDouble(x);
        if (!d) return false;
        numbers.push_back(*d);
    }
    if (numbers.size() % n != 0 || (!array && numbers.size() != n)) return false;
    std::vector<ua::ExtensionObject> xs;
    for (std::size_t i = 0; i < numbers.size(); i += n) xs.push_back(make(&numbers[i]));
    if (array)
        out = ua::Variant(std::move(xs));
    else
        out = ua::Variant(std::move(xs.at(0)));
    return true;
}

bool coerceInto(ua::UInt32 type, bool array, std::string_view text, ua::Variant& out) {
    namespace ids = ua::ns0;
    auto xs = items(text);
    switch (type) {
        case ids::ThreeDFrame:
            return structsInto(
                text, 6, array,
                [](const double* d) {
                    ua::ThreeDFrame f;
                    f.cartesianCoordinates = {d[0], d[1], d[2]};
                    f.orientation = {d[3], d[4], d[5]};
                    return ua::toExtensionObject(f);
                },
                out);
        case ids::ThreeDVector:
        case ids::ThreeDCartesianCoordinates:
            return structsInto(
                text, 3, array,
                [type](const double* d) {
                    if (type == ids::ThreeDVector)
                        return ua::toExtensionObject(ua::ThreeDVector{d[0], d[1], d[2]});
                    return ua::toExtensionObject(ua::ThreeDCartesianCoordinates{d[0], d[1], d[2]});
                },
                out);
        case ids::Range:
            return structsInto(
                text, 2, array,
                [](const double* d) {
                    return ua::toExtensionObject(ua::Range{d[0], d[1]});
                },
                out);
        default:
            break;
    }
    if (!array) {
        switch (type) {
            case ids::Boolean:
                return scalarInto<bool>(text, toBool, out);
            case ids::SByte:
                return scalarInto<ua::SByte>(text, toInt, out);
            case ids::Byte:
                return scalarInto<ua::Byte>(text, toUInt, out);
            case ids::Int16:
                return scalarInto<ua::Int16>(text, toInt, out);
            case ids::UInt16:
                return scalarInto<ua::UInt16>(text, toUInt, out);
            case ids::Int32:
                return scalarInto<ua::Int32>(text, toInt, out);
            case ids::UInt32:
                return scalarInto<ua::UInt32>(text, toUInt, out);
            case ids::Int64:
                return scalarInto<ua::Int64>(text, toInt, out);
            case ids::UInt64:
                return scalarInto<ua::UInt64>(text, toUInt, out);
            case ids::Float:
                return scalarInto<ua::Float>(text, toDouble, out);
            case ids::Double:
            case ids::Duration:
                return scalarInto<ua::Double>(text, toDouble, out);
            case ids::String:
                out = ua::Variant(ua::String(text));
                return true;
            case ids::LocalizedText:
                out = ua::Variant(ua::LocalizedText("", std::string(text)));
                return true;
            default:
                return false;
        }
    }
    switch (type) {
        case ids::Boolean:
            return arrayInto<bool>(xs, toBool, out);
        case ids::SByte:
            return arrayInto<ua::SByte>(xs, toInt, out);
        case ids::Byte:
            return arrayInto<ua::Byte>(xs, toUInt, out);
        case ids::Int16:
            return arrayInto<ua::Int16>(xs, toInt, out);
        case ids::UInt16:
            return arrayInto<ua::UInt16>(xs, toUInt, out);
        case ids::Int32:
            return arrayInto<ua::Int32>(xs, toInt, out);
        case ids::UInt32:
            return arrayInto<ua::UInt32>(xs, toUInt, out);
        case ids::Int64:
            return arrayInto<ua::Int64>(xs, toInt, out);
        case ids::UInt64:
            return arrayInto<ua::UInt64>(xs, toUInt, out);
        case ids::Float:
            return arrayInto<ua::Float>(xs, toDouble, out);
        case ids::Double:
        case ids::Duration:
            return arrayInto<ua::Double>(xs, toDouble, out);
        case ids::String:
        case ids::LocalizedText: {
            std::vector<ua::String> ss;
            for (auto& x : xs) {
                std::string_view v = x;
                if (v.size() >= 2 && v.front() == '"' && v.back() == '"')
                    v = v.substr(1, v.size() - 2);
                ss.emplace_back(v);
            }
            if (type == ids::String) {
                out = ua::Variant(std::move(ss));
            } else {
                std::vector<ua::LocalizedText> ts;
                for (auto& s : ss) ts.emplace_back("", std::move(s));
                out = ua::Variant(std::move(ts));
            }
            return true;
        }
        default:
            return false;
    }
}

}  // namespace

std::string typeName(const ua::NodeId& dataType, ua::Int32 valueRank) {
    std::string base;
    if (dataType.namespaceIndex() == 0 && dataType.isNumeric()) {
        switch (dataType.numeric()) {
            case ua::ns0::ThreeDFrame:
                base = "ThreeDFrame";
                break;
            case ua::ns0::ThreeDVector:
                base = "ThreeDVector";
                break;
            case ua::ns0::ThreeDCartesianCoordinates:
                base = "ThreeDCartesianCoordinates";
                break;
            case ua::ns0::Range:
                base = "Range";
                break;
            case ua::ns0::Duration:
                base = "Duration";
                break;
            default:
                if (dataType.numeric() >= 1 && dataType.numeric() <= 25)
                    base =
                        std::string(ua::toString(static_cast<ua::BuiltinType>(dataType.numeric())));
        }
    }
    if (base.empty()) base = dataType.toString();
    return valueRank >= 0 ? base + "[]" : base;
}

std::string formatValue(const ua::Variant& value) {
    auto one = [](const ua::ExtensionObject& x) -> std::string {
        std::ostringstream s;
        try {
            if (auto f = ua::fromExtensionObject<ua::ThreeDFrame>(x)) {
                s << f->cartesianCoordinates.x << ',' << f->cartesianCoordinates.y << ','
                  << f->cartesianCoordinates.z << ',' << f->orientation.a << ',' << f->orientation.b
                  << ',' << f->orientation.c;
                return s.str();
            }
            if (auto v = ua::fromExtensionObject<ua::ThreeDVector>(x)) {
                s << v->x << ',' << v->y << ',' << v->z;
                return s.str();
            }
            if (auto r = ua::fromExtensionObject<ua::Range>(x)) {
                s << r->low << ',' << r->high;
                return s.str();
            }
        } catch (const std::exception&) {
        }
        return ua::Variant(x).toString();
    };
    if (const auto* x = value.scalar<ua::ExtensionObject>()) return one(*x);
    if (const auto* xs = value.array<ua::ExtensionObject>()) {
        std::string s = "[";
        for (std::size_t i = 0; i < xs->size(); ++i) s += (i ? "],[" : "[") + one((*xs)[i]);
        return s + (xs->empty() ? "]" : "]]");
    }
    if (const auto* t = value.scalar<ua::String>()) return *t;
    if (const auto* t = value.scalar<ua::LocalizedText>()) return t->text;
    return value.isEmpty() ? "(empty)" : value.toString();
}

ua::Variant coerce(const ParameterInfo& p, std::string_view text) {
    ua::Variant out;
    const bool array = p.valueRank >= 0;
    const bool known = p.dataType.namespaceIndex() == 0 && p.dataType.isNumeric();
    if (known && coerceInto(p.dataType.numeric(), array, text, out)) return out;
    // Enumerations of the skill models (SkillResultCode, GripPointKind): Int32 values.
    if (!known && !array) {
        ua::Variant v;
        if (scalarInto<ua::Int32>(text, toInt, v)) return v;
    }
    throw Error(status::BadTypeMismatch, "parameter " + p.name + ": '" + std::string(text) +
                                             "' is not a " + typeName(p.dataType, p.valueRank));
}

ua::Variant GenericSkillClient::coerce(std::string_view name, std::string_view text) const {
    const ParameterInfo* p = findParameter(name);
    if (p == nullptr)
        throw Error(status::BadNotFound,
                    "skill " + browseName() + " has no parameter " + std::string(name));
    return client::coerce(*p, text);
}

NamedValues GenericSkillClient::parse(const std::vector<std::string>& assignments) const {
    NamedValues out;
    for (const auto& a : assignments) {
        auto eq = a.find('=');
        if (eq == std::string::npos)
            throw Error(status::BadSyntaxError, "'" + a + "' is not name=value");
        std::string name(trim(std::string_view(a).substr(0, eq)));
        out.emplace_back(name, coerce(name, std::string_view(a).substr(eq + 1)));
    }
    return out;
}

void GenericSkillClient::setParametersFromText(const std::vector<std::string>& assignments,
                                               Deadline deadline) {
    setParameters(parse(assignments), deadline);
}

std::string GenericSkillClient::describe(Deadline deadline) {
    std::ostringstream s;
    s << browseName() << " (" << type().name;
    for (std::size_t i = 1; i < typeChain().size(); ++i) s << " < " << typeChain()[i].name;
    s << ")\n";
    for (const auto& [name, value] : parameterValues(deadline)) {
        const ParameterInfo* p = findParameter(name);
        s << "  " << name << ": " << typeName(p->dataType, p->valueRank) << " = "
          << formatValue(value) << (p->writable ? "" : " (read-only)") << '\n';
    }
    return s.str();
}

}  // namespace pnp::skill::client
