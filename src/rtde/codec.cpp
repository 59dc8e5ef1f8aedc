#include "rtde/codec.hpp"

#include <bit>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <type_traits>

namespace pnp::rtde {

namespace {

template <class... F>
struct Overloaded : F... {
    using F::operator()...;
};
template <class... F>
Overloaded(F...) -> Overloaded<F...>;

// ---- big-endian writer / bounded reader ----

class Writer {
  public:
    void u8(std::uint8_t v) { out_.push_back(v); }
    void u16(std::uint16_t v) {
        u8(static_cast<std::uint8_t>(v >> 8));
        u8(static_cast<std::uint8_t>(v));
    }
    void u32(std::uint32_t v) {
        for (int shift = 24; shift >= 0; shift -= 8) u8(static_cast<std::uint8_t>(v >> shift));
    }
    void u64(std::uint64_t v) {
        for (int shift = 56; shift >= 0; shift -= 8) u8(static_cast<std::uint8_t>(v >> shift));
    }
    void i32(std::int32_t v) { u32(static_cast<std::uint32_t>(v)); }
    void f64(double v) { u64(std::bit_cast<std::uint64_t>(v)); }
    void bytes(std::string_view s) { out_.insert(out_.end(), s.begin(), s.end()); }
    void bytes(std::span<const std::uint8_t> s) { out_.insert(out_.end(), s.begin(), s.end()); }
    // Length-prefixed (uint8) string; longer strings are cut to 255 bytes.
    void shortString(std::string_view s) {
        if (s.size() > 255) s = s.substr(0, 255);
        u8(static_cast<std::uint8_t>(s.size()));
        bytes(s);
    }
    std::vector<std::uint8_t>& buffer() { return out_; }

  private:
    std::vector<std::uint8_t> out_;
};

struct Truncated {};

class Reader {
  public:
    explicit Reader(std::span<const std::uint8_t> in) : in_(in) {}
    std::size_t remaining() const { return in_.size() - pos_; }
    std::uint8_t u8() {
        need(1);
        return in_[pos_++];
    }
    std::uint16_t u16() {
        std::uint16_t hi = u8();
        return static_cast<std::uint16_t>((hi << 8) | u8());
    }
    std::uint32_t u32() {
        std::uint32_t v = 0;
        for (int i = 0; i < 4; ++i) v = (v << 8) | u8();
        return v;
    }
    std::uint64_t u64() {
        std::uint64_t v = 0;
        for (int i = 0; i < 8; ++i) v = (v << 8) | u8();
        return v;
    }
    std::int32_t i32() { return static_cast<std::int32_t>(u32()); }
    double f64() { return std::bit_cast<double>(u64()); }
    std::string string(std::size_t n) {
        need(n);
        std::string s(reinterpret_cast<const char*>(in_.data() + pos_), n);
        pos_ += n;
        return s;
    }
    std::string rest() { return string(remaining()); }
    std::vector<std::uint8_t> restBytes() {
        std::vector<std::uint8_t> v(in_.begin() + static_cast<std::ptrdiff_t>(pos_), in_.end());
        pos_ = in_.size();
        return v;
    }

