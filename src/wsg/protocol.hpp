// The WSG command set (Weiss Robotics / Schunk WSG grippers, e.g. the WSG 50) over TCP: frames,
// checksum, command ids, status codes, grasping states and the payloads of the commands pnp
// uses. Sans-I/O, shared by the device side (sim/wsg) and the adapter (device/wsg).
//
// A frame: preamble AA AA AA, command id (1 byte), payload size (uint16 LE), payload, CRC-16
// (uint16 LE) over everything before it. A response's payload starts with a 2-byte status code;
// command-specific values follow only with E_SUCCESS. Multi-byte values are little-endian,
// floats IEEE-754 single precision (widths in mm, speeds in mm/s, forces in N).
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace pnp::wsg {

inline constexpr std::uint16_t kDefaultPort = 1000;
inline constexpr std::uint8_t kPreambleByte = 0xAA;
inline constexpr std::size_t kPreambleSize = 3;
inline constexpr std::size_t kHeaderSize = 6;  // preamble + id + size
inline constexpr std::size_t kChecksumSize = 2;
// Largest payload either side accepts: the commands pnp knows carry at most 10 bytes; a larger
// size field is garbage (or a command we do not serve) and must not make us buffer 64 KiB.
inline constexpr std::size_t kMaxPayload = 1024;
inline constexpr std::size_t kMaxFrameSize = kHeaderSize + kMaxPayload + kChecksumSize;

enum class Command : std::uint8_t {
    kLoop = 0x06,                   // echoes its payload
    kDisconnect = 0x07,             // disconnect announcement (no fast stop on close)
    kHoming = 0x20,                 // payload: direction (0 default, 1 open, 2 close)
    kPrePosition = 0x21,            // flags, width, speed
    kStop = 0x22,                   //
    kFastStop = 0x23,               // needs kAcknowledgeFastStop before the next motion
    kAcknowledgeFastStop = 0x24,    // payload: the ASCII letters "ack"
    kGrasp = 0x25,                  // nominal part width, speed
    kRelease = 0x26,                // opening width, speed
    kSetAcceleration = 0x30,        // float mm/s²
    kGetAcceleration = 0x31,        //
    kSetForceLimit = 0x32,          // float N
    kGetForceLimit = 0x33,          //
    kGetSystemState = 0x40,         // -> uint32 flags (SystemFlag)
    kGetGraspingState = 0x41,       // -> uint8 GraspingState
    kGetGraspingStatistics = 0x42,  // -> uint32 total, uint16 no part, uint16 lost
    kGetOpeningWidth = 0x43,        // -> float mm
    kGetSpeed = 0x44,               // -> float mm/s
    kGetForce = 0x45,               // -> float N
    kGetSystemInformation = 0x50,   // -> type, hardware revision, firmware, serial number
};

// "HOMING", "PRE-POSITION"...; "UNKNOWN" for an id pnp does not know.
std::string_view commandName(std::uint8_t id);
bool knownCommand(std::uint8_t id);

enum class Status : std::uint16_t {
    kSuccess = 0,
    kNotAvailable = 1,
    kNoSensor = 2,
    kNotInitialized = 3,
    kAlreadyRunning = 4,
    kFeatureNotSupported = 5,
    kInconsistentData = 6,
    kTimeout = 7,
    kReadError = 8,
    kWriteError = 9,
    kInsufficientResources = 10,
    kChecksumError = 11,
    kNoParamExpected = 12,
    kNotEnoughParams = 13,
    kCmdUnknown = 14,
    kCmdFormatError = 15,
    kAccessDenied = 16,
    kAlreadyOpen = 17,
    kCmdFailed = 18,
    kCmdAborted = 19,
    kInvalidHandle = 20,
    kNotFound = 21,
    kNotOpen = 22,
    kIoError = 23,
    kInvalidParameter = 24,
    kIndexOutOfBounds = 25,
    kCmdPending = 26,  // accepted, running: a second response with the result follows
    kOverrun = 27,
    kRangeError = 28,
    kAxisBlocked = 29,
    kFileExists = 30,
};

// The manual's names: "E_SUCCESS", "E_CMD_PENDING"...; "E_UNKNOWN" beyond the table.
std::string_view statusName(std::uint16_t status);
inline std::string_view statusName(Status status) {
    return statusName(static_cast<std::uint16_t>(status));
}

enum class GraspingState : std::uint8_t {
    kIdle = 0,
    kGrasping = 1,
    kNoPartFound = 2,
    kPartLost = 3,
    kHolding = 4,
    kReleasing = 5,
    kPositioning = 6,
    kError = 7,
};

// "IDLE", "NO PART FOUND"...; "UNKNOWN" beyond the table.
std::string_view graspingStateName(std::uint8_t state);
inline std::string_view graspingStateName(GraspingState state) {
    return graspingStateName(static_cast<std::uint8_t>(state));
}

// Bits of the system state (0x40).
namespace system_flag {
inline constexpr std::uint32_t kReferenced = 1u << 0;
inline constexpr std::uint32_t kMoving = 1u << 1;
inline constexpr std::uint32_t kBlockedMinus = 1u << 2;
inline constexpr std::uint32_t kBlockedPlus = 1u << 3;
inline constexpr std::uint32_t kSoftLimitMinus = 1u << 4;
inline constexpr std::uint32_t kSoftLimitPlus = 1u << 5;
inline constexpr std::uint32_t kAxisStopped = 1u << 6;
inline constexpr std::uint32_t kTargetPositionReached = 1u << 7;
inline constexpr std::uint32_t kOverdriveMode = 1u << 8;
inline constexpr std::uint32_t kForceControlMode = 1u << 9;
inline constexpr std::uint32_t kFastStop = 1u << 12;
inline constexpr std::uint32_t kTemperatureWarning = 1u << 13;
inline constexpr std::uint32_t kTemperatureFault = 1u << 14;
inline constexpr std::uint32_t kPowerFault = 1u << 15;
inline constexpr std::uint32_t kCurrentFault = 1u << 16;
inline constexpr std::uint32_t kFingerFault = 1u << 17;
inline constexpr std::uint32_t kCommandFailure = 1u << 18;
}  // namespace system_flag

// Pre-position flags (0x21).
namespace move_flag {
inline constexpr std::uint8_t kRelative = 1u << 0;     // width is relative to the current one
inline constexpr std::uint8_t kStopOnBlock = 1u << 1;  // stop (not clamp) when blocked
}  // namespace move_flag

// The WSG's CRC-16: the CCITT polynomial 0x1021 table applied byte-wise from the low end,
// initial value 0xFFFF, no final XOR (the algorithm of Weiss's reference code; it reproduces
// every example frame of the manual). Running it over a whole frame, checksum included,
// gives 0.
std::uint16_t checksum(std::span<const std::uint8_t> bytes, std::uint16_t crc = 0xFFFF);

// A whole frame for `id` and `payload` (a command, or a response whose payload already holds
// the status). Throws std::length_error for a payload above kMaxPayload.
std::vector<std::uint8_t> encodeFrame(std::uint8_t id, std::span<const std::uint8_t> payload);
inline std::vector<std::uint8_t> encodeCommand(Command id, std::span<const std::uint8_t> payload) {
    return encodeFrame(static_cast<std::uint8_t>(id), payload);
}
// A response: status, then `values` (only sent with kSuccess by the device).
std::vector<std::uint8_t> encodeResponse(std::uint8_t id, Status status,
                                         std::span<const std::uint8_t> values = {});

enum class FrameError {
    kNone,
    kChecksum,  // the CRC did not match: id and payload are as received
    kTooLarge,  // the size field exceeded kMaxPayload: payload empty, nothing consumed past it
};

struct Frame {
    std::uint8_t id = 0;
    std::vector<std::uint8_t> payload;
    FrameError error = FrameError::kNone;
};

// Splits a byte stream into frames, fed arbitrary slices. It looks for the preamble (bytes
// before it are discarded and counted), waits for the size field and the whole frame, and
// checks the CRC. A frame with a bad CRC or an oversized size field is reported (so the
// device can answer E_CHECKSUM_ERROR) and only its first preamble byte is consumed: the
// decoder resynchronises on the next preamble, so garbage that happened to contain one
// cannot swallow the frames after it. A run of more than three AA bytes is read as padding
// before the preamble (its last three bytes). Its buffer never holds more than kMaxFrameSize +
// the slice being fed.
class Decoder {
  public:
    // Every complete frame in the bytes fed so far, in order.
    std::vector<Frame> feed(std::span<const std::uint8_t> bytes);

    std::uint64_t checksumErrors() const { return checksumErrors_; }
    std::uint64_t oversizedFrames() const { return oversized_; }
    std::uint64_t discardedBytes() const { return discarded_; }
    std::size_t buffered() const { return buffer_.size(); }
    void reset() { buffer_.clear(); }

  private:
    std::vector<std::uint8_t> buffer_;
    std::uint64_t checksumErrors_ = 0;
    std::uint64_t oversized_ = 0;
    std::uint64_t discarded_ = 0;
};

// A response split into its status and the values after it.
struct Response {
    std::uint8_t id = 0;
    std::uint16_t status = 0;
    std::vector<std::uint8_t> values;
    bool ok() const { return status == static_cast<std::uint16_t>(Status::kSuccess); }
    bool pending() const { return status == static_cast<std::uint16_t>(Status::kCmdPending); }
};
// nullopt when the payload has no room for a status code.
std::optional<Response> parseResponse(const Frame& frame);

// ---- little-endian values ----
void putU16(std::vector<std::uint8_t>& out, std::uint16_t v);
void putU32(std::vector<std::uint8_t>& out, std::uint32_t v);
void putFloat(std::vector<std::uint8_t>& out, float v);
// nullopt when `bytes` is too short from `offset`.
std::optional<std::uint16_t> getU16(std::span<const std::uint8_t> bytes, std::size_t offset);
std::optional<std::uint32_t> getU32(std::span<const std::uint8_t> bytes, std::size_t offset);
std::optional<float> getFloat(std::span<const std::uint8_t> bytes, std::size_t offset);

// ---- command payloads ----
std::vector<std::uint8_t> homingPayload(std::uint8_t direction = 0);
std::vector<std::uint8_t> prePositionPayload(std::uint8_t flags, float widthMm, float speedMmS);
std::vector<std::uint8_t> graspPayload(float widthMm, float speedMmS);  // also release
std::vector<std::uint8_t> floatPayload(float value);                    // set acc / force
std::vector<std::uint8_t> acknowledgeFastStopPayload();                 // "ack"
// The 3-byte request of the state / value queries 0x40..0x45: no automatic updates.
std::vector<std::uint8_t> queryPayload();

// The values of a 0x50 answer.
struct SystemInformation {
    std::uint8_t type = 0;  // 1 = WSG 50
    std::uint8_t hardwareRevision = 0;
    std::uint16_t firmware = 0;  // four nibbles, e.g. 0x4200 = 4.2.0.0
    std::uint32_t serialNumber = 0;
};
std::vector<std::uint8_t> encodeSystemInformation(const SystemInformation& info);
std::optional<SystemInformation> parseSystemInformation(std::span<const std::uint8_t> values);
// "4.2.0.0"
std::string firmwareString(std::uint16_t firmware);
// "WSG 50", "WSG 32"... for the type byte; "unknown" otherwise.
std::string_view deviceTypeName(std::uint8_t type);

struct GraspingStatistics {
    std::uint32_t total = 0;
    std::uint16_t noPart = 0;
    std::uint16_t lostPart = 0;
};
std::vector<std::uint8_t> encodeGraspingStatistics(const GraspingStatistics& s);
std::optional<GraspingStatistics> parseGraspingStatistics(std::span<const std::uint8_t> values);

}  // namespace pnp::wsg
