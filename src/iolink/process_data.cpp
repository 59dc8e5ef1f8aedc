#include "iolink/process_data.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <set>
#include <sstream>
#include <system_error>

namespace pnp::iolink {
namespace {

constexpr std::uintmax_t kMaxFileSize = 1 << 20;
constexpr std::size_t kMaxFields = 256;
constexpr std::size_t kMaxPdBytes = 32;  // IO-Link's maximum process data per direction
constexpr std::size_t kMaxPorts = 64;
constexpr std::size_t kMaxText = 128;  // names, units

// The first problem found; thrown inside the parser only, caught at the API boundary.
struct Failure {
    Error error;
};

int lineOf(const YAML::Node& node) {
    const int line = node.Mark().line;  // 0-based; -1 without a position
    return line >= 0 ? line + 1 : 0;
}

class Parser {
  public:
    explicit Parser(std::string source) : source_(std::move(source)) {}

    [[noreturn]] void fail(int line, const std::string& what) const {
        std::string message = source_;
        if (line > 0) message += ":" + std::to_string(line);
        throw Failure{Error{message + ": " + what, line}};
    }
    [[noreturn]] void fail(const YAML::Node& node, const std::string& what) const {
        fail(lineOf(node), what);
    }

    // Every key of `map` must be one of `known`.
    void checkKeys(const YAML::Node& map, std::initializer_list<std::string_view> known,
                   const std::string& what) const {
        if (!map.IsMap()) fail(map, what + " must be a mapping");
        std::set<std::string> seen;
        for (const auto& kv : map) {
            if (!kv.first.IsScalar()) fail(kv.first, "a key of " + what + " is not a name");
            const std::string key = kv.first.Scalar();
            if (std::find(known.begin(), known.end(), key) == known.end()) {
                fail(kv.first, "unknown key '" + clip(key) + "' in " + what);
            }
            if (!seen.insert(key).second) fail(kv.first, "key '" + key + "' repeated");
        }
    }

    YAML::Node required(const YAML::Node& map, const std::string& key,
                        const std::string& what) const {
        YAML::Node node = map[key];
        if (!node.IsDefined() || node.IsNull()) fail(map, what + " has no '" + key + "'");
        return node;
    }

    std::string text(const YAML::Node& node, const std::string& key) const {
        if (!node.IsScalar()) fail(node, "'" + key + "' must be text");
        const std::string& s = node.Scalar();
        if (s.empty() || s.size() > kMaxText) {
            fail(node, "'" + key + "' must be 1.." + std::to_string(kMaxText) + " characters");
        }
        return s;
    }

    // An integer (decimal or 0x hexadecimal) within [min, max].
    std::uint64_t integer(const YAML::Node& node, const std::string& key, std::uint64_t min,
                          std::uint64_t max) const {
        if (!node.IsScalar()) fail(node, "'" + key + "' must be an integer");
        std::string_view s = node.Scalar();
        int base = 10;
        if (s.size() > 2 && s[0] == '0' && (s[1] == 'x' || s[1] == 'X')) {
            s.remove_prefix(2);
            base = 16;
        }
        std::uint64_t value = 0;
        const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), value, base);
        if (ec != std::errc() || end != s.data() + s.size() || s.empty()) {
            fail(node, "'" + key + "' must be an integer, not '" + clip(node.Scalar()) + "'");
        }
        if (value < min || value > max) {
            fail(node, "'" + key + "' is " + std::to_string(value) + ", outside " +
                           std::to_string(min) + ".." + std::to_string(max));
        }
        return value;
    }

    double number(const YAML::Node& node, const std::string& key) const {
        if (!node.IsScalar()) fail(node, "'" + key + "' must be a number");
        const std::string& s = node.Scalar();
        double value = 0.0;
        const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
        if (ec != std::errc() || end != s.data() + s.size() || !std::isfinite(value)) {
            fail(node, "'" + key + "' must be a finite number, not '" + clip(s) + "'");
        }
        return value;
    }

