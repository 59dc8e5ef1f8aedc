#include "ua/client/browse_path.hpp"

#include <array>
#include <charconv>
#include <string>
#include <utility>

#include "ua/client/error.hpp"
#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {

namespace {

struct NamedReferenceType {
    std::string_view name;
    UInt32 id;
};

constexpr std::array<NamedReferenceType, 29> kReferenceTypes{{
    {"References", 31},
    {"NonHierarchicalReferences", 32},
    {"HierarchicalReferences", 33},
    {"HasChild", 34},
    {"Organizes", 35},
    {"HasEventSource", 36},
    {"HasModellingRule", 37},
    {"HasEncoding", 38},
    {"HasDescription", 39},
    {"HasTypeDefinition", 40},
    {"GeneratesEvent", 41},
    {"Aggregates", 44},
    {"HasSubtype", 45},
    {"HasProperty", 46},
    {"HasComponent", 47},
    {"HasNotifier", 48},
    {"HasOrderedComponent", 49},
    {"FromState", 51},
    {"ToState", 52},
    {"HasCause", 53},
    {"HasEffect", 54},
    {"HasHistoricalConfiguration", 56},
    {"HasSubStateMachine", 117},
    {"AlwaysGeneratesEvent", 3065},
    {"HasTrueSubState", 9004},
    {"HasFalseSubState", 9005},
    {"HasCondition", 9006},
    {"HasInterface", 17603},
    {"HasAddIn", 17604},
}};

[[noreturn]] void syntaxError(std::string_view text, std::string_view why) {
    throw Error(status::BadSyntaxError,
                "invalid browse path \"" + std::string(text) + "\": " + std::string(why));
}

bool isDelimiter(char c) { return c == '/' || c == '.' || c == '<'; }

// Reads an escaped token up to (not including) an unescaped character of `stops`.
// `lastColon` receives the position in the unescaped output of the last unescaped ':'.
std::string readToken(std::string_view text, std::size_t& i, std::string_view stops,
                      std::size_t* lastColon) {
    std::string out;
    while (i < text.size()) {
        char c = text[i];
        if (c == '&') {
            if (i + 1 >= text.size()) syntaxError(text, "'&' at the end");
            out += text[i + 1];
            i += 2;
            continue;
        }
        if (stops.find(c) != std::string_view::npos) break;
        if (c == ':' && lastColon) *lastColon = out.size();
        out += c;
        ++i;
    }
    return out;
}

std::optional<UInt16> parseIndex(std::string_view s) {
    UInt16 v = 0;
    auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (s.empty() || ec != std::errc() || p != s.data() + s.size()) return std::nullopt;
    return v;
}

// "ns:Name" (numeric or URI prefix) -> QualifiedName.
QualifiedName qualify(std::string_view text, std::string token, std::size_t colon,
                      const NamespaceResolver& resolver) {
    if (colon == std::string::npos) return QualifiedName{0, std::move(token)};
    std::string_view prefix(token.data(), colon);
    QualifiedName q;
    q.name = token.substr(colon + 1);
    if (auto ns = parseIndex(prefix)) {
        q.namespaceIndex = *ns;
    } else if (prefix.empty()) {
        syntaxError(text, "empty namespace prefix");
    } else if (resolver) {
        q.namespaceIndex = resolver(prefix);
    } else {
        throw Error(status::BadNotSupported,
                    "browse path \"" + std::string(text) +
                        "\": a namespace URI prefix needs a namespace resolver");
    }
    return q;
}

}  // namespace

NodeId referenceTypeByName(std::string_view name) {
    for (const auto& r : kReferenceTypes)
        if (r.name == name) return NodeId(0, r.id);
    return NodeId();
}

RelativePath parseRelativePath(std::string_view text, const NamespaceResolver& resolver) {
    RelativePath path;
    if (text.empty()) syntaxError(text, "empty path");
    std::size_t i = 0;
    while (i < text.size()) {
        RelativePathElement el{};
        el.isInverse = false;
        el.includeSubtypes = true;
        char c = text[i];
        if (c == '/' || (i == 0 && !isDelimiter(c))) {
            // A path may start with a name: that reads as "/name".
            el.referenceTypeId = NodeId(0, 33);  // HierarchicalReferences
            if (c == '/') ++i;
        } else if (c == '.') {
            el.referenceTypeId = NodeId(0, 44);  // Aggregates
            ++i;
        } else if (c == '<') {
            ++i;
            while (i < text.size() && (text[i] == '#' || text[i] == '!')) {
                if (text[i] == '#') el.includeSubtypes = false;
                if (text[i] == '!') el.isInverse = true;
                ++i;
            }
            std::size_t colon = std::string::npos;
            std::string ref = readToken(text, i, ">", &colon);
            if (i >= text.size()) syntaxError(text, "missing '>'");
            ++i;  // '>'
            if (ref.empty()) syntaxError(text, "empty reference type");
            if (ref.starts_with("i=") || ref.starts_with("ns=") || ref.starts_with("s=") ||
                ref.starts_with("g=") || ref.starts_with("b=")) {
                auto id = NodeId::parse(ref);
                if (!id) syntaxError(text, "invalid reference type NodeId \"" + ref + "\"");
                el.referenceTypeId = *id;
            } else {
                QualifiedName q = qualify(text, ref, colon, resolver);
                NodeId id = q.namespaceIndex == 0 ? referenceTypeByName(q.name) : NodeId();
                if (id.isNull())
                    throw Error(status::BadNoMatch, "browse path \"" + std::string(text) +
                                                        "\": unknown reference type \"" + ref +
                                                        "\"");
                el.referenceTypeId = id;
            }
        } else {
            syntaxError(text, "expected '/', '.' or '<'");
        }
        std::size_t colon = std::string::npos;
        std::string name = readToken(text, i, "/.<", &colon);
        if (name.empty() && i < text.size()) syntaxError(text, "empty browse name");
        el.targetName = qualify(text, std::move(name), colon, resolver);
        path.elements.push_back(std::move(el));
    }
    return path;
}

}  // namespace pnp::ua::client