  private:
    void need(std::size_t n) const {
        if (remaining() < n) throw Truncated{};
    }
    std::span<const std::uint8_t> in_;
    std::size_t pos_ = 0;
};

bool isKnownType(std::uint8_t t) {
    switch (static_cast<PackageType>(t)) {
        case PackageType::requestProtocolVersion:
        case PackageType::getControllerVersion:
        case PackageType::textMessage:
        case PackageType::dataPackage:
        case PackageType::setupOutputs:
        case PackageType::setupInputs:
        case PackageType::start:
        case PackageType::pause:
            return true;
    }
    return false;
}

void writeValue(Writer& w, const Value& value) {
    std::visit(Overloaded{
                   [&](bool v) { w.u8(v ? 1 : 0); },
                   [&](std::uint8_t v) { w.u8(v); },
                   [&](std::uint32_t v) { w.u32(v); },
                   [&](std::uint64_t v) { w.u64(v); },
                   [&](std::int32_t v) { w.i32(v); },
                   [&](double v) { w.f64(v); },
                   [&](const Vector3d& v) {
                       for (double d : v) w.f64(d);
                   },
                   [&](const Vector6d& v) {
                       for (double d : v) w.f64(d);
                   },
                   [&](const Vector6Int32& v) {
                       for (std::int32_t d : v) w.i32(d);
                   },
                   [&](const Vector6Uint32& v) {
                       for (std::uint32_t d : v) w.u32(d);
                   },
               },
               value);
}

Value readValue(Reader& r, Type type) {
    switch (type) {
        case Type::boolean: {
            std::uint8_t b = r.u8();
            if (b > 1) throw DecodeError{"BOOL value " + std::to_string(b) + " is not 0 or 1"};
            return b == 1;
        }
        case Type::uint8:
            return r.u8();
        case Type::uint32:
            return r.u32();
        case Type::uint64:
            return r.u64();
        case Type::int32:
            return r.i32();
        case Type::float64:
            return r.f64();
        case Type::vector3d: {
            Vector3d v{};
            for (double& d : v) d = r.f64();
            return v;
        }
        case Type::vector6d: {
            Vector6d v{};
            for (double& d : v) d = r.f64();
            return v;
        }
        case Type::vector6int32: {
            Vector6Int32 v{};
            for (std::int32_t& d : v) d = r.i32();
            return v;
        }
        case Type::vector6uint32: {
            Vector6Uint32 v{};
            for (std::uint32_t& d : v) d = r.u32();
            return v;
        }
    }
    throw DecodeError{"unknown variable type"};
}

Package decodePayload(PackageType type, Reader& r, Direction direction) {
    const bool toController = direction == Direction::toController;
    switch (type) {
        case PackageType::requestProtocolVersion:
            if (toController) return RequestProtocolVersion{r.u16()};
            return ProtocolVersionReply{r.u8() != 0};
        case PackageType::getControllerVersion:
            if (toController) return GetControllerVersion{};
            {
                ControllerVersion v;
                v.major = r.u32();
                v.minor = r.u32();
                v.bugfix = r.u32();
                v.build = r.u32();
                return v;
            }
        case PackageType::setupOutputs:
            if (toController) {
                SetupOutputs s;
                s.frequency = r.f64();
                s.names = splitList(r.rest());
                return s;
            } else {
                SetupOutputsReply s;
                s.recipeId = r.u8();
                s.types = splitList(r.rest());
                return s;
            }
        case PackageType::setupInputs:
            if (toController) return SetupInputs{splitList(r.rest())};
            {
                SetupInputsReply s;
                s.recipeId = r.u8();
                s.types = splitList(r.rest());
                return s;
            }
        case PackageType::start:
            if (toController) return Start{};
            return StartReply{r.u8() != 0};
        case PackageType::pause:
            if (toController) return Pause{};
            return PauseReply{r.u8() != 0};
        case PackageType::dataPackage: {
            DataPackage d;
            d.recipeId = r.u8();
            d.payload = r.restBytes();
            return d;
        }
        case PackageType::textMessage: {
            TextMessage m;
            m.message = r.string(r.u8());
            m.source = r.string(r.u8());
            std::uint8_t level = r.u8();
            if (level > 3) throw DecodeError{"text message warning level " + std::to_string(level)};
            m.level = static_cast<WarningLevel>(level);
            return m;
        }
    }
    throw DecodeError{"unknown package type"};
}

std::string typeLabel(std::uint8_t t) {
    std::ostringstream s;
    if (t >= 0x20 && t < 0x7f) s << "'" << static_cast<char>(t) << "' ";
    s << "(0x" << std::hex << static_cast<int>(t) << ")";
    return s.str();
}

}  // namespace

Type typeOf(const Value& value) { return static_cast<Type>(value.index()); }

Value defaultValue(Type type) {
    switch (type) {
        case Type::boolean:
            return false;
        case Type::uint8:
            return std::uint8_t{0};
        case Type::uint32:
            return std::uint32_t{0};
        case Type::uint64:
            return std::uint64_t{0};
        case Type::int32:
            return std::int32_t{0};
        case Type::float64:
            return 0.0;
        case Type::vector3d:
            return Vector3d{};
        case Type::vector6d:
            return Vector6d{};
        case Type::vector6int32:
            return Vector6Int32{};
        case Type::vector6uint32:
            return Vector6Uint32{};
    }
    return false;
}

std::string_view typeName(Type type) {
    switch (type) {
        case Type::boolean:
            return "BOOL";
        case Type::uint8:
            return "UINT8";
        case Type::uint32:
            return "UINT32";
        case Type::uint64:
            return "UINT64";
        case Type::int32:
            return "INT32";
        case Type::float64:
            return "DOUBLE";
        case Type::vector3d:
            return "VECTOR3D";
        case Type::vector6d:
            return "VECTOR6D";
        case Type::vector6int32:
            return "VECTOR6INT32";
        case Type::vector6uint32:
            return "VECTOR6UINT32";
    }
    return "?";
}

std::optional<Type> parseTypeName(std::string_view name) {
    for (int i = 0; i <= static_cast<int>(Type::vector6uint32); ++i) {
        auto t = static_cast<Type>(i);
        if (typeName(t) == name) return t;
    }
    return std::nullopt;
}

std::size_t encodedSize(Type type) {
    switch (type) {
        case Type::boolean:
        case Type::uint8:
            return 1;
        case Type::uint32:
        case Type::int32:
            return 4;
        case Type::uint64:
        case Type::float64:
            return 8;
        case Type::vector3d:
            return 24;
        case Type::vector6d:
            return 48;
        case Type::vector6int32:
        case Type::vector6uint32:
            return 24;
    }
    return 0;
}

std::string toString(const Value& value) {
    std::ostringstream s;
    auto list = [&](const auto& a) {
        s << "[";
        for (std::size_t i = 0; i < a.size(); ++i) s << (i ? ", " : "") << a[i];
        s << "]";
    };
    std::visit(Overloaded{
                   [&](bool v) { s << (v ? "true" : "false"); },
                   [&](std::uint8_t v) { s << static_cast<unsigned>(v); },
                   [&](double v) { s << v; },
                   [&](const Vector3d& v) { list(v); },
                   [&](const Vector6d& v) { list(v); },
                   [&](const Vector6Int32& v) { list(v); },
                   [&](const Vector6Uint32& v) { list(v); },
                   [&](auto v) { s << v; },
               },
               value);
    return s.str();
}

PackageType packageTypeOf(const Package& package) {
    return std::visit(
        Overloaded{
            [](const RequestProtocolVersion&) { return PackageType::requestProtocolVersion; },
            [](const ProtocolVersionReply&) { return PackageType::requestProtocolVersion; },
            [](const GetControllerVersion&) { return PackageType::getControllerVersion; },
            [](const ControllerVersion&) { return PackageType::getControllerVersion; },
            [](const SetupOutputs&) { return PackageType::setupOutputs; },
            [](const SetupInputs&) { return PackageType::setupInputs; },
            [](const SetupOutputsReply&) { return PackageType::setupOutputs; },
            [](const SetupInputsReply&) { return PackageType::setupInputs; },
            [](const Start&) { return PackageType::start; },
            [](const StartReply&) { return PackageType::start; },
            [](const Pause&) { return PackageType::pause; },
            [](const PauseReply&) { return PackageType::pause; },
            [](const DataPackage&) { return PackageType::dataPackage; },
            [](const TextMessage&) { return PackageType::textMessage; },
        },
        package);
}

std::vector<std::uint8_t> encode(const Package& package) {
    const PackageType type = packageTypeOf(package);
    Writer w;
    w.u16(0);  // size, patched below
    w.u8(static_cast<std::uint8_t>(type));
    std::visit(Overloaded{
                   [&](const RequestProtocolVersion& p) { w.u16(p.version); },
                   [&](const ProtocolVersionReply& p) { w.u8(p.accepted ? 1 : 0); },
                   [&](const GetControllerVersion&) {},
                   [&](const ControllerVersion& p) {
                       w.u32(p.major);
                       w.u32(p.minor);
                       w.u32(p.bugfix);
                       w.u32(p.build);
                   },
                   [&](const SetupOutputs& p) {
                       w.f64(p.frequency);
                       w.bytes(joinList(p.names));
                   },
                   [&](const SetupInputs& p) { w.bytes(joinList(p.names)); },
                   [&](const SetupReply& p) {
                       w.u8(p.recipeId);
                       w.bytes(joinList(p.types));
                   },
                   [&](const Start&) {},
                   [&](const StartReply& p) { w.u8(p.accepted ? 1 : 0); },
                   [&](const Pause&) {},
                   [&](const PauseReply& p) { w.u8(p.accepted ? 1 : 0); },
                   [&](const DataPackage& p) {
                       w.u8(p.recipeId);
                       w.bytes(p.payload);
                   },
                   [&](const TextMessage& p) {
                       w.shortString(p.message);
                       w.shortString(p.source);
                       w.u8(static_cast<std::uint8_t>(p.level));
                   },
               },
               package);
    auto& out = w.buffer();
    if (out.size() > kMaxPackageSize) {
        throw std::length_error("RTDE package of " + std::to_string(out.size()) +
                                " bytes exceeds the limit of " + std::to_string(kMaxPackageSize));
    }
    out[0] = static_cast<std::uint8_t>(out.size() >> 8);
    out[1] = static_cast<std::uint8_t>(out.size());
    return std::move(out);
}

FrameResult decodeFrame(std::span<const std::uint8_t> buffer, Direction direction) {
    FrameResult result;
    if (buffer.size() < kHeaderSize) return result;
    const std::size_t size = (static_cast<std::size_t>(buffer[0]) << 8) | buffer[1];
    const std::uint8_t type = buffer[2];
    result.kind = FrameResult::Kind::error;
    if (size < kHeaderSize) {
        result.error.message = "package size " + std::to_string(size) + " is below the header size";
        return result;
    }
    if (size > kMaxPackageSize) {
        result.error.message = "package size " + std::to_string(size) + " exceeds the limit of " +
                               std::to_string(kMaxPackageSize);
        return result;
    }
    if (!isKnownType(type)) {
        result.error.message = "unknown package type " + typeLabel(type);
        return result;
    }
    if (buffer.size() < size) {
        result.kind = FrameResult::Kind::needMore;
        return result;
    }
    auto decoded = decode(buffer.first(size), direction);
    if (auto* error = std::get_if<DecodeError>(&decoded)) {
        result.error = std::move(*error);
        return result;
    }
    result.kind = FrameResult::Kind::package;
    result.consumed = size;
    result.package = std::move(std::get<Package>(decoded));
    return result;
}

std::variant<Package, DecodeError> decode(std::span<const std::uint8_t> frame,
                                          Direction direction) {
    if (frame.size() < kHeaderSize) return DecodeError{"package shorter than its header"};
    const std::size_t size = (static_cast<std::size_t>(frame[0]) << 8) | frame[1];
    if (size != frame.size()) {
        return DecodeError{"package size field " + std::to_string(size) + " but " +
                           std::to_string(frame.size()) + " bytes"};
    }
    if (size > kMaxPackageSize) return DecodeError{"package exceeds the size limit"};
    const std::uint8_t type = frame[2];
    if (!isKnownType(type)) return DecodeError{"unknown package type " + typeLabel(type)};
    Reader r(frame.subspan(kHeaderSize));
    try {
        Package p = decodePayload(static_cast<PackageType>(type), r, direction);
        if (r.remaining() != 0) {
            return DecodeError{"package " + typeLabel(type) + " has " +
                               std::to_string(r.remaining()) + " trailing bytes"};
        }
        return p;
    } catch (const Truncated&) {
        return DecodeError{"package " + typeLabel(type) + " payload is truncated"};
    } catch (DecodeError& e) {
        return std::move(e);
    }
}

std::vector<std::uint8_t> encodeValues(std::span<const Value> values) {
    Writer w;
    for (const Value& v : values) writeValue(w, v);
    if (w.buffer().size() > kMaxPackageSize - kHeaderSize - 1) {
        throw std::length_error("RTDE data package values exceed the package size limit");
    }
    return std::move(w.buffer());
}

std::variant<std::vector<Value>, DecodeError> decodeValues(std::span<const Type> types,
                                                           std::span<const std::uint8_t> payload) {
    Reader r(payload);
    std::vector<Value> values;
    values.reserve(types.size());
    try {
        for (Type t : types) values.push_back(readValue(r, t));
    } catch (const Truncated&) {
        return DecodeError{"data package values are truncated (" + std::to_string(payload.size()) +
                           " bytes for " + std::to_string(types.size()) + " variables)"};
    } catch (DecodeError& e) {
        return std::move(e);
    }
    if (r.remaining() != 0) {
        return DecodeError{"data package has " + std::to_string(r.remaining()) +
                           " bytes after the recipe's values"};
    }
    return values;
}

std::vector<std::string> splitList(std::string_view text) {
    std::vector<std::string> items;
    if (text.empty()) return items;
    std::size_t start = 0;
    while (true) {
        std::size_t comma = text.find(',', start);
        items.emplace_back(
            text.substr(start, comma == std::string_view::npos ? text.npos : comma - start));
        if (comma == std::string_view::npos) break;
        start = comma + 1;
    }
    return items;
}

std::string joinList(std::span<const std::string> items) {
    std::string s;
    for (std::size_t i = 0; i < items.size(); ++i) {
        if (i) s += ',';
        s += items[i];
    }
    return s;
}

}  // namespace pnp::rtde
