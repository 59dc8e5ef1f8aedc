#include "sim/ecbpi/iolink_master.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <utility>

namespace pnp::sim::ecbpi {

namespace {

iolink::MasterMap defaultMap() {
    iolink::Result<iolink::MasterMap> map = iolink::loadMasterMap(iolink::defaultMasterMapPath());
    if (!map.ok()) throw std::runtime_error(map.error().message);
    return *map;
}

bool within(std::uint32_t offset, std::uint32_t start, std::size_t count) {
    return offset >= start && offset < start + count;
}

}  // namespace

IoLinkMaster::IoLinkMaster() : IoLinkMaster(defaultMap()) {}

IoLinkMaster::IoLinkMaster(iolink::MasterMap map) : map_(std::move(map)), ports_(map_.ports) {
    for (Port& p : ports_) {
        p.pdIn.assign(map_.pdMaxBytes, 0);
        p.pdOut.assign(map_.pdMaxBytes, 0);
    }
}

IoLinkMaster::~IoLinkMaster() = default;

void IoLinkMaster::attachDevice(std::size_t port, std::unique_ptr<IoLinkDevice> device) {
    if (port < 1 || port > ports_.size()) {
        throw std::out_of_range("IO-Link master has ports 1.." + std::to_string(ports_.size()) +
                                ", not " + std::to_string(port));
    }
    if (device &&
        (device->pdInBytes() > map_.pdMaxBytes || device->pdOutBytes() > map_.pdMaxBytes)) {
        throw std::invalid_argument("the device's process data is larger than the master's " +
                                    std::to_string(map_.pdMaxBytes) + " octets");
    }
    const std::lock_guard lock(mutex_);
    Port& p = ports_[port - 1];
    p.device = std::move(device);
    publish(p);
}

void IoLinkMaster::detach(std::size_t port) { attachDevice(port, nullptr); }

void IoLinkMaster::publish(Port& p) {
    std::fill(p.pdIn.begin(), p.pdIn.end(), 0);
    p.state = p.device ? p.device->portState() : iolink::PortState::kNoDevice;
    // Process data in is valid in OPERATE only; otherwise the master shows zeros.
    if (p.state == iolink::PortState::kOperate) {
        const std::vector<std::uint8_t> in = p.device->processDataIn();
        std::copy_n(in.begin(), std::min(in.size(), p.pdIn.size()), p.pdIn.begin());
    }
}

void IoLinkMaster::step(double dt) {
    const std::lock_guard lock(mutex_);
    for (Port& p : ports_) {
        if (p.device) {
            p.device->setProcessDataOut(
                std::span<const std::uint8_t>(p.pdOut).first(p.device->pdOutBytes()));
            p.device->step(dt);
        }
        publish(p);
    }
}

PortImage IoLinkMaster::port(std::size_t port) const {
    const std::lock_guard lock(mutex_);
    const Port& p = ports_.at(port - 1);
    return PortImage{p.state, p.pdIn, p.pdOut};
}

bool IoLinkMaster::locate(std::uint32_t address, std::size_t& port, std::uint32_t& offset) const {
    if (address < map_.portBase) return false;
    const std::uint32_t rel = address - map_.portBase;
    const std::uint32_t stride = std::max<std::uint32_t>(map_.portStride, 1);
    port = map_.ports > 1 ? rel / stride : 0;
    offset = map_.ports > 1 ? rel % stride : rel;
    return port < ports_.size();
}

bool IoLinkMaster::readOne(std::uint32_t address, std::uint16_t& value) const {
    std::size_t port = 0;
    std::uint32_t offset = 0;
    if (!locate(address, port, offset)) return false;
    const Port& p = ports_[port];
    if (offset == map_.statusOffset) {
        value = map_.statusValue(p.state);
        return true;
    }
    if (map_.identityOffset &&
        within(offset, *map_.identityOffset, iolink::MasterMap::kIdentityRegisters)) {
        value = 0;
        if (p.device && p.state != iolink::PortState::kNoDevice) {
            const std::uint32_t id = p.device->deviceId();
            const std::uint16_t identity[] = {p.device->vendorId(),
                                              static_cast<std::uint16_t>(id >> 16),
                                              static_cast<std::uint16_t>(id & 0xFFFF),
                                              static_cast<std::uint16_t>(p.device->pdInBytes()),
                                              static_cast<std::uint16_t>(p.device->pdOutBytes())};
            value = identity[offset - *map_.identityOffset];
        }
        return true;
    }
    const std::size_t words = map_.pdRegisters();
    auto word = [](const std::vector<std::uint8_t>& octets, std::size_t k) {
        const std::uint8_t hi = octets[2 * k];
        const std::uint8_t lo = 2 * k + 1 < octets.size() ? octets[2 * k + 1] : 0;
        return static_cast<std::uint16_t>((hi << 8) | lo);
    };
    if (within(offset, map_.pdInOffset, words)) {
        value = word(p.pdIn, offset - map_.pdInOffset);
        return true;
    }
    if (within(offset, map_.pdOutOffset, words)) {
        value = word(p.pdOut, offset - map_.pdOutOffset);
        return true;
    }
    return false;
}

modbus::Exception IoLinkMaster::readHolding(std::uint16_t address, std::span<std::uint16_t> out) {
    const std::lock_guard lock(mutex_);
    for (std::size_t i = 0; i < out.size(); ++i) {
        if (!readOne(std::uint32_t{address} + static_cast<std::uint32_t>(i), out[i])) {
            return modbus::Exception::kIllegalDataAddress;
        }
    }
    return modbus::Exception::kNone;
}

modbus::Exception IoLinkMaster::readInput(std::uint16_t address, std::span<std::uint16_t> out) {
    return readHolding(address, out);
}

modbus::Exception IoLinkMaster::writeHolding(std::uint16_t address,
                                             std::span<const std::uint16_t> values) {
    const std::lock_guard lock(mutex_);
    // All or nothing: every register must be in one port's process data out area.
    const std::size_t words = map_.pdRegisters();
    for (std::size_t i = 0; i < values.size(); ++i) {
        std::size_t port = 0;
        std::uint32_t offset = 0;
        if (!locate(std::uint32_t{address} + static_cast<std::uint32_t>(i), port, offset) ||
            !within(offset, map_.pdOutOffset, words)) {
            return modbus::Exception::kIllegalDataAddress;
        }
    }
    for (std::size_t i = 0; i < values.size(); ++i) {
        std::size_t port = 0;
        std::uint32_t offset = 0;
        locate(std::uint32_t{address} + static_cast<std::uint32_t>(i), port, offset);
        std::vector<std::uint8_t>& pd = ports_[port].pdOut;
        const std::size_t k = offset - map_.pdOutOffset;
        pd[2 * k] = static_cast<std::uint8_t>(values[i] >> 8);
        if (2 * k + 1 < pd.size()) pd[2 * k + 1] = static_cast<std::uint8_t>(values[i] & 0xFF);
    }
    return modbus::Exception::kNone;
}

}  // namespace pnp::sim::ecbpi
