// Conversions between OPC UA values and text, for the pnp command line tools.
//
// Text -> value (parseValue): the text of one command-line argument is converted into a
// Variant of a given built-in type:
//   Boolean          true / false / 1 / 0
//   integers         42, -7, 0x2A (range-checked)
//   Float, Double    3.5, -1e300, NaN, Infinity, -Infinity
//   String           the text as is                     XmlElement   the text as is
//   DateTime         ISO-8601: 2024-05-06T07:08:09.123Z, 2024-05-06T09:08:09+02:00,
//                    2024-05-06 (midnight UTC), or "now"
//   Guid             72962B91-FA75-4AE6-8D28-B404DC7DAF63 (braces optional)
//   ByteString       0x-hex (0x0001fe) or base64 (AAEC/g==)
//   NodeId           i=85, ns=1;s=Name, ns=1;g=..., ns=1;b=base64, nsu=urn:x;s=Name
//   ExpandedNodeId   the same, plus svr=1;... (the namespace URI is kept)
//   StatusCode       BadTimeout, 0x800A0000, 2148139008
//   QualifiedName    Name or 1:Name
//   LocalizedText    hello, "hello"@en-US, {"Locale":"en-US","Text":"hello"}
//   ExtensionObject  {"TypeId":"i=886","Body":"<base64>"} (binary body as is), or decoded
//                    {"Type":"Range","Body":{"Low":1,"High":2}} / {"TypeId":"i=886","Body":{..}}
//                    when ParseOptions::types describes the DataType (the CLI asks the
//                    server for its DataTypeDefinition)
//   DataValue        {"Value":{"Type":"Double","Body":1.25},"Status":"Good",
//                     "SourceTimestamp":"2024-01-02T03:04:05.678Z"}
//   Variant          a JSON value: 1 (Int32), 1.5 (Double), true, "text",
//                    {"Type":"Int16","Body":5}; text that is not JSON is a String
//   DiagnosticInfo   {"SymbolicId":3,"AdditionalInfo":"info","InnerStatusCode":"BadTimeout"}
// Arrays are JSON arrays whose elements are JSON values of the same forms (strings hold the
// text forms above): [1,2,3], ["a","b"], ["0x00ff","AQID"], ["i=85","ns=1;s=x"].
//
// Value -> JSON (toJson) produces exactly the forms parseValue accepts, so `read --json`
// output can be written back: numbers as JSON numbers (64-bit integers exactly), NaN and
// infinities as the strings "NaN", "Infinity", "-Infinity", ByteString as base64, StatusCode
// as its name, LocalizedText / DataValue / Variant / DiagnosticInfo as the objects above,
// ExtensionObject decoded through the namespace-0 codec registry when the type is known:
//   {"TypeId":"i=886","Type":"Range","Body":{"Low":-1.5,"High":99.25}}
// and as {"TypeId":"ns=2;i=5","Encoding":"Binary","Body":"<base64>"} otherwise.
//
// Value -> human text (toText): scalars plainly (strings without quotes, ByteString as
// 0x-hex, DateTime ISO-8601, StatusCode by name, LocalizedText "text"@locale, decoded
// structures as `Range {"Low":-1.5,"High":99.25}`), arrays and composite values as compact
// JSON.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>

#include "ua/types/builtin.hpp"
#include "ua/types/ns0_types_parameters.hpp"

namespace pnp::cli {

using namespace pnp::ua;  // NOLINT: the CLI speaks the OPC UA vocabulary types throughout

// JSON objects keep their keys in insertion order (structure fields in definition order).
using Json = nlohmann::ordered_json;

// Text that cannot be converted (a usage error of the command line).
class ValueError : public std::invalid_argument {
  public:
    using std::invalid_argument::invalid_argument;
};

// Whether the text stands for a scalar or an array.
enum class Shape {
    Scalar,
    Array,
    Auto,  // an array when the text is a JSON array, a scalar otherwise
};
// ValueRank -1 -> Scalar, >= 1 -> Array, anything else (Any, ScalarOrOneDimension, ...) Auto.
Shape shapeOfValueRank(Int32 valueRank);

// What encoding a decoded structure needs to know about a DataType.
struct DataTypeDescription {
    BuiltinType builtin = BuiltinType::Variant;    // how values travel (Int32 for enumerations,
                                                   // ExtensionObject for structures)
    std::optional<StructureDefinition> structure;  // a concrete structure: its fields
    std::optional<EnumDefinition> enumeration;     // an enumeration: names of its values
};

// Source of DataType descriptions (the CLI's implementation reads them from the server).
class TypeCatalog {
  public:
    virtual ~TypeCatalog() = default;
    virtual DataTypeDescription describe(const NodeId& dataType) = 0;
    // The DataType of an encoding node ("Default Binary"); a null NodeId when unknown.
    virtual NodeId dataTypeOfEncoding(const NodeId& encodingId) = 0;
};

struct ParseOptions {
    // Resolves the namespace URI of "nsu=..." NodeId values; without it they are refused.
    std::function<UInt16(std::string_view uri)> namespaceIndex;
    // Describes DataTypes so that decoded structures can be encoded; without it only the
    // {"TypeId":..,"Body":"<base64>"} form of ExtensionObjects is accepted.
    TypeCatalog* types = nullptr;
};

// "Int32" -> {Int32, Auto}, "Int32[]" -> {Int32, Array}; nullopt for an unknown name.
// Names are the built-in type names of OPC 10000-6 (case-insensitive), plus "Bool",
// "Structure" (ExtensionObject) and "BaseDataType" (Variant).
std::optional<std::pair<BuiltinType, Shape>> parseTypeName(std::string_view name);

// Throws ValueError with a message naming the type and the offending text.
Variant parseValue(std::string_view text, BuiltinType type, Shape shape = Shape::Scalar,
                   const ParseOptions& options = {});
// The same from an already parsed JSON value (a JSON string holds the text form).
Variant valueFromJson(const Json& json, BuiltinType type, Shape shape,
                      const ParseOptions& options = {});

Json toJson(const Variant& value);  // null for an empty Variant
Json toJson(const DataValue& value);
std::string toText(const Variant& value);
// "Int32", "String[3]", "Double[2x3]" (matrix), "null".
std::string typeText(const Variant& value);

// Shared helpers.
std::string statusText(StatusCode status);  // "BadTimeout", or "0x80AB0000" when unnamed
std::string dateTimeText(DateTime t);       // ISO-8601, fraction without trailing zeros
std::optional<DateTime> parseDateTime(std::string_view text);
std::string hexText(std::string_view bytes);  // "0x0001fe"

}  // namespace pnp::cli