    YAML::Node document(std::string_view text) const {
        if (text.size() > kMaxFileSize) fail(0, "larger than 1 MiB");
        std::vector<YAML::Node> docs;
        try {
            docs = YAML::LoadAll(std::string(text));
        } catch (const YAML::ParserException& e) {
            fail(e.mark.line >= 0 ? e.mark.line + 1 : 0, "not YAML: " + e.msg);
        }
        if (docs.size() != 1) fail(0, "must hold exactly one YAML document");
        return docs[0];
    }

    static std::string clip(const std::string& s) {
        constexpr std::size_t kMax = 40;
        return s.size() <= kMax ? s : s.substr(0, kMax) + "...";
    }

  private:
    std::string source_;
};

Result<std::string> readFile(const std::filesystem::path& file) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(file, ec)) {
        return Error{file.string() + ": not a readable file"};
    }
    const auto size = std::filesystem::file_size(file, ec);
    if (ec) return Error{file.string() + ": " + ec.message()};
    if (size > kMaxFileSize) return Error{file.string() + ": larger than 1 MiB"};
    std::ifstream in(file, std::ios::binary);
    if (!in) return Error{file.string() + ": cannot be opened"};
    std::ostringstream content;
    content << in.rdbuf();
    return content.str();
}

Field parseField(const Parser& p, const YAML::Node& node, const DeviceTable& table) {
    p.checkKeys(
        node, {"name", "direction", "bit-offset", "bit-length", "type", "unit", "scale", "offset"},
        "a process data field");
    Field f;
    f.line = lineOf(node);
    f.name = p.text(p.required(node, "name", "a field"), "name");
    const YAML::Node dir = p.required(node, "direction", "field '" + f.name + "'");
    const std::string d = p.text(dir, "direction");
    if (d == "in") {
        f.direction = Direction::kIn;
    } else if (d == "out") {
        f.direction = Direction::kOut;
    } else {
        p.fail(dir,
               "direction of '" + f.name + "' must be in or out, not '" + Parser::clip(d) + "'");
    }
    const YAML::Node type = p.required(node, "type", "field '" + f.name + "'");
    const std::string t = p.text(type, "type");
    if (t == "bool") {
        f.type = FieldType::kBool;
    } else if (t == "uint") {
        f.type = FieldType::kUInt;
    } else if (t == "int") {
        f.type = FieldType::kInt;
    } else {
        p.fail(type,
               "type of '" + f.name + "' must be bool, uint or int, not '" + Parser::clip(t) + "'");
    }
    const std::size_t bits = 8 * table.bytes(f.direction);
    const YAML::Node length = p.required(node, "bit-length", "field '" + f.name + "'");
    f.bitLength = static_cast<unsigned>(p.integer(length, "bit-length", 1, 32));
    if (f.type == FieldType::kBool && f.bitLength != 1) {
        p.fail(length, "bool field '" + f.name + "' must have bit-length 1");
    }
    const YAML::Node offset = p.required(node, "bit-offset", "field '" + f.name + "'");
    f.bitOffset = static_cast<unsigned>(p.integer(offset, "bit-offset", 0, 8 * kMaxPdBytes));
    if (f.bitOffset + f.bitLength > bits) {
        p.fail(offset, "field '" + f.name + "' (bits " + std::to_string(f.bitOffset) + ".." +
                           std::to_string(f.bitOffset + f.bitLength - 1) + ") reaches beyond the " +
                           std::to_string(bits) + " bits of process data " + d);
    }
    if (node["unit"]) f.unit = p.text(node["unit"], "unit");
    if (node["scale"]) {
        f.scale = p.number(node["scale"], "scale");
        if (f.scale == 0.0) p.fail(node["scale"], "scale of '" + f.name + "' must not be 0");
    }
    if (node["offset"]) f.offset = p.number(node["offset"], "offset");
    return f;
}

