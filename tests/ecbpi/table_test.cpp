// The process data tables (pnp_iolink): the installed ECBPi table and master map load, bits
// are packed as IODD numbers them, and bad tables are refused with FILE:LINE.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "iolink/process_data.hpp"

namespace pnp::iolink {
namespace {

const char* kGood = R"(pnp-iolink-device: 1
vendor: Test
vendor-id: 0x00EA
device: T
device-id: 7
pd-in-bytes: 4
pd-out-bytes: 1
process-data:
  - {name: flag, direction: in, bit-offset: 24, bit-length: 1, type: bool}
  - {name: level, direction: in, bit-offset: 0, bit-length: 16, type: int, unit: mbar, scale: 0.5, offset: 10}
  - {name: on, direction: out, bit-offset: 0, bit-length: 1, type: bool}
)";

// kGood with the line `from` replaced by `to` (1-based lines).
std::string withLine(int line, const std::string& to) {
    std::string text = kGood;
    std::size_t start = 0;
    for (int i = 1; i < line; ++i) start = text.find('\n', start) + 1;
    const std::size_t end = text.find('\n', start);
    return text.substr(0, start) + to + text.substr(end);
}

void expectRefused(const std::string& text, int line, const std::string& says) {
    Result<DeviceTable> t = parseDeviceTable(text, "bad.yaml");
    ASSERT_FALSE(t.ok()) << text;
    const std::string prefix = "bad.yaml:" + std::to_string(line) + ": ";
    EXPECT_EQ(t.error().message.rfind(prefix, 0), 0u) << t.error().message;
    EXPECT_NE(t.error().message.find(says), std::string::npos) << t.error().message;
    EXPECT_EQ(t.error().line, line);
}

TEST(IoLinkTable, InstalledEcbpiTableLoads) {
    Result<DeviceTable> t = loadDeviceTable(modelsDirectory() / "schmalz-ecbpi.yaml");
    ASSERT_TRUE(t.ok()) << t.error().message;
    EXPECT_EQ(t->vendorId, 234);
    EXPECT_EQ(t->device, "ECBPi");
    EXPECT_EQ(t->pdInBytes, 4u);
    EXPECT_EQ(t->pdOutBytes, 1u);
    const Field* present = t->find("part-present", Direction::kIn);
    ASSERT_NE(present, nullptr);
    EXPECT_EQ(present->bitOffset, 24u);  // octet 0, bit 0
    const Field* vacuum = t->find("vacuum", Direction::kIn);
    ASSERT_NE(vacuum, nullptr);
    EXPECT_EQ(vacuum->bitLength, 16u);
    EXPECT_EQ(vacuum->unit, "mbar");
    ASSERT_NE(t->find("suction", Direction::kOut), nullptr);
    ASSERT_NE(t->find("blow-off", Direction::kOut), nullptr);
    EXPECT_EQ(t->find("suction", Direction::kIn), nullptr);
}

TEST(IoLinkTable, InstalledMasterMapLoads) {
    Result<MasterMap> m = loadMasterMap(defaultMasterMapPath());
    ASSERT_TRUE(m.ok()) << m.error().message;
    EXPECT_EQ(m->ports, 4u);
    EXPECT_EQ(m->address(1, m->statusOffset), 1000);
    EXPECT_EQ(m->address(2, m->pdInOffset), 2010);
    EXPECT_EQ(m->address(4, m->pdOutOffset), 4100);
    EXPECT_EQ(m->state(2), PortState::kOperate);
    EXPECT_EQ(m->state(1), PortState::kPreoperate);
    EXPECT_EQ(m->state(0), PortState::kNoDevice);
    EXPECT_EQ(m->statusValue(PortState::kNoDevice), 0);
}

TEST(IoLinkTable, BitsAreNumberedAsIoddDoes) {
    Result<DeviceTable> t = parseDeviceTable(kGood, "good.yaml");
    ASSERT_TRUE(t.ok()) << t.error().message;
    EXPECT_EQ(t->vendorId, 0xEA);
    const Field& flag = *t->find("flag", Direction::kIn);
    const Field& level = *t->find("level", Direction::kIn);
    std::vector<std::uint8_t> pd(4, 0);
    writeRaw(pd, flag, 1);
    EXPECT_EQ(pd, (std::vector<std::uint8_t>{0x01, 0, 0, 0}));  // bit 24: octet 0's LSB
    writeRaw(pd, level, 0x1234);
    EXPECT_EQ(pd, (std::vector<std::uint8_t>{0x01, 0, 0x12, 0x34}));  // big-endian, last octets
    EXPECT_EQ(readRaw(pd, level), 0x1234u);
    EXPECT_EQ(readRaw(pd, flag), 1u);
    writeRaw(pd, flag, 0);
    EXPECT_EQ(pd[0], 0);
    // int: sign-extended, then raw * scale + offset.
    EXPECT_DOUBLE_EQ(toValue(level, 0xFFFF), -1 * 0.5 + 10);
    EXPECT_DOUBLE_EQ(toValue(level, 100), 60.0);
    EXPECT_EQ(fromValue(level, 60.0), 100u);
    EXPECT_EQ(fromValue(level, -1e9), 0x8000u);  // clamped to the 16-bit range
    EXPECT_EQ(fromValue(level, 1e9), 0x7FFFu);
}

TEST(IoLinkTable, OctetsPackIntoRegistersHighByteFirst) {
    const std::vector<std::uint8_t> octets = {0x01, 0x02, 0x03};
    const std::vector<std::uint16_t> regs = toRegisters(octets);
    EXPECT_EQ(regs, (std::vector<std::uint16_t>{0x0102, 0x0300}));
    EXPECT_EQ(fromRegisters(regs, 3), octets);
}

TEST(IoLinkTable, BadTablesAreRefusedWithFileAndLine) {
    // A second output on the bit of 'on'.
    expectRefused(withLine(11,
                           "  - {name: on, direction: out, bit-offset: 0, bit-length: 1, "
                           "type: bool}\n  - {name: on2, direction: out, bit-offset: 0, "
                           "bit-length: 1, type: bool}"),
                  12, "overlaps 'on'");
    expectRefused(withLine(9,
                           "  - {name: flag, direction: in, bit-offset: 31, bit-length: 2, "
                           "type: uint}"),
                  9, "reaches beyond the 32 bits");
    expectRefused(withLine(9,
                           "  - {name: flag, direction: in, bit-offset: 24, bit-length: 2, "
                           "type: bool}"),
                  9, "bit-length 1");
    expectRefused(withLine(9,
                           "  - {name: flag, direction: sideways, bit-offset: 24, "
                           "bit-length: 1, type: bool}"),
                  9, "in or out");
    expectRefused(withLine(9,
                           "  - {name: flag, direction: in, bit-offest: 24, bit-length: 1, "
                           "type: bool}"),
                  9, "unknown key 'bit-offest'");
    expectRefused(withLine(6, "pd-in-bytes: 40"), 6, "outside 1..32");
    expectRefused(withLine(3, "vendor-id: twelve"), 3, "must be an integer");
    expectRefused(withLine(1, "pnp-iolink-device: 2"), 1, "not a version");
    expectRefused(withLine(10,
                           "  - {name: flag, direction: in, bit-offset: 0, bit-length: 1, "
                           "type: bool}"),
                  10, "defined twice");
    expectRefused(withLine(10,
                           "  - {name: level, direction: in, bit-offset: 0, bit-length: 16, "
                           "type: int, scale: 0}"),
                  10, "must not be 0");
}

TEST(IoLinkTable, UnreadableOrMalformedFilesAreRefused) {
    Result<DeviceTable> missing = loadDeviceTable("/nonexistent/table.yaml");
    ASSERT_FALSE(missing.ok());
    EXPECT_NE(missing.error().message.find("/nonexistent/table.yaml"), std::string::npos);
    Result<DeviceTable> syntax = parseDeviceTable("a: [1, 2\nb: }", "broken.yaml");
    ASSERT_FALSE(syntax.ok());
    EXPECT_EQ(syntax.error().message.rfind("broken.yaml:", 0), 0u) << syntax.error().message;
    Result<DeviceTable> empty = parseDeviceTable("", "empty.yaml");
    ASSERT_FALSE(empty.ok());
    Result<DeviceTable> missingKey =
        parseDeviceTable("pnp-iolink-device: 1\nvendor: x\n", "short.yaml");
    ASSERT_FALSE(missingKey.ok());
    EXPECT_NE(missingKey.error().message.find("no 'vendor-id'"), std::string::npos)
        << missingKey.error().message;
    const std::string huge(2 << 20, '#');
    EXPECT_FALSE(parseDeviceTable(huge, "huge.yaml").ok());
}

TEST(IoLinkTable, BadMasterMapsAreRefused) {
    const std::string good = R"(pnp-iolink-master: 1
name: m
ports: 4
port-base: 1000
port-stride: 1000
status: {offset: 0, mask: 0xFFFF, operate: 2, preoperate: 1}
identity-offset: 1
pd-in-offset: 10
pd-out-offset: 100
pd-max-bytes: 32
)";
    ASSERT_TRUE(parseMasterMap(good, "m.yaml").ok());
    auto refused = [&](const std::string& from, const std::string& to, const std::string& says) {
        std::string text = good;
        text.replace(text.find(from), from.size(), to);
        Result<MasterMap> m = parseMasterMap(text, "m.yaml");
        ASSERT_FALSE(m.ok()) << text;
        EXPECT_EQ(m.error().message.rfind("m.yaml:", 0), 0u) << m.error().message;
        EXPECT_NE(m.error().message.find(says), std::string::npos) << m.error().message;
    };
    refused("pd-out-offset: 100", "pd-out-offset: 20", "overlap");
    refused("port-stride: 1000", "port-stride: 50", "smaller than a port's block");
    refused("port-base: 1000", "port-base: 63000", "beyond address 65535");
    refused("operate: 2", "operate: 1", "must differ");
    refused("ports: 4", "ports: 0", "outside 1..64");
    refused("name: m", "name: m\nbogus: 1", "unknown key 'bogus'");
}

}  // namespace
}  // namespace pnp::iolink
