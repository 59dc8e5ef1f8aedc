// JSON rendering of the built-in types for the generated namespace-0 types.
// Copied from tools/codegen/templates/ns0_json.cpp by the code generator.
#include "ua/types/detail/ns0_json.hpp"

#include <cmath>
#include <cstdio>
#include <type_traits>
#include <variant>

namespace pnp::ua::detail {

void JsonWriter::separator() {
    if (afterKey_) {
        afterKey_ = false;
        return;
    }
    if (!first_.empty()) {
        if (!first_.back()) out_ += ',';
        first_.back() = false;
    }
}

void JsonWriter::beginObject() {
    separator();
    out_ += '{';
    first_.push_back(true);
}

void JsonWriter::endObject() {
    out_ += '}';
    first_.pop_back();
}

void JsonWriter::beginArray() {
    separator();
    out_ += '[';
    first_.push_back(true);
}

void JsonWriter::endArray() {
    out_ += ']';
    first_.pop_back();
}

void JsonWriter::key(std::string_view k) {
    string(k);
    out_ += ':';
    afterKey_ = true;
}

void JsonWriter::string(std::string_view s) {
    separator();
    out_ += '"';
    for (char ch : s) {
        auto c = static_cast<unsigned char>(ch);
        switch (ch) {
            case '"':
                out_ += "\\\"";
                break;
            case '\\':
                out_ += "\\\\";
                break;
            case '\n':
                out_ += "\\n";
                break;
            case '\r':
                out_ += "\\r";
                break;
            case '\t':
                out_ += "\\t";
                break;
            default:
                if (c < 0x20) {
                    char buf[8];
                    std::snprintf(buf, sizeof buf, "\\u%04x", c);
                    out_ += buf;
                } else {
                    out_ += ch;  // UTF-8 passes through unchanged
                }
        }
    }
    out_ += '"';
}

void JsonWriter::raw(std::string_view json) {
    separator();
    out_ += json;
}

namespace {

template <class T>
void writeInteger(JsonWriter& w, T v) {
    w.raw(std::to_string(v));
}

void writeFloating(JsonWriter& w, double v, int digits) {
    if (std::isnan(v)) return w.string("NaN");
    if (std::isinf(v)) return w.string(v > 0 ? "Infinity" : "-Infinity");
    char buf[40];
    std::snprintf(buf, sizeof buf, "%.*g", digits, v);
    w.raw(buf);
}

// Nested ExtensionObjects are decoded recursively: bound the recursion.
thread_local int extensionObjectDepth = 0;
constexpr int kMaxExtensionObjectDepth = 16;

}  // namespace

void writeJson(JsonWriter& w, Boolean v) { w.raw(v ? "true" : "false"); }
void writeJson(JsonWriter& w, SByte v) { writeInteger(w, static_cast<int>(v)); }
void writeJson(JsonWriter& w, Byte v) { writeInteger(w, static_cast<unsigned>(v)); }
void writeJson(JsonWriter& w, Int16 v) { writeInteger(w, v); }
void writeJson(JsonWriter& w, UInt16 v) { writeInteger(w, v); }
void writeJson(JsonWriter& w, Int32 v) { writeInteger(w, v); }
void writeJson(JsonWriter& w, UInt32 v) { writeInteger(w, v); }
void writeJson(JsonWriter& w, Int64 v) { writeInteger(w, v); }
void writeJson(JsonWriter& w, UInt64 v) { writeInteger(w, v); }
void writeJson(JsonWriter& w, Float v) { writeFloating(w, v, 9); }
void writeJson(JsonWriter& w, Double v) { writeFloating(w, v, 17); }
void writeJson(JsonWriter& w, const String& v) { w.string(v); }
void writeJson(JsonWriter& w, const DateTime& v) { w.string(v.toIso8601()); }
void writeJson(JsonWriter& w, const Guid& v) { w.string(v.toString()); }
void writeJson(JsonWriter& w, const ByteString& v) { w.string(v.toBase64()); }
void writeJson(JsonWriter& w, const XmlElement& v) { w.string(v.xml); }
void writeJson(JsonWriter& w, const NodeId& v) { w.string(v.toString()); }
void writeJson(JsonWriter& w, const ExpandedNodeId& v) { w.string(v.toString()); }
void writeJson(JsonWriter& w, StatusCode v) { w.string(v.toString()); }
void writeJson(JsonWriter& w, const QualifiedName& v) { w.string(v.toString()); }

void writeJson(JsonWriter& w, const LocalizedText& v) {
    w.beginObject();
    if (!v.locale.empty()) {
        w.key("Locale");
        w.string(v.locale);
    }
    w.key("Text");
    w.string(v.text);
    w.endObject();
}

void writeJson(JsonWriter& w, const ExtensionObject& v) {
    if (v.empty()) return w.null();
    w.beginObject();
    w.key("TypeId");
    writeJson(w, v.typeId);
    const DataTypeCodec* codec = nullptr;
    if (v.encoding == ExtensionObject::Encoding::Binary && v.typeId.namespaceIndex() == 0 &&
        v.typeId.isNumeric())
        codec = findCodecByEncodingId(v.typeId.numeric());
    bool decoded = false;
    if (codec != nullptr && extensionObjectDepth < kMaxExtensionObjectDepth) {
        ++extensionObjectDepth;
        try {
            BinaryDecoder d(reinterpret_cast<const Byte*>(v.body.data()), v.body.size());
            std::string body = codec->toJson(d);
            w.key("Type");
            w.string(codec->name);
            w.key("Body");
            w.raw(body);
            decoded = true;
        } catch (const DecodeError&) {
        }
        --extensionObjectDepth;
    }
    if (!decoded) {
        w.key("Encoding");
        w.string(v.encoding == ExtensionObject::Encoding::Xml ? "Xml" : "Binary");
        w.key("Body");
        if (v.encoding == ExtensionObject::Encoding::Xml)
            w.string(v.body);
        else
            w.string(ByteString(v.body).toBase64());
    }
    w.endObject();
}

void writeJson(JsonWriter& w, const DataValue& v) {
    w.beginObject();
    if (v.value) {
        w.key("Value");
        writeJson(w, *v.value);
    }
    if (v.status) {
        w.key("Status");
        writeJson(w, *v.status);
    }
    if (v.sourceTimestamp) {
        w.key("SourceTimestamp");
        writeJson(w, *v.sourceTimestamp);
    }
    if (v.sourcePicoseconds) {
        w.key("SourcePicoseconds");
        writeJson(w, *v.sourcePicoseconds);
    }
    if (v.serverTimestamp) {
        w.key("ServerTimestamp");
        writeJson(w, *v.serverTimestamp);
    }
    if (v.serverPicoseconds) {
        w.key("ServerPicoseconds");
        writeJson(w, *v.serverPicoseconds);
    }
    w.endObject();
}

void writeJson(JsonWriter& w, const Variant& v) {
    if (v.isEmpty()) return w.null();
    w.beginObject();
    w.key("Type");
    w.string(toString(v.type()));
    w.key("Body");
    std::visit(
        [&w](const auto& x) {
            using X = std::decay_t<decltype(x)>;
            if constexpr (std::is_same_v<X, std::monostate> || std::is_same_v<X, NoScalarVariant>)
                w.null();
            else if constexpr (std::is_same_v<X, Box<DataValue>> ||
                               std::is_same_v<X, Box<DiagnosticInfo>>)
                writeJson(w, *x);
            else
                writeJson(w, x);
        },
        v.storage());
    if (!v.arrayDimensions().empty()) {
        w.key("Dimensions");
        writeJson(w, v.arrayDimensions());
    }
    w.endObject();
}

void writeJson(JsonWriter& w, const DiagnosticInfo& v) {
    w.beginObject();
    if (v.symbolicId) {
        w.key("SymbolicId");
        writeJson(w, *v.symbolicId);
    }
    if (v.namespaceUri) {
        w.key("NamespaceUri");
        writeJson(w, *v.namespaceUri);
    }
    if (v.localizedText) {
        w.key("LocalizedText");
        writeJson(w, *v.localizedText);
    }
    if (v.locale) {
        w.key("Locale");
        writeJson(w, *v.locale);
    }
    if (v.additionalInfo) {
        w.key("AdditionalInfo");
        writeJson(w, *v.additionalInfo);
    }
    if (v.innerStatusCode) {
        w.key("InnerStatusCode");
        writeJson(w, *v.innerStatusCode);
    }
    if (v.innerDiagnosticInfo) {
        w.key("InnerDiagnosticInfo");
        writeJson(w, *v.innerDiagnosticInfo);
    }
    w.endObject();
}

}  // namespace pnp::ua::detail

namespace pnp::ua {

std::string toJson(const ExtensionObject& v) {
    detail::JsonWriter w;
    detail::writeJson(w, v);
    return w.take();
}

}  // namespace pnp::ua
