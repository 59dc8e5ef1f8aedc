// IO-Link process data as tables (what an IODD gives): a device's fields (name, direction,
// bit offset and length, type, unit, scaling) and an IO-Link master's Modbus TCP map (where
// each port's status and process data are). Both sides of a device link read the same files
// (models/iolink/*.yaml, docs/schmalz-ecbpi.md): the simulator packs its state by the table, the
// adapter unpacks it by the same table. No I/O besides reading the files; no Modbus here.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "base/result.hpp"

namespace pnp::iolink {

// Why a table did not load: "FILE:LINE: problem" (no line for whole-file problems).
struct Error {
    std::string message;
    int line = 0;  // 1-based; 0 when the problem is not at one line
};

template <class T>
using Result = base::Result<T, Error>;

enum class Direction { kIn, kOut };  // in: device -> master; out: master -> device
enum class FieldType { kBool, kUInt, kInt };

// One process data item. IODD's bit numbering: the process data of one direction is one
// big-endian bit string; bit offset 0 is the least significant bit of its last octet.
struct Field {
    std::string name;
    Direction direction = Direction::kIn;
    unsigned bitOffset = 0;
    unsigned bitLength = 1;  // 1..32 (bool: 1)
    FieldType type = FieldType::kBool;
    std::string unit;    // for people: "mbar", "%"
    double scale = 1.0;  // value = raw * scale + offset
    double offset = 0.0;
    int line = 0;  // where it is defined in its file
};

struct DeviceTable {
    std::string vendor;
    std::uint16_t vendorId = 0;
    std::string device;
    std::uint32_t deviceId = 0;  // 24 bits; 0 = not checked
    std::size_t pdInBytes = 0;   // 1..32
    std::size_t pdOutBytes = 0;  // 0..32
    std::vector<Field> fields;
    std::string source;  // the file it came from

    // nullptr when the table has no such field in that direction.
    const Field* find(std::string_view name, Direction direction) const;
    std::size_t bytes(Direction direction) const {
        return direction == Direction::kIn ? pdInBytes : pdOutBytes;
    }
};

// What a port's status register says (our simulated master's values; a real master's map
// gives its own mask and values, see MasterMap::status).
enum class PortState { kNoDevice, kPreoperate, kOperate };

// An IO-Link master's Modbus map: one block of registers per port, at
// portBase + (port - 1) * portStride; offsets within the block. Addresses are 0-based.
struct MasterMap {
    std::string name;
    std::size_t ports = 4;
    std::uint16_t portBase = 1000;
    std::uint16_t portStride = 1000;
    std::uint16_t statusOffset = 0;
    std::uint16_t statusMask = 0xFFFF;
    std::uint16_t statusOperate = 2;
    std::uint16_t statusPreoperate = 1;
    // Five registers: vendor id, device id high 8 bits, device id low 16 bits, PD in / out
    // length in octets. None when the master does not publish them there.
    std::optional<std::uint16_t> identityOffset = 1;
    std::uint16_t pdInOffset = 10;
    std::uint16_t pdOutOffset = 100;
    std::size_t pdMaxBytes = 32;
    std::string source;

    static constexpr std::size_t kIdentityRegisters = 5;
    std::size_t pdRegisters() const { return (pdMaxBytes + 1) / 2; }
    // The address of `offset` in port `port`'s block (port 1-based, checked by the loader to
    // fit in 16 bits for every port and area).
    std::uint16_t address(std::size_t port, std::uint16_t offset) const;
    PortState state(std::uint16_t statusRegister) const;
    // The value our simulated master publishes for a state.
    std::uint16_t statusValue(PortState state) const;
};

// Loaders: a file of at most 1 MiB, one YAML document; every key checked (an unknown key is a
// typo), every number bounded, fields may not overlap or reach beyond the process data.
Result<DeviceTable> loadDeviceTable(const std::filesystem::path& file);
Result<DeviceTable> parseDeviceTable(std::string_view text, const std::string& source);
Result<MasterMap> loadMasterMap(const std::filesystem::path& file);
Result<MasterMap> parseMasterMap(std::string_view text, const std::string& source);

// The installed tables (models/iolink of the source tree this was built from).
std::filesystem::path modelsDirectory();
std::filesystem::path defaultMasterMapPath();  // modbus-master.yaml

// Process data images: `pd` is one direction's octets (pd.size() == table.bytes(dir)); the
// field must lie within it (the loader checked that for its own table).
std::uint32_t readRaw(std::span<const std::uint8_t> pd, const Field& field);
void writeRaw(std::span<std::uint8_t> pd, const Field& field, std::uint32_t raw);
// raw -> engineering value (kInt sign-extended from bitLength), and back (rounded, clamped to
// the field's range; bool: value != 0).
double toValue(const Field& field, std::uint32_t raw);
std::uint32_t fromValue(const Field& field, double value);

// Octets <-> Modbus registers: octet 2k in the high byte of register k, octet 2k+1 in its
// low byte (an odd last octet leaves the low byte 0).
std::vector<std::uint16_t> toRegisters(std::span<const std::uint8_t> octets);
std::vector<std::uint8_t> fromRegisters(std::span<const std::uint16_t> registers,
                                        std::size_t octets);

}  // namespace pnp::iolink
