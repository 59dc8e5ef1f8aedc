// Helpers of the Modbus tests: a device with plain register arrays, frames from hex, and the
// far end of a pseudo-terminal opened as an adapter opens a serial port. Every wait bounded.
#pragma once

#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <span>
#include <sstream>
#include <string>
#include <vector>

#include "modbus/modbus.hpp"

namespace pnp::modbus::test {

using Bytes = std::vector<std::uint8_t>;

inline Bytes fromHex(const std::string& hex) {
    Bytes out;
    std::istringstream in(hex);
    std::string byte;
    while (in >> byte) out.push_back(static_cast<std::uint8_t>(std::stoul(byte, nullptr, 16)));
    return out;
}

inline std::string toHex(std::span<const std::uint8_t> bytes) {
    static const char* digits = "0123456789ABCDEF";
    std::string out;
    for (std::uint8_t b : bytes) {
        if (!out.empty()) out += ' ';
        out += digits[b >> 4];
        out += digits[b & 0xF];
    }
    return out;
}

// Address + PDU + CRC (low byte first).
inline Bytes rtuFrame(std::uint8_t address, const Bytes& pdu) {
    Bytes out;
    out.reserve(pdu.size() + 3);
    out.push_back(address);
    for (std::uint8_t b : pdu) out.push_back(b);  // (insert() trips GCC 12's -Warray-bounds)
    const std::uint16_t crc = crc16(out);
    out.push_back(static_cast<std::uint8_t>(crc & 0xFF));
    out.push_back(static_cast<std::uint8_t>(crc >> 8));
    return out;
}

// Holding registers 0x0000..0x00FF, input registers 0x1000..0x10FF (input i = 0x1000 + i,
// its value 0xA000 + i); anything else is exception 02. Writing 0xDEAD is refused with
// exception 03 (a value the device does not accept), 0xFA11 with 04.
class MemoryRegisters : public Registers {
  public:
    static constexpr std::uint16_t kInputBase = 0x1000;

    Exception readHolding(std::uint16_t address, std::span<std::uint16_t> out) override {
        std::lock_guard lock(mutex_);
        if (address + out.size() > holding_.size()) return Exception::kIllegalDataAddress;
        for (std::size_t i = 0; i < out.size(); ++i) out[i] = holding_[address + i];
        ++reads;
        return Exception::kNone;
    }
    Exception readInput(std::uint16_t address, std::span<std::uint16_t> out) override {
        if (address < kInputBase || address + out.size() > kInputBase + 0x100u) {
            return Exception::kIllegalDataAddress;
        }
        for (std::size_t i = 0; i < out.size(); ++i) {
            out[i] = static_cast<std::uint16_t>(0xA000 + (address - kInputBase) + i);
        }
        ++reads;
        return Exception::kNone;
    }
    Exception writeHolding(std::uint16_t address, std::span<const std::uint16_t> values) override {
        std::lock_guard lock(mutex_);
        if (address + values.size() > holding_.size()) return Exception::kIllegalDataAddress;
        for (std::uint16_t v : values) {
            if (v == 0xDEAD) return Exception::kIllegalDataValue;
            if (v == 0xFA11) return Exception::kServerDeviceFailure;
        }
        for (std::size_t i = 0; i < values.size(); ++i) holding_[address + i] = values[i];
        ++writes;
        return Exception::kNone;
    }
    bool answering() const override { return on; }

    std::uint16_t holding(std::size_t i) {
        std::lock_guard lock(mutex_);
        return holding_.at(i);
    }

    std::atomic<bool> on{true};
    std::atomic<int> reads{0};
    std::atomic<int> writes{0};

  private:
    std::mutex mutex_;
    std::array<std::uint16_t, 0x100> holding_{};
};

// The adapter's end of a pseudo-terminal, raw, opened by path.
class SerialPeer {
  public:
    explicit SerialPeer(const std::string& path) {
        fd_ = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
        if (fd_ < 0) return;
        termios tio{};
        tcgetattr(fd_, &tio);
        cfmakeraw(&tio);
        tcsetattr(fd_, TCSANOW, &tio);
    }
    ~SerialPeer() {
        if (fd_ >= 0) ::close(fd_);
    }
    SerialPeer(const SerialPeer&) = delete;
    SerialPeer& operator=(const SerialPeer&) = delete;
    bool ok() const { return fd_ >= 0; }
    int fd() const { return fd_; }

    bool write(const Bytes& bytes) {
        return ::write(fd_, bytes.data(), bytes.size()) == static_cast<ssize_t>(bytes.size());
    }
    // Reads until `count` bytes arrived or `timeout` passed; then what did arrive.
    Bytes read(std::size_t count, std::chrono::milliseconds timeout) {
        Bytes out;
        const auto end = std::chrono::steady_clock::now() + timeout;
        for (int i = 0; i < 10000 && out.size() < count; ++i) {
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                end - std::chrono::steady_clock::now());
            if (left.count() <= 0) break;
            pollfd p{fd_, POLLIN, 0};
            if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) break;
            std::array<std::uint8_t, 512> buffer{};
            const ssize_t got =
                ::read(fd_, buffer.data(), std::min(buffer.size(), count - out.size()));
            if (got <= 0) break;
            out.insert(out.end(), buffer.begin(), buffer.begin() + got);
        }
        return out;
    }
    // A request and its response (`count` bytes expected).
    Bytes exchange(const Bytes& request, std::size_t count,
                   std::chrono::milliseconds timeout = std::chrono::milliseconds(1000)) {
        if (!write(request)) return {};
        return read(count, timeout);
    }

  private:
    int fd_ = -1;
};

}  // namespace pnp::modbus::test
