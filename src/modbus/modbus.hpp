// The device side of Modbus (the application protocol V1.1b3 and Modbus over serial line
// V1.02): what a simulated device answers, over RTU on a serial line or over TCP (MBAP).
// The adapters use libmodbus, an independent implementation of the master side; this module
// is what the simulators in src/sim/* answer with. No threads of the device model: the
// transports call the data model (Registers) on their own thread, one request at a time.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace pnp::modbus {

// Exception codes of the application protocol (§7); kNone = a normal answer.
enum class Exception : std::uint8_t {
    kNone = 0x00,
    kIllegalFunction = 0x01,
    kIllegalDataAddress = 0x02,
    kIllegalDataValue = 0x03,
    kServerDeviceFailure = 0x04,
    kGatewayPathUnavailable = 0x0A,
    kGatewayTargetFailed = 0x0B,  // TcpServer: a request for another unit id
};

// A device's registers, as its manual maps them. Called on the transport's thread, one
// request at a time; an implementation shared with another thread locks itself.
class Registers {
  public:
    virtual ~Registers() = default;
    // FC03: `out.size()` holding registers from `address`.
    virtual Exception readHolding(std::uint16_t address, std::span<std::uint16_t> out) = 0;
    // FC04: input registers.
    virtual Exception readInput(std::uint16_t address, std::span<std::uint16_t> out) = 0;
    // FC06 (one value) and FC16 (several): holding registers from `address`.
    virtual Exception writeHolding(std::uint16_t address,
                                   std::span<const std::uint16_t> values) = 0;
    // Whether the device answers at all (false: powered off — requests get no answer, as
    // from a device without power).
    virtual bool answering() const { return true; }
};

// CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF); on the wire low byte first.
std::uint16_t crc16(std::span<const std::uint8_t> bytes);

// One request PDU (function code + data) against `registers`: the response PDU (a normal
// answer or function | 0x80 + exception code). Supports FC03, FC04, FC06, FC16 and FC23
// (read/write multiple); any other function gets kIllegalFunction; a quantity outside the
// protocol's bounds (e.g. 1..125 for reads) gets kIllegalDataValue.
std::vector<std::uint8_t> answer(Registers& registers, std::span<const std::uint8_t> pdu);

// RTU framing from a byte stream: feed bytes as they arrive and the time gaps between
// them; a frame ends after a silence of 3.5 character times (at 115200 baud: the fixed
// 1.75 ms of the serial-line spec above 19200). A frame with a bad CRC or for another
// slave is dropped without an answer; address 0 (broadcast) is executed without an answer.
struct RtuStats {
    std::uint64_t frames = 0;        // well-formed frames for us, answered
    std::uint64_t badCrc = 0;        // dropped
    std::uint64_t otherSlave = 0;    // dropped
    std::uint64_t tooShort = 0;      // dropped (< 4 bytes)
    std::uint64_t tooLong = 0;       // > 256 bytes: dropped
    std::uint64_t broadcasts = 0;    // executed, not answered
    std::uint64_t notAnswering = 0;  // for us while answering() was false: dropped
};

struct RtuSlaveConfig {
    std::uint8_t slave = 1;
    std::uint32_t baud = 115200;  // for the inter-frame silence
};

// The RTU receiver without I/O (RtuSlave's core, usable on its own): bytes in with the time
// they were read, frames out. A frame ends when nothing arrived for t3.5 (checked when the
// next bytes come, or by expire() when the reader's wait for bytes times out at deadline()).
// The 1.5-character inter-byte limit is not enforced: a pty or a USB adapter delivers a frame
// in chunks with gaps no real RS-485 line has.
class RtuFramer {
  public:
    using Clock = std::chrono::steady_clock;
    static constexpr std::size_t kMaxFrame = 256;  // serial line V1.02 §2.5.1

    explicit RtuFramer(RtuSlaveConfig config);
    // t3.5: 3.5 characters of 11 bits at the baud rate; fixed 1.75 ms above 19200 baud.
    Clock::duration silence() const { return silence_; }
    // Bytes read at `now`. A frame in progress silent for t3.5 by then is completed first:
    // its response ADU (address, PDU, CRC), if it gets one.
    std::optional<std::vector<std::uint8_t>> receive(std::span<const std::uint8_t> bytes,
                                                     Clock::time_point now, Registers& registers);
    // Completes the frame in progress if it has been silent for t3.5 at `now`.
    std::optional<std::vector<std::uint8_t>> expire(Clock::time_point now, Registers& registers);
    // When the frame in progress ends if nothing more arrives; none without one.
    std::optional<Clock::time_point> deadline() const;
    const RtuStats& stats() const { return stats_; }

  private:
    std::optional<std::vector<std::uint8_t>> complete(Registers& registers);

    RtuSlaveConfig config_;
    Clock::duration silence_;
    std::vector<std::uint8_t> frame_;
    bool overflow_ = false;  // more than kMaxFrame bytes: the frame is dropped at its end
    std::optional<Clock::time_point> last_;  // when the frame in progress got bytes last
    RtuStats stats_;
};

// A slave on a serial line: a pseudo-terminal's master side (the simulator) or a tty. Owns
// a thread that reads the fd, frames, answers through `registers` and writes the response.
class RtuSlave {
  public:
    // `fd` stays owned by the caller and must outlive the slave; start() makes it
    // non-blocking (a response is dropped after 100 ms if the line does not take it).
    RtuSlave(int fd, RtuSlaveConfig config, Registers& registers);
    ~RtuSlave();  // stop()
    RtuSlave(const RtuSlave&) = delete;
    RtuSlave& operator=(const RtuSlave&) = delete;
    void start();  // throws std::system_error (no thread / pipe)
    void stop();   // returns within milliseconds; restartable
    RtuStats stats() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

// A pseudo-terminal pair for a simulated serial device: the simulator keeps the master
// side, an adapter opens `path()` (e.g. /dev/pts/7) as it would /dev/ttyUSB0. Raw mode.
class PseudoTerminal {
  public:
    PseudoTerminal();  // throws std::system_error; the master side is non-blocking
    ~PseudoTerminal();
    PseudoTerminal(const PseudoTerminal&) = delete;
    PseudoTerminal& operator=(const PseudoTerminal&) = delete;
    int masterFd() const;
    const std::string& path() const;

  private:
    int master_ = -1;
    int slaveKeepAlive_ = -1;  // held open so the master never reads EIO between clients
    std::string path_;
};

struct TcpServerConfig {
    std::string bindAddress = "127.0.0.1";
    std::uint16_t port = 502;        // 0: any free port
    std::size_t maxConnections = 8;  // more are accepted and closed at once
    // A request for another unit id: answered (0xFF and 0 are "this device" by convention)
    // unless set; then it gets exception 0x0B (gateway target failed to respond).
    std::optional<std::uint8_t> unitId;
    std::size_t maxPendingOutput = 65536;  // bytes of answers a client has not read: closed
};

// Modbus TCP (MBAP header: transaction id, protocol 0, length, unit id) on a listening
// socket; one thread with poll() for every connection; answers in order per connection.
// A malformed header (protocol ≠ 0, length out of 2..254) closes that connection only.
// While answering() is false requests are read and dropped (the client times out).
class TcpServer {
  public:
    TcpServer(TcpServerConfig config, Registers& registers);
    ~TcpServer();  // stop()
    TcpServer(const TcpServer&) = delete;
    TcpServer& operator=(const TcpServer&) = delete;
    void start();  // throws std::system_error (port taken...)
    void stop();
    std::uint16_t port() const;  // the bound port (after start)

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::modbus
