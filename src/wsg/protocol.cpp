#include "wsg/protocol.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <stdexcept>

namespace pnp::wsg {

namespace {

// The CCITT table (polynomial 0x1021, most significant bit first), built at compile time.
constexpr std::array<std::uint16_t, 256> makeTable() {
    std::array<std::uint16_t, 256> table{};
    for (unsigned i = 0; i < 256; ++i) {
        unsigned c = i << 8;
        for (int bit = 0; bit < 8; ++bit) c = (c & 0x8000u) ? ((c << 1) ^ 0x1021u) : (c << 1);
        table[i] = static_cast<std::uint16_t>(c & 0xFFFFu);
    }
    return table;
}
constexpr std::array<std::uint16_t, 256> kTable = makeTable();

struct Named {
    std::uint8_t id;
    std::string_view name;
};
constexpr std::array<Named, 20> kCommands{{
    {0x06, "LOOP"},
    {0x07, "DISCONNECT ANNOUNCEMENT"},
    {0x20, "HOMING"},
    {0x21, "PRE-POSITION"},
    {0x22, "STOP"},
    {0x23, "FAST STOP"},
    {0x24, "ACKNOWLEDGE FAST STOP"},
    {0x25, "GRASP PART"},
    {0x26, "RELEASE PART"},
    {0x30, "SET ACCELERATION"},
    {0x31, "GET ACCELERATION"},
    {0x32, "SET FORCE LIMIT"},
    {0x33, "GET FORCE LIMIT"},
    {0x40, "GET SYSTEM STATE"},
    {0x41, "GET GRASPING STATE"},
    {0x42, "GET GRASPING STATISTICS"},
    {0x43, "GET OPENING WIDTH"},
    {0x44, "GET SPEED"},
    {0x45, "GET FORCE"},
    {0x50, "GET SYSTEM INFORMATION"},
}};

constexpr std::array<std::string_view, 31> kStatusNames{
    "E_SUCCESS",
    "E_NOT_AVAILABLE",
    "E_NO_SENSOR",
    "E_NOT_INITIALIZED",
    "E_ALREADY_RUNNING",
    "E_FEATURE_NOT_SUPPORTED",
    "E_INCONSISTENT_DATA",
    "E_TIMEOUT",
    "E_READ_ERROR",
    "E_WRITE_ERROR",
    "E_INSUFFICIENT_RESOURCES",
    "E_CHECKSUM_ERROR",
    "E_NO_PARAM_EXPECTED",
    "E_NOT_ENOUGH_PARAMS",
    "E_CMD_UNKNOWN",
    "E_CMD_FORMAT_ERROR",
    "E_ACCESS_DENIED",
    "E_ALREADY_OPEN",
    "E_CMD_FAILED",
    "E_CMD_ABORTED",
    "E_INVALID_HANDLE",
    "E_NOT_FOUND",
    "E_NOT_OPEN",
    "E_IO_ERROR",
    "E_INVALID_PARAMETER",
    "E_INDEX_OUT_OF_BOUNDS",
    "E_CMD_PENDING",
    "E_OVERRUN",
    "E_RANGE_ERROR",
    "E_AXIS_BLOCKED",
    "E_FILE_EXISTS",
};

constexpr std::array<std::string_view, 8> kGraspingStates{
    "IDLE",    "GRASPING",  "NO PART FOUND", "PART LOST",
    "HOLDING", "RELEASING", "POSITIONING",   "ERROR",
};

bool isPreamble(const std::vector<std::uint8_t>& b, std::size_t at) {
    return b[at] == kPreambleByte && b[at + 1] == kPreambleByte && b[at + 2] == kPreambleByte;
}

}  // namespace

std::string_view commandName(std::uint8_t id) {
    for (const Named& c : kCommands) {
        if (c.id == id) return c.name;
    }
    return "UNKNOWN";
}

bool knownCommand(std::uint8_t id) {
    return std::any_of(kCommands.begin(), kCommands.end(),
                       [id](const Named& c) { return c.id == id; });
}

std::string_view statusName(std::uint16_t status) {
    return status < kStatusNames.size() ? kStatusNames[status] : "E_UNKNOWN";
}

std::string_view graspingStateName(std::uint8_t state) {
    return state < kGraspingStates.size() ? kGraspingStates[state] : "UNKNOWN";
}

std::uint16_t checksum(std::span<const std::uint8_t> bytes, std::uint16_t crc) {
    for (std::uint8_t b : bytes) {
        crc = static_cast<std::uint16_t>(kTable[(crc ^ b) & 0xFFu] ^ (crc >> 8));
    }
    return crc;
}

std::vector<std::uint8_t> encodeFrame(std::uint8_t id, std::span<const std::uint8_t> payload) {
    if (payload.size() > kMaxPayload) {
        throw std::length_error("WSG payload of " + std::to_string(payload.size()) +
                                " bytes exceeds " + std::to_string(kMaxPayload));
    }
    std::vector<std::uint8_t> out;
    out.reserve(kHeaderSize + payload.size() + kChecksumSize);
    out.insert(out.end(), kPreambleSize, kPreambleByte);
    out.push_back(id);
    putU16(out, static_cast<std::uint16_t>(payload.size()));
    out.insert(out.end(), payload.begin(), payload.end());
    putU16(out, checksum(out));
    return out;
}

std::vector<std::uint8_t> encodeResponse(std::uint8_t id, Status status,
                                         std::span<const std::uint8_t> values) {
    std::vector<std::uint8_t> payload;
    payload.reserve(2 + values.size());
    putU16(payload, static_cast<std::uint16_t>(status));
    payload.insert(payload.end(), values.begin(), values.end());
    return encodeFrame(id, payload);
}

std::vector<Frame> Decoder::feed(std::span<const std::uint8_t> bytes) {
    std::vector<Frame> frames;
    buffer_.insert(buffer_.end(), bytes.begin(), bytes.end());
    std::size_t pos = 0;  // consumed so far (erased once at the end)
    while (buffer_.size() - pos >= kPreambleSize) {
        if (!isPreamble(buffer_, pos)) {
            ++pos;
            ++discarded_;
            continue;
        }
        if (buffer_.size() - pos < kHeaderSize) break;
        const std::uint8_t id = buffer_[pos + 3];
        if (id == kPreambleByte) {
            // A run of more than three AA: the preamble is its last three bytes (a command id
            // 0xAA cannot be told from it; no WSG command has that id).
            ++pos;
            ++discarded_;
            continue;
        }
        const std::size_t size = buffer_[pos + 4] | (std::size_t{buffer_[pos + 5]} << 8);
        if (size > kMaxPayload) {
            ++oversized_;
            frames.push_back({id, {}, FrameError::kTooLarge});
            ++pos;  // resynchronise on the next preamble
            ++discarded_;
            continue;
        }
        const std::size_t total = kHeaderSize + size + kChecksumSize;
        if (buffer_.size() - pos < total) break;
        const auto frame = std::span(buffer_).subspan(pos, total);
        Frame f;
        f.id = id;
        f.payload.assign(frame.begin() + kHeaderSize, frame.begin() + kHeaderSize + size);
        if (checksum(frame) != 0) {
            ++checksumErrors_;
            f.error = FrameError::kChecksum;
            frames.push_back(std::move(f));
            ++pos;
            ++discarded_;
            continue;
        }
        frames.push_back(std::move(f));
        pos += total;
    }
    buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<std::ptrdiff_t>(pos));
    return frames;
}