DeviceTable parseDevice(const Parser& p, std::string_view text, const std::string& source) {
    const YAML::Node root = p.document(text);
    p.checkKeys(root,
                {"pnp-iolink-device", "vendor", "vendor-id", "device", "device-id", "pd-in-bytes",
                 "pd-out-bytes", "process-data"},
                "the device table");
    const YAML::Node version = p.required(root, "pnp-iolink-device", "the device table");
    if (p.integer(version, "pnp-iolink-device", 0, 1000) != 1) {
        p.fail(version,
               "pnp-iolink-device " + version.Scalar() + " is not a version this reads (1)");
    }
    DeviceTable t;
    t.source = source;
    t.vendor = p.text(p.required(root, "vendor", "the device table"), "vendor");
    t.vendorId = static_cast<std::uint16_t>(
        p.integer(p.required(root, "vendor-id", "the device table"), "vendor-id", 0, 0xFFFF));
    t.device = p.text(p.required(root, "device", "the device table"), "device");
    t.deviceId = static_cast<std::uint32_t>(
        p.integer(p.required(root, "device-id", "the device table"), "device-id", 0, 0xFFFFFF));
    t.pdInBytes = p.integer(p.required(root, "pd-in-bytes", "the device table"), "pd-in-bytes", 1,
                            kMaxPdBytes);
    t.pdOutBytes = p.integer(p.required(root, "pd-out-bytes", "the device table"), "pd-out-bytes",
                             0, kMaxPdBytes);
    const YAML::Node list = p.required(root, "process-data", "the device table");
    if (!list.IsSequence()) p.fail(list, "'process-data' must be a list");
    if (list.size() > kMaxFields) {
        p.fail(list, "more than " + std::to_string(kMaxFields) + " process data fields");
    }
    for (const YAML::Node& node : list) {
        Field f = parseField(p, node, t);
        for (const Field& other : t.fields) {
            if (other.direction != f.direction) continue;
            if (other.name == f.name) {
                p.fail(f.line, "field '" + f.name + "' defined twice (first at line " +
                                   std::to_string(other.line) + ")");
            }
            const bool apart = f.bitOffset + f.bitLength <= other.bitOffset ||
                               other.bitOffset + other.bitLength <= f.bitOffset;
            if (!apart) {
                p.fail(f.line, "field '" + f.name + "' overlaps '" + other.name + "' (line " +
                                   std::to_string(other.line) + ")");
            }
        }
        t.fields.push_back(std::move(f));
    }
    return t;
}

