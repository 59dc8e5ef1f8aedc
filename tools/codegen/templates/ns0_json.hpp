// Internal: JSON rendering of the namespace-0 types (used by toJson() and the DataTypeCodec
// registry). The text is a plain JSON view for humans and tools (field names as in the
// DataTypeDefinition), not the reversible OPC UA JSON encoding of Part 6 §5.4.
// This part is copied from tools/codegen/templates/ns0_json.hpp; the declarations at the end
// are generated.
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "ua/types/ns0_types.hpp"

namespace pnp::ua::detail {

class JsonWriter {
  public:
    void beginObject();
    void endObject();
    void beginArray();
    void endArray();
    void key(std::string_view k);
    void string(std::string_view s);
    void raw(std::string_view json);  // one complete JSON value
    void null() { raw("null"); }
    std::string take() { return std::move(out_); }

  private:
    void separator();

    std::string out_;
    std::vector<bool> first_;
    bool afterKey_ = false;
};

void writeJson(JsonWriter& w, Boolean v);
void writeJson(JsonWriter& w, SByte v);
void writeJson(JsonWriter& w, Byte v);
void writeJson(JsonWriter& w, Int16 v);
void writeJson(JsonWriter& w, UInt16 v);
void writeJson(JsonWriter& w, Int32 v);
void writeJson(JsonWriter& w, UInt32 v);
void writeJson(JsonWriter& w, Int64 v);
void writeJson(JsonWriter& w, UInt64 v);
void writeJson(JsonWriter& w, Float v);
void writeJson(JsonWriter& w, Double v);
void writeJson(JsonWriter& w, const String& v);
void writeJson(JsonWriter& w, const DateTime& v);
void writeJson(JsonWriter& w, const Guid& v);
void writeJson(JsonWriter& w, const ByteString& v);
void writeJson(JsonWriter& w, const XmlElement& v);
void writeJson(JsonWriter& w, const NodeId& v);
void writeJson(JsonWriter& w, const ExpandedNodeId& v);
void writeJson(JsonWriter& w, StatusCode v);
void writeJson(JsonWriter& w, const QualifiedName& v);
void writeJson(JsonWriter& w, const LocalizedText& v);
void writeJson(JsonWriter& w, const ExtensionObject& v);
void writeJson(JsonWriter& w, const DataValue& v);
void writeJson(JsonWriter& w, const Variant& v);
void writeJson(JsonWriter& w, const DiagnosticInfo& v);

template <class T>
void writeJson(JsonWriter& w, const std::vector<T>& v) {
    w.beginArray();
    for (const auto& x : v) writeJson(w, x);
    w.endArray();
}

template <class T>
void writeJson(JsonWriter& w, const std::optional<T>& v) {
    if (v)
        writeJson(w, *v);
    else
        w.null();
}

// Enumerations: the symbolic name as a string, or the number when it has none.
template <class E>
void writeEnumJson(JsonWriter& w, E v) {
    auto name = toString(v);
    if (name.empty())
        writeJson(w, static_cast<Int32>(v));
    else
        w.string(name);
}