std::optional<Response> parseResponse(const Frame& frame) {
    if (frame.error != FrameError::kNone) return std::nullopt;
    const auto status = getU16(frame.payload, 0);
    if (!status) return std::nullopt;
    Response r;
    r.id = frame.id;
    r.status = *status;
    r.values.assign(frame.payload.begin() + 2, frame.payload.end());
    return r;
}

void putU16(std::vector<std::uint8_t>& out, std::uint16_t v) {
    out.push_back(static_cast<std::uint8_t>(v & 0xFFu));
    out.push_back(static_cast<std::uint8_t>(v >> 8));
}

void putU32(std::vector<std::uint8_t>& out, std::uint32_t v) {
    for (int i = 0; i < 4; ++i) out.push_back(static_cast<std::uint8_t>((v >> (8 * i)) & 0xFFu));
}

void putFloat(std::vector<std::uint8_t>& out, float v) {
    putU32(out, std::bit_cast<std::uint32_t>(v));
}

std::optional<std::uint16_t> getU16(std::span<const std::uint8_t> bytes, std::size_t offset) {
    if (offset > bytes.size() || bytes.size() - offset < 2) return std::nullopt;
    return static_cast<std::uint16_t>(bytes[offset] | (bytes[offset + 1] << 8));
}

std::optional<std::uint32_t> getU32(std::span<const std::uint8_t> bytes, std::size_t offset) {
    if (offset > bytes.size() || bytes.size() - offset < 4) return std::nullopt;
    std::uint32_t v = 0;
    for (std::size_t i = 0; i < 4; ++i) v |= std::uint32_t{bytes[offset + i]} << (8 * i);
    return v;
}