MasterMap parseMaster(const Parser& p, std::string_view text, const std::string& source) {
    const YAML::Node root = p.document(text);
    p.checkKeys(root,
                {"pnp-iolink-master", "name", "ports", "port-base", "port-stride", "status",
                 "identity-offset", "pd-in-offset", "pd-out-offset", "pd-max-bytes"},
                "the master map");
    const YAML::Node version = p.required(root, "pnp-iolink-master", "the master map");
    if (p.integer(version, "pnp-iolink-master", 0, 1000) != 1) {
        p.fail(version,
               "pnp-iolink-master " + version.Scalar() + " is not a version this reads (1)");
    }
    MasterMap m;
    m.source = source;
    m.name = p.text(p.required(root, "name", "the master map"), "name");
    m.ports = p.integer(p.required(root, "ports", "the master map"), "ports", 1, kMaxPorts);
    auto u16 = [&](const char* key) {
        return static_cast<std::uint16_t>(
            p.integer(p.required(root, key, "the master map"), key, 0, 0xFFFF));
    };
    m.portBase = u16("port-base");
    m.portStride = u16("port-stride");
    m.pdInOffset = u16("pd-in-offset");
    m.pdOutOffset = u16("pd-out-offset");
    m.pdMaxBytes = p.integer(p.required(root, "pd-max-bytes", "the master map"), "pd-max-bytes", 1,
                             kMaxPdBytes);
    const YAML::Node status = p.required(root, "status", "the master map");
    p.checkKeys(status, {"offset", "mask", "operate", "preoperate"}, "status");
    auto s16 = [&](const char* key) {
        return static_cast<std::uint16_t>(
            p.integer(p.required(status, key, "status"), key, 0, 0xFFFF));
    };
    m.statusOffset = s16("offset");
    m.statusMask = s16("mask");
    m.statusOperate = s16("operate");
    m.statusPreoperate = s16("preoperate");
    if ((m.statusOperate & m.statusMask) != m.statusOperate ||
        (m.statusPreoperate & m.statusMask) != m.statusPreoperate ||
        m.statusOperate == m.statusPreoperate) {
        p.fail(status, "status: operate and preoperate must differ and lie within the mask");
    }
    const YAML::Node identity = root["identity-offset"];
    if (!identity.IsDefined() || identity.IsNull()) {
        m.identityOffset.reset();
    } else {
        m.identityOffset =
            static_cast<std::uint16_t>(p.integer(identity, "identity-offset", 0, 0xFFFF));
    }

    // Every area of every port must lie below 65536, and no two areas of a port overlap.
    struct Area {
        const char* name;
        std::size_t offset;
        std::size_t count;
    };
    std::vector<Area> areas = {{"status", m.statusOffset, 1},
                               {"pd-in", m.pdInOffset, m.pdRegisters()},
                               {"pd-out", m.pdOutOffset, m.pdRegisters()}};
    if (m.identityOffset) {
        areas.push_back({"identity", *m.identityOffset, MasterMap::kIdentityRegisters});
    }
    for (std::size_t i = 0; i < areas.size(); ++i) {
        for (std::size_t j = i + 1; j < areas.size(); ++j) {
            const Area& a = areas[i];
            const Area& b = areas[j];
            if (a.offset < b.offset + b.count && b.offset < a.offset + a.count) {
                p.fail(root, std::string("the ") + a.name + " and " + b.name +
                                 " areas of a port overlap");
            }
        }
    }
    std::size_t blockEnd = 0;
    for (const Area& a : areas) blockEnd = std::max(blockEnd, a.offset + a.count);
    if (m.ports > 1 && m.portStride < blockEnd) {
        p.fail(root["port-stride"], "port-stride " + std::to_string(m.portStride) +
                                        " is smaller than a port's block (" +
                                        std::to_string(blockEnd) + " registers)");
    }
    const std::size_t last = m.portBase + (m.ports - 1) * std::size_t{m.portStride} + blockEnd;
    if (last > 0x10000) {
        p.fail(root["ports"],
               "port " + std::to_string(m.ports) + "'s registers reach beyond address 65535");
    }
    return m;
}

}  // namespace

const Field* DeviceTable::find(std::string_view name, Direction direction) const {
    for (const Field& f : fields) {
        if (f.direction == direction && f.name == name) return &f;
    }
    return nullptr;
}

std::uint16_t MasterMap::address(std::size_t port, std::uint16_t offset) const {
    return static_cast<std::uint16_t>(portBase + (port - 1) * std::size_t{portStride} + offset);
}

PortState MasterMap::state(std::uint16_t statusRegister) const {
    const std::uint16_t v = statusRegister & statusMask;
    if (v == statusOperate) return PortState::kOperate;
    if (v == statusPreoperate) return PortState::kPreoperate;
    return PortState::kNoDevice;
}

std::uint16_t MasterMap::statusValue(PortState state) const {
    switch (state) {
        case PortState::kOperate:
            return statusOperate;
        case PortState::kPreoperate:
            return statusPreoperate;
        case PortState::kNoDevice:
            break;
    }
    // A value that is neither: 0 unless 0 is one of them.
    for (std::uint32_t v = 0; v <= 0xFFFF; ++v) {
        const auto masked = static_cast<std::uint16_t>(v & statusMask);
        if (masked != statusOperate && masked != statusPreoperate) {
            return static_cast<std::uint16_t>(v);
        }
    }
    return 0;  // the mask leaves no third value: the map says so (mask 1, values 0 and 1)
}

Result<DeviceTable> parseDeviceTable(std::string_view text, const std::string& source) {
    const Parser p(source);
    try {
        return parseDevice(p, text, source);
    } catch (const Failure& f) {
        return f.error;
    } catch (const YAML::Exception& e) {
        return Error{source + ": " + e.what()};
    }
}

Result<DeviceTable> loadDeviceTable(const std::filesystem::path& file) {
    Result<std::string> text = readFile(file);
    if (!text.ok()) return text.error();
    return parseDeviceTable(*text, file.string());
}

