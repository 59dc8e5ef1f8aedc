// The application protocol on its own: CRC-16 vectors and answer() for every function and
// every exception.
#include <gtest/gtest.h>

#include "modbus_helpers.hpp"

namespace pnp::modbus::test {
namespace {

Bytes ask(Registers& r, const std::string& pdu) { return answer(r, fromHex(pdu)); }

TEST(ModbusCrc, KnownVectors) {
    // The CRC-16/MODBUS check value, and frames of the Robotiq manual (on the wire low first).
    const std::string check = "123456789";
    EXPECT_EQ(crc16(Bytes(check.begin(), check.end())), 0x4B37);
    EXPECT_EQ(crc16(fromHex("09 03 07 D0 00 01")), 0xCF85);
    EXPECT_EQ(crc16(fromHex("09 10 03 E8 00 03 06 01 00 00 00 00 00")), 0xE172);
    EXPECT_EQ(crc16(fromHex("09 10 03 E8 00 03")), 0x3001);
    EXPECT_EQ(crc16(fromHex("09 04 06 B9 00 00 FF BD 00")), 0x9A5C);
    EXPECT_EQ(crc16(Bytes{}), 0xFFFF);
    // A frame with its CRC appended checks to 0.
    EXPECT_EQ(crc16(rtuFrame(0x11, fromHex("03 00 6B 00 03"))), 0x0000);
}

TEST(ModbusAnswer, ReadHoldingAndInput) {
    MemoryRegisters r;
    ASSERT_EQ(ask(r, "06 00 05 12 34"), fromHex("06 00 05 12 34"));
    EXPECT_EQ(ask(r, "03 00 04 00 02"), fromHex("03 04 00 00 12 34"));
    EXPECT_EQ(ask(r, "04 10 02 00 03"), fromHex("04 06 A0 02 A0 03 A0 04"));
    // The largest read: 125 registers, 250 bytes.
    const Bytes big = ask(r, "03 00 00 00 7D");
    ASSERT_EQ(big.size(), 2u + 250u);
    EXPECT_EQ(big[1], 250);
}

TEST(ModbusAnswer, WriteSingleAndMultiple) {
    MemoryRegisters r;
    EXPECT_EQ(ask(r, "06 00 10 AB CD"), fromHex("06 00 10 AB CD"));
    EXPECT_EQ(r.holding(0x10), 0xABCD);
    EXPECT_EQ(ask(r, "10 00 20 00 02 04 00 0A 01 02"), fromHex("10 00 20 00 02"));
    EXPECT_EQ(r.holding(0x20), 0x000A);
    EXPECT_EQ(r.holding(0x21), 0x0102);
    // 123 registers, the most one FC16 may write.
    std::string request = "10 00 00 00 7B F6";
    for (int i = 0; i < 123; ++i) request += " 00 01";
    EXPECT_EQ(ask(r, request), fromHex("10 00 00 00 7B"));
    EXPECT_EQ(r.holding(122), 1);
}

TEST(ModbusAnswer, ReadWriteMultipleWritesBeforeReading) {
    MemoryRegisters r;
    EXPECT_EQ(ask(r, "17 00 30 00 02 00 30 00 01 02 55 66"), fromHex("17 04 55 66 00 00"));
    EXPECT_EQ(r.holding(0x30), 0x5566);
}

TEST(ModbusAnswer, IllegalFunction) {
    MemoryRegisters r;
    EXPECT_EQ(ask(r, "01 00 00 00 01"), fromHex("81 01"));  // coils: not a register device
    EXPECT_EQ(ask(r, "05 00 00 FF 00"), fromHex("85 01"));
    EXPECT_EQ(ask(r, "2B 0E 01 00"), fromHex("AB 01"));
    EXPECT_EQ(ask(r, "00"), fromHex("80 01"));
    EXPECT_EQ(ask(r, "83 00 00 00 01"), fromHex("83 01"));  // an exception code as a request
    EXPECT_TRUE(answer(r, Bytes{}).empty());                // nothing to answer to
}

TEST(ModbusAnswer, IllegalQuantityOrLengthIsIllegalDataValue) {
    MemoryRegisters r;
    EXPECT_EQ(ask(r, "03 00 00 00 00"), fromHex("83 03"));  // 0 registers
    EXPECT_EQ(ask(r, "03 00 00 00 7E"), fromHex("83 03"));  // 126
    EXPECT_EQ(ask(r, "04 10 00 00 00"), fromHex("84 03"));
    EXPECT_EQ(ask(r, "04 10 00 00 7E"), fromHex("84 03"));
    EXPECT_EQ(ask(r, "03 00 00 00"), fromHex("83 03"));        // short
    EXPECT_EQ(ask(r, "03 00 00 00 01 00"), fromHex("83 03"));  // long
    EXPECT_EQ(ask(r, "06 00 00 00"), fromHex("86 03"));
    EXPECT_EQ(ask(r, "10 00 00 00 00 00"), fromHex("90 03"));           // 0 registers
    EXPECT_EQ(ask(r, "10 00 00 00 02 02 00 01"), fromHex("90 03"));     // byte count ≠ 2N
    EXPECT_EQ(ask(r, "10 00 00 00 01 02 00"), fromHex("90 03"));        // data short
    EXPECT_EQ(ask(r, "10 00 00 00 01 02 00 01 00"), fromHex("90 03"));  // data long
    EXPECT_EQ(ask(r, "10 00 00"), fromHex("90 03"));
    std::string tooMany = "10 00 00 00 7C F8";  // 124 registers
    for (int i = 0; i < 124; ++i) tooMany += " 00 00";
    EXPECT_EQ(ask(r, tooMany), fromHex("90 03"));
    EXPECT_EQ(ask(r, "17 00 00 00 00 00 00 00 01 02 00 00"), fromHex("97 03"));  // read 0
    EXPECT_EQ(ask(r, "17 00 00 00 01 00 00 00 00 00"), fromHex("97 03"));        // write 0
    EXPECT_EQ(ask(r, "17 00 00 00 01 00 00 00 01 04 00 00"), fromHex("97 03"));  // count
    EXPECT_EQ(ask(r, "17 00 00 00 01"), fromHex("97 03"));
    EXPECT_EQ(r.writes.load(), 0);  // nothing reached the device
}

TEST(ModbusAnswer, IllegalAddress) {
    MemoryRegisters r;
    EXPECT_EQ(ask(r, "03 01 00 00 01"), fromHex("83 02"));  // beyond the map
    EXPECT_EQ(ask(r, "03 00 FF 00 02"), fromHex("83 02"));  // runs off its end
    EXPECT_EQ(ask(r, "03 FF FF 00 02"), fromHex("83 02"));  // off the address space
    EXPECT_EQ(ask(r, "04 00 00 00 01"), fromHex("84 02"));
    EXPECT_EQ(ask(r, "06 01 00 00 01"), fromHex("86 02"));
    EXPECT_EQ(ask(r, "10 00 FF 00 02 04 00 01 00 02"), fromHex("90 02"));
    EXPECT_EQ(ask(r, "17 01 00 00 01 00 00 00 01 02 00 01"), fromHex("97 02"));
    EXPECT_EQ(ask(r, "17 00 00 00 01 01 00 00 01 02 00 01"), fromHex("97 02"));
}

TEST(ModbusAnswer, DeviceRefusesAValueOrFails) {
    MemoryRegisters r;
    EXPECT_EQ(ask(r, "06 00 00 DE AD"), fromHex("86 03"));
    EXPECT_EQ(ask(r, "10 00 00 00 01 02 FA 11"), fromHex("90 04"));
    EXPECT_EQ(ask(r, "17 00 00 00 01 00 00 00 01 02 DE AD"), fromHex("97 03"));
    EXPECT_EQ(r.holding(0), 0);
}

}  // namespace
}  // namespace pnp::modbus::test
