// RTDE (Universal Robots Real-Time Data Exchange, protocol version 2) wire format: package
// framing, every package type of both directions, the variable types and their values.
// Decoding checks every length; malformed input yields a DecodeError, never UB.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

namespace pnp::rtde {

inline constexpr std::uint16_t kDefaultPort = 30004;
inline constexpr std::uint16_t kProtocolVersion = 2;
inline constexpr std::size_t kHeaderSize = 3;  // uint16 size + uint8 type
// Largest package either side accepts (UR's own packages stay far below this).
inline constexpr std::size_t kMaxPackageSize = 4096;

// Package type codes (the ASCII letters UR uses).
enum class PackageType : std::uint8_t {
    requestProtocolVersion = 'V',
    getControllerVersion = 'v',
    textMessage = 'M',
    dataPackage = 'U',
    setupOutputs = 'O',
    setupInputs = 'I',
    start = 'S',
    pause = 'P',
};

// ---- variable types and values ----

// Order matches the alternatives of Value.
enum class Type : std::uint8_t {
    boolean,
    uint8,
    uint32,
    uint64,
    int32,
    float64,
    vector3d,
    vector6d,
    vector6int32,
    vector6uint32,
};

using Vector3d = std::array<double, 3>;
using Vector6d = std::array<double, 6>;
using Vector6Int32 = std::array<std::int32_t, 6>;
using Vector6Uint32 = std::array<std::uint32_t, 6>;

using Value = std::variant<bool, std::uint8_t, std::uint32_t, std::uint64_t, std::int32_t, double,
                           Vector3d, Vector6d, Vector6Int32, Vector6Uint32>;

Type typeOf(const Value& value);
Value defaultValue(Type type);         // zero of the type
std::string_view typeName(Type type);  // "BOOL", "VECTOR6D", ...
std::optional<Type> parseTypeName(std::string_view name);
std::size_t encodedSize(Type type);        // bytes on the wire
std::string toString(const Value& value);  // for logs and test messages

// ---- packages ----

// Client -> controller.
struct RequestProtocolVersion {
    std::uint16_t version = kProtocolVersion;
};
struct GetControllerVersion {};
struct SetupOutputs {
    double frequency = 125.0;
    std::vector<std::string> names;
};
struct SetupInputs {
    std::vector<std::string> names;
};
struct Start {};
struct Pause {};

// Controller -> client.
struct ProtocolVersionReply {
    bool accepted = false;
};
struct ControllerVersion {
    std::uint32_t major = 0;
    std::uint32_t minor = 0;
    std::uint32_t bugfix = 0;
    std::uint32_t build = 0;
    bool operator==(const ControllerVersion&) const = default;
};
// Reply to SetupOutputs / SetupInputs: recipe id 0 = not set up; types hold the type name of
// each variable or "NOT_FOUND" / "IN_USE".
struct SetupReply {
    std::uint8_t recipeId = 0;
    std::vector<std::string> types;
};
struct SetupOutputsReply : SetupReply {};
struct SetupInputsReply : SetupReply {};
struct StartReply {
    bool accepted = false;
};
struct PauseReply {
    bool accepted = false;
};

// Both directions. The values stay raw: only the recipe says how to read them.
struct DataPackage {
    std::uint8_t recipeId = 0;
    std::vector<std::uint8_t> payload;
};

enum class WarningLevel : std::uint8_t { exception = 0, error = 1, warning = 2, info = 3 };

// Both directions (protocol version 2 layout). Strings longer than 255 bytes are cut.
struct TextMessage {
    std::string message;
    std::string source;
    WarningLevel level = WarningLevel::info;
};

using Package =
    std::variant<RequestProtocolVersion, GetControllerVersion, SetupOutputs, SetupInputs, Start,
                 Pause, ProtocolVersionReply, ControllerVersion, SetupOutputsReply,
                 SetupInputsReply, StartReply, PauseReply, DataPackage, TextMessage>;

// Which side sends: the same type letter has different payloads per direction.
enum class Direction { toController, toClient };

PackageType packageTypeOf(const Package& package);

// Encodes one whole package (header included). Throws std::length_error when it would exceed
// kMaxPackageSize (too many names, a huge data payload).
std::vector<std::uint8_t> encode(const Package& package);

struct DecodeError {
    std::string message;
};

// Result of looking at the front of a receive buffer.
struct FrameResult {
    enum class Kind { needMore, package, error } kind = Kind::needMore;
    std::size_t consumed = 0;  // bytes of the buffer this frame took (kind == package)
    Package package;           // kind == package
    DecodeError error;         // kind == error
};

// Decodes the first package of `buffer` if it is complete. The header is checked as soon as it
// is there (size < 3, size > kMaxPackageSize, unknown type -> error at once); the payload must
// be exactly what the type needs (truncated or trailing bytes -> error).
FrameResult decodeFrame(std::span<const std::uint8_t> buffer, Direction direction);

// Decodes exactly one whole package (the span is one frame).
std::variant<Package, DecodeError> decode(std::span<const std::uint8_t> frame, Direction direction);

// ---- data package values ----

// Values in recipe order, big-endian. Throws std::length_error beyond the package limit.
std::vector<std::uint8_t> encodeValues(std::span<const Value> values);
// Exactly the bytes of `types`: too few or too many -> DecodeError.
std::variant<std::vector<Value>, DecodeError> decodeValues(std::span<const Type> types,
                                                           std::span<const std::uint8_t> payload);

// Comma-separated lists of the setup packages.
std::vector<std::string> splitList(std::string_view text);
std::string joinList(std::span<const std::string> items);

}  // namespace pnp::rtde