Result<MasterMap> parseMasterMap(std::string_view text, const std::string& source) {
    const Parser p(source);
    try {
        return parseMaster(p, text, source);
    } catch (const Failure& f) {
        return f.error;
    } catch (const YAML::Exception& e) {
        return Error{source + ": " + e.what()};
    }
}

Result<MasterMap> loadMasterMap(const std::filesystem::path& file) {
    Result<std::string> text = readFile(file);
    if (!text.ok()) return text.error();
    return parseMasterMap(*text, file.string());
}

std::filesystem::path modelsDirectory() { return PNP_IOLINK_DIR; }
std::filesystem::path defaultMasterMapPath() { return modelsDirectory() / "modbus-master.yaml"; }

std::uint32_t readRaw(std::span<const std::uint8_t> pd, const Field& field) {
    std::uint32_t raw = 0;
    for (unsigned i = 0; i < field.bitLength; ++i) {
        const std::size_t bit = field.bitOffset + i;  // from the LSB of the last octet
        if (bit / 8 >= pd.size()) break;
        const std::size_t octet = pd.size() - 1 - bit / 8;
        if ((pd[octet] >> (bit % 8)) & 1U) raw |= std::uint32_t{1} << i;
    }
    return raw;
}

void writeRaw(std::span<std::uint8_t> pd, const Field& field, std::uint32_t raw) {
    for (unsigned i = 0; i < field.bitLength; ++i) {
        const std::size_t bit = field.bitOffset + i;
        if (bit / 8 >= pd.size()) break;
        const std::size_t octet = pd.size() - 1 - bit / 8;
        const auto mask = static_cast<std::uint8_t>(1U << (bit % 8));
        if ((raw >> i) & 1U) {
            pd[octet] |= mask;
        } else {
            pd[octet] &= static_cast<std::uint8_t>(~mask);
        }
    }
}

double toValue(const Field& field, std::uint32_t raw) {
    if (field.type == FieldType::kBool) return raw != 0 ? 1.0 : 0.0;
    double v = static_cast<double>(raw);
    if (field.type == FieldType::kInt && ((raw >> (field.bitLength - 1)) & 1U)) {
        v -= std::ldexp(1.0, static_cast<int>(field.bitLength));  // two's complement
    }
    return v * field.scale + field.offset;
}

std::uint32_t fromValue(const Field& field, double value) {
    if (field.type == FieldType::kBool) return value != 0.0 ? 1U : 0U;
    double raw = std::round((value - field.offset) / field.scale);
    const double span = std::ldexp(1.0, static_cast<int>(field.bitLength));
    double lo = 0.0;
    double hi = span - 1.0;
    if (field.type == FieldType::kInt) {
        lo = -span / 2.0;
        hi = span / 2.0 - 1.0;
    }
    if (!std::isfinite(raw)) raw = value > 0 ? hi : lo;
    raw = std::clamp(raw, lo, hi);
    const auto bits = static_cast<std::int64_t>(raw);
    const std::uint64_t mask = (std::uint64_t{1} << field.bitLength) - 1;
    return static_cast<std::uint32_t>(static_cast<std::uint64_t>(bits) & mask);
}

std::vector<std::uint16_t> toRegisters(std::span<const std::uint8_t> octets) {
    std::vector<std::uint16_t> regs((octets.size() + 1) / 2, 0);
    for (std::size_t i = 0; i < octets.size(); ++i) {
        regs[i / 2] |= static_cast<std::uint16_t>(octets[i] << (i % 2 == 0 ? 8 : 0));
    }
    return regs;
}

std::vector<std::uint8_t> fromRegisters(std::span<const std::uint16_t> registers,
                                        std::size_t octets) {
    std::vector<std::uint8_t> out(octets, 0);
    for (std::size_t i = 0; i < octets && i / 2 < registers.size(); ++i) {
        out[i] = static_cast<std::uint8_t>(registers[i / 2] >> (i % 2 == 0 ? 8 : 0));
    }
    return out;
}

}  // namespace pnp::iolink