std::optional<float> getFloat(std::span<const std::uint8_t> bytes, std::size_t offset) {
    const auto v = getU32(bytes, offset);
    if (!v) return std::nullopt;
    return std::bit_cast<float>(*v);
}

std::vector<std::uint8_t> homingPayload(std::uint8_t direction) { return {direction}; }

std::vector<std::uint8_t> prePositionPayload(std::uint8_t flags, float widthMm, float speedMmS) {
    std::vector<std::uint8_t> p{flags};
    putFloat(p, widthMm);
    putFloat(p, speedMmS);
    return p;
}

std::vector<std::uint8_t> graspPayload(float widthMm, float speedMmS) {
    std::vector<std::uint8_t> p;
    putFloat(p, widthMm);
    putFloat(p, speedMmS);
    return p;
}

std::vector<std::uint8_t> floatPayload(float value) {
    std::vector<std::uint8_t> p;
    putFloat(p, value);
    return p;
}

std::vector<std::uint8_t> acknowledgeFastStopPayload() { return {'a', 'c', 'k'}; }

std::vector<std::uint8_t> queryPayload() { return {0, 0, 0}; }

std::vector<std::uint8_t> encodeSystemInformation(const SystemInformation& info) {
    std::vector<std::uint8_t> p{info.type, info.hardwareRevision};
    putU16(p, info.firmware);
    putU32(p, info.serialNumber);
    return p;
}

std::optional<SystemInformation> parseSystemInformation(std::span<const std::uint8_t> values) {
    const auto firmware = getU16(values, 2);
    const auto serial = getU32(values, 4);
    if (!firmware || !serial) return std::nullopt;
    return SystemInformation{values[0], values[1], *firmware, *serial};
}

std::string firmwareString(std::uint16_t firmware) {
    std::string s;
    for (int shift = 12; shift >= 0; shift -= 4) {
        if (!s.empty()) s += '.';
        s += std::to_string((firmware >> shift) & 0xFu);
    }
    return s;
}

std::string_view deviceTypeName(std::uint8_t type) {
    constexpr std::array<std::string_view, 7> kTypes{"unknown", "WSG 50", "WSG 32", "KMS 40",
                                                     "WTS",     "WSG 25", "WSG 70"};
    return type < kTypes.size() ? kTypes[type] : "unknown";
}

std::vector<std::uint8_t> encodeGraspingStatistics(const GraspingStatistics& s) {
    std::vector<std::uint8_t> p;
    putU32(p, s.total);
    putU16(p, s.noPart);
    putU16(p, s.lostPart);
    return p;
}

std::optional<GraspingStatistics> parseGraspingStatistics(std::span<const std::uint8_t> values) {
    const auto total = getU32(values, 0);
    const auto noPart = getU16(values, 4);
    const auto lost = getU16(values, 6);
    if (!total || !noPart || !lost) return std::nullopt;
    return GraspingStatistics{*total, *noPart, *lost};
}

}  // namespace pnp::wsg
