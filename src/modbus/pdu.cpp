// The application protocol (Modbus Application Protocol V1.1b3): one request PDU against a
// device's registers, checked in the order of the spec's state diagrams (§6): function code,
// then quantity / byte count (exception 03), then address range (02), then the device (its
// own 02 / 03 / 04).
#include <array>

#include "modbus/modbus.hpp"

namespace pnp::modbus {

namespace {

constexpr std::uint8_t kReadHolding = 0x03;
constexpr std::uint8_t kReadInput = 0x04;
constexpr std::uint8_t kWriteSingle = 0x06;
constexpr std::uint8_t kWriteMultiple = 0x10;
constexpr std::uint8_t kReadWriteMultiple = 0x17;

// Quantities of the spec (§6.3, §6.4, §6.12, §6.17).
constexpr std::size_t kMaxRead = 125;
constexpr std::size_t kMaxWrite = 123;
constexpr std::size_t kMaxReadWriteWrite = 121;

std::uint16_t be16(std::span<const std::uint8_t> bytes, std::size_t at) {
    return static_cast<std::uint16_t>(bytes[at] << 8 | bytes[at + 1]);
}

void put16(std::vector<std::uint8_t>& out, std::uint16_t value) {
    out.push_back(static_cast<std::uint8_t>(value >> 8));
    out.push_back(static_cast<std::uint8_t>(value & 0xFF));
}

std::vector<std::uint8_t> exception(std::uint8_t function, Exception code) {
    return {static_cast<std::uint8_t>(function | 0x80), static_cast<std::uint8_t>(code)};
}

// The registers from `address` fit in the 16-bit address space.
bool fits(std::uint16_t address, std::size_t quantity) {
    return static_cast<std::size_t>(address) + quantity <= 0x10000;
}

std::vector<std::uint16_t> values(std::span<const std::uint8_t> bytes, std::size_t count) {
    std::vector<std::uint16_t> out(count);
    for (std::size_t i = 0; i < count; ++i) out[i] = be16(bytes, 2 * i);
    return out;
}

std::vector<std::uint8_t> readResponse(std::uint8_t function,
                                       std::span<const std::uint16_t> registers) {
    std::vector<std::uint8_t> out{function, static_cast<std::uint8_t>(2 * registers.size())};
    for (std::uint16_t r : registers) put16(out, r);
    return out;
}

std::vector<std::uint8_t> read(Registers& registers, std::uint8_t function,
                               std::span<const std::uint8_t> data) {
    if (data.size() != 4) return exception(function, Exception::kIllegalDataValue);
    const std::uint16_t address = be16(data, 0);
    const std::uint16_t quantity = be16(data, 2);
    if (quantity < 1 || quantity > kMaxRead) {
        return exception(function, Exception::kIllegalDataValue);
    }
    if (!fits(address, quantity)) return exception(function, Exception::kIllegalDataAddress);
    std::array<std::uint16_t, kMaxRead> buffer{};
    const std::span<std::uint16_t> out(buffer.data(), quantity);
    const Exception e = function == kReadHolding ? registers.readHolding(address, out)
                                                 : registers.readInput(address, out);
    if (e != Exception::kNone) return exception(function, e);
    return readResponse(function, out);
}

std::vector<std::uint8_t> writeSingle(Registers& registers, std::span<const std::uint8_t> pdu) {
    const auto data = pdu.subspan(1);
    if (data.size() != 4) return exception(kWriteSingle, Exception::kIllegalDataValue);
    const std::uint16_t value = be16(data, 2);
    const Exception e = registers.writeHolding(be16(data, 0), std::span(&value, 1));
    if (e != Exception::kNone) return exception(kWriteSingle, e);
    return {pdu.begin(), pdu.end()};  // the normal response echoes the request
}

std::vector<std::uint8_t> writeMultiple(Registers& registers, std::span<const std::uint8_t> data) {
    if (data.size() < 5) return exception(kWriteMultiple, Exception::kIllegalDataValue);
    const std::uint16_t address = be16(data, 0);
    const std::uint16_t quantity = be16(data, 2);
    const std::size_t byteCount = data[4];
    if (quantity < 1 || quantity > kMaxWrite || byteCount != 2u * quantity ||
        data.size() != 5 + byteCount) {
        return exception(kWriteMultiple, Exception::kIllegalDataValue);
    }
    if (!fits(address, quantity)) return exception(kWriteMultiple, Exception::kIllegalDataAddress);
    const auto v = values(data.subspan(5), quantity);
    const Exception e = registers.writeHolding(address, v);
    if (e != Exception::kNone) return exception(kWriteMultiple, e);
    std::vector<std::uint8_t> out{kWriteMultiple};
    put16(out, address);
    put16(out, quantity);
    return out;
}

// FC23: the write is performed before the read (§6.17).
std::vector<std::uint8_t> readWriteMultiple(Registers& registers,
                                            std::span<const std::uint8_t> data) {
    if (data.size() < 9) return exception(kReadWriteMultiple, Exception::kIllegalDataValue);
    const std::uint16_t readAddress = be16(data, 0);
    const std::uint16_t readQuantity = be16(data, 2);
    const std::uint16_t writeAddress = be16(data, 4);
    const std::uint16_t writeQuantity = be16(data, 6);
    const std::size_t byteCount = data[8];
    if (readQuantity < 1 || readQuantity > kMaxRead || writeQuantity < 1 ||
        writeQuantity > kMaxReadWriteWrite || byteCount != 2u * writeQuantity ||
        data.size() != 9 + byteCount) {
        return exception(kReadWriteMultiple, Exception::kIllegalDataValue);
    }
    if (!fits(readAddress, readQuantity) || !fits(writeAddress, writeQuantity)) {
        return exception(kReadWriteMultiple, Exception::kIllegalDataAddress);
    }
    const auto v = values(data.subspan(9), writeQuantity);
    if (const Exception e = registers.writeHolding(writeAddress, v); e != Exception::kNone) {
        return exception(kReadWriteMultiple, e);
    }
    std::array<std::uint16_t, kMaxRead> buffer{};
    const std::span<std::uint16_t> out(buffer.data(), readQuantity);
    if (const Exception e = registers.readHolding(readAddress, out); e != Exception::kNone) {
        return exception(kReadWriteMultiple, e);
    }
    return readResponse(kReadWriteMultiple, out);
}

}  // namespace

std::uint16_t crc16(std::span<const std::uint8_t> bytes) {
    std::uint16_t crc = 0xFFFF;
    for (std::uint8_t b : bytes) {
        crc ^= b;
        for (int bit = 0; bit < 8; ++bit) {
            crc = (crc & 1) ? static_cast<std::uint16_t>((crc >> 1) ^ 0xA001)
                            : static_cast<std::uint16_t>(crc >> 1);
        }
    }
    return crc;
}

std::vector<std::uint8_t> answer(Registers& registers, std::span<const std::uint8_t> pdu) {
    if (pdu.empty()) return {};  // no function code: nothing to answer to
    const std::uint8_t function = pdu[0];
    switch (function) {
        case kReadHolding:
        case kReadInput:
            return read(registers, function, pdu.subspan(1));
        case kWriteSingle:
            return writeSingle(registers, pdu);
        case kWriteMultiple:
            return writeMultiple(registers, pdu.subspan(1));
        case kReadWriteMultiple:
            return readWriteMultiple(registers, pdu.subspan(1));
        default:
            return exception(function, Exception::kIllegalFunction);
    }
}

}  // namespace pnp::modbus
