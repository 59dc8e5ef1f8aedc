#include "device/ecbpi/ecbpi_hardware.hpp"

#include <modbus.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <thread>
#include <utility>

namespace pnp::device::ecbpi {

namespace {

using Clock = gripper::Clock;
using iolink::Direction;
using iolink::PortState;
using std::chrono::milliseconds;

long long msBetween(Clock::time_point from, Clock::time_point to) {
    return std::chrono::duration_cast<milliseconds>(to - from).count();
}

std::string mbar(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.0f mbar", v);
    return buf;
}

bool isProtocolErrno(int e) {
    return (e > MODBUS_ENOBASE && e <= MODBUS_ENOBASE + MODBUS_EXCEPTION_GATEWAY_TARGET) ||
           e == EMBBADCRC || e == EMBBADDATA || e == EMBBADEXC || e == EMBMDATA || e == EMBBADSLAVE;
}

}  // namespace

struct EcbpiHardware::Context {
    modbus_t* ctx = nullptr;
    ~Context() {
        if (ctx != nullptr) {
            modbus_close(ctx);
            modbus_free(ctx);
        }
    }
};

base::Result<EcbpiOptions, std::string> parseIoLinkAddress(std::string_view text,
                                                           EcbpiOptions options) {
    const std::size_t colon = text.rfind(':');
    if (colon == std::string_view::npos || colon == 0 || colon + 1 == text.size()) {
        return std::string("an IO-Link master address is HOST:PORT, not '") + std::string(text) +
               "'";
    }
    std::string_view host = text.substr(0, colon);
    const std::string_view port = text.substr(colon + 1);
    if (host.size() > 2 && host.front() == '[' && host.back() == ']') {
        host = host.substr(1, host.size() - 2);
    }
    unsigned value = 0;
    const auto [end, ec] = std::from_chars(port.data(), port.data() + port.size(), value);
    if (ec != std::errc() || end != port.data() + port.size() || value < 1 || value > 65535) {
        return "the port in '" + std::string(text) + "' must be 1..65535";
    }
    if (host.empty() || host.size() > 255) return "no host in '" + std::string(text) + "'";
    options.host = std::string(host);
    options.tcpPort = static_cast<std::uint16_t>(value);
    return options;
}

base::Result<std::unique_ptr<EcbpiHardware>, std::string> EcbpiHardware::create(
    EcbpiOptions options) {
    const std::filesystem::path tablePath =
        options.table.empty() ? iolink::modelsDirectory() / "schmalz-ecbpi.yaml" : options.table;
    const std::filesystem::path mapPath =
        options.masterMap.empty() ? iolink::defaultMasterMapPath() : options.masterMap;
    iolink::Result<iolink::DeviceTable> table = iolink::loadDeviceTable(tablePath);
    if (!table.ok()) return table.error().message;
    iolink::Result<iolink::MasterMap> map = iolink::loadMasterMap(mapPath);
    if (!map.ok()) return map.error().message;
    if (options.ioLinkPort < 1 || options.ioLinkPort > map->ports) {
        return "IO-Link port " + std::to_string(options.ioLinkPort) + " is not one of " +
               map->name + "'s ports 1.." + std::to_string(map->ports) + " (" + map->source + ")";
    }
    if (table->pdInBytes > map->pdMaxBytes || table->pdOutBytes > map->pdMaxBytes) {
        return table->source + ": the device's process data is larger than the master's " +
               std::to_string(map->pdMaxBytes) + " octets (" + map->source + ")";
    }
    for (const auto& [name, dir] :
         {std::pair{"part-present", Direction::kIn}, std::pair{"in-control-range", Direction::kIn},
          std::pair{"part-detached", Direction::kIn}, std::pair{"vacuum", Direction::kIn},
          std::pair{"suction", Direction::kOut}, std::pair{"blow-off", Direction::kOut}}) {
        if (table->find(name, dir) == nullptr) {
            return table->source + ": no process data " + (dir == Direction::kIn ? "in" : "out") +
                   " field '" + name + "' (the ECBPi adapter needs it)";
        }
    }
    if (!std::isfinite(options.cupDiameter) || options.cupDiameter <= 0.0 ||
        options.cupDiameter > 1.0) {
        return std::string("the cup diameter must be in (0, 1] m");
    }
    if (options.requestTimeout < milliseconds(1) || options.pollPeriod < milliseconds(1) ||
        options.partTimeout < milliseconds(1) || options.releaseTimeout < milliseconds(1)) {
        return std::string("every timeout and the poll period must be at least 1 ms");
    }
    return std::unique_ptr<EcbpiHardware>(
        new EcbpiHardware(std::move(options), std::move(*table), std::move(*map)));
}

EcbpiHardware::EcbpiHardware(EcbpiOptions options, iolink::DeviceTable table, iolink::MasterMap map)
    : options_(std::move(options)), table_(std::move(table)), map_(std::move(map)) {
    partPresent_ = table_.find("part-present", Direction::kIn);
    inControlRange_ = table_.find("in-control-range", Direction::kIn);
    partDetached_ = table_.find("part-detached", Direction::kIn);
    vacuum_ = table_.find("vacuum", Direction::kIn);
    deviceStatus_ = table_.find("device-status", Direction::kIn);
    suction_ = table_.find("suction", Direction::kOut);
    blowOff_ = table_.find("blow-off", Direction::kOut);
    pdOut_.assign(table_.pdOutBytes, 0);
}

EcbpiHardware::~EcbpiHardware() { disconnect(); }

// --- Transport ---------------------------------------------------------------------------

void EcbpiHardware::closeLocked() {
    ctx_.reset();
    pdOutKnown_ = false;
}

void EcbpiHardware::disconnect() {
    const std::lock_guard lock(mutex_);
    closeLocked();
}

Result<Done> EcbpiHardware::setTimeout(Deadline deadline) {
    const auto left =
        std::chrono::duration_cast<std::chrono::microseconds>(deadline - Clock::now());
    if (left.count() <= 0) {
        return Error{ErrorKind::kTimeout, "the deadline passed before the IO-Link master at " +
                                              options_.host + ":" +
                                              std::to_string(options_.tcpPort) + " answered"};
    }
    const auto us = std::max<long long>(
        1000, std::min<long long>(
                  left.count(),
                  std::chrono::duration_cast<std::chrono::microseconds>(options_.requestTimeout)
                      .count()));
    const auto sec = static_cast<std::uint32_t>(us / 1000000);
    const auto usec = static_cast<std::uint32_t>(us % 1000000);
    modbus_set_response_timeout(ctx_->ctx, sec, usec);
    modbus_set_byte_timeout(ctx_->ctx, sec, usec);
    return Done{};
}

Result<Done> EcbpiHardware::ensureConnected(Deadline deadline) {
    if (ctx_) return Done{};
    const std::string where = options_.host + ":" + std::to_string(options_.tcpPort);
    auto context = std::make_unique<Context>();
    context->ctx =
        modbus_new_tcp_pi(options_.host.c_str(), std::to_string(options_.tcpPort).c_str());
    if (context->ctx == nullptr) {
        return Error{ErrorKind::kNoDevice, "cannot open a Modbus TCP context for " + where + ": " +
                                               modbus_strerror(errno)};
    }
    ctx_ = std::move(context);
    // libmodbus bounds its connect() by the response timeout.
    if (Result<Done> t = setTimeout(deadline); !t.ok()) {
        closeLocked();
        return t.error();
    }
    if (modbus_connect(ctx_->ctx) == -1) {
        const int e = errno;
        closeLocked();
        return Error{Clock::now() >= deadline ? ErrorKind::kTimeout : ErrorKind::kNoDevice,
                     "no IO-Link master at " + where + ": " + modbus_strerror(e)};
    }
    pdOutKnown_ = false;
    return Done{};
}

Error EcbpiHardware::requestFailed(const std::string& what) {
    const int e = errno;
    const std::string where = options_.host + ":" + std::to_string(options_.tcpPort);
    if (isProtocolErrno(e)) {
        // The stream is still in step after an exception; a bad frame may not be.
        if (e <= MODBUS_ENOBASE || e > MODBUS_ENOBASE + MODBUS_EXCEPTION_GATEWAY_TARGET) {
            closeLocked();
        }
        return Error{ErrorKind::kProtocol,
                     "IO-Link master " + where + " refused " + what + ": " + modbus_strerror(e)};
    }
    closeLocked();
    if (e == ETIMEDOUT) {
        return Error{ErrorKind::kNoDevice,
                     "no answer from the IO-Link master at " + where + " to " + what};
    }
    return Error{ErrorKind::kNoDevice,
                 "lost the IO-Link master at " + where + " (" + what + "): " + modbus_strerror(e)};
}

// --- Process data ------------------------------------------------------------------------

Result<EcbpiHardware::Inputs> EcbpiHardware::readInputsLocked(Deadline deadline) {
    if (Result<Done> c = ensureConnected(deadline); !c.ok()) return c.error();
    const std::size_t port = options_.ioLinkPort;
    Inputs in;

    std::uint16_t status = 0;
    if (Result<Done> t = setTimeout(deadline); !t.ok()) return t.error();
    if (modbus_read_registers(ctx_->ctx, map_.address(port, map_.statusOffset), 1, &status) != 1) {
        return requestFailed("reading port " + std::to_string(port) + "'s status");
    }
    in.port = map_.state(status);

    const auto outWords = static_cast<int>((table_.pdOutBytes + 1) / 2);
    if (!pdOutKnown_ && outWords > 0) {
        // The outputs as the master holds them: we change only our bits.
        std::vector<std::uint16_t> regs(static_cast<std::size_t>(outWords));
        if (Result<Done> t = setTimeout(deadline); !t.ok()) return t.error();
        if (modbus_read_registers(ctx_->ctx, map_.address(port, map_.pdOutOffset), outWords,
                                  regs.data()) != outWords) {
            return requestFailed("reading port " + std::to_string(port) + "'s process data out");
        }
        pdOut_ = iolink::fromRegisters(regs, table_.pdOutBytes);
        pdOutKnown_ = true;
    }
    in.suction = iolink::readRaw(pdOut_, *suction_) != 0;
    in.blowOff = iolink::readRaw(pdOut_, *blowOff_) != 0;
    if (in.port != PortState::kOperate) return in;  // process data in is not valid

    const auto inWords = static_cast<int>((table_.pdInBytes + 1) / 2);
    std::vector<std::uint16_t> regs(static_cast<std::size_t>(inWords));
    if (Result<Done> t = setTimeout(deadline); !t.ok()) return t.error();
    if (modbus_read_registers(ctx_->ctx, map_.address(port, map_.pdInOffset), inWords,
                              regs.data()) != inWords) {
        return requestFailed("reading port " + std::to_string(port) + "'s process data in");
    }
    const std::vector<std::uint8_t> pd = iolink::fromRegisters(regs, table_.pdInBytes);
    in.partPresent = iolink::readRaw(pd, *partPresent_) != 0;
    in.inControlRange = iolink::readRaw(pd, *inControlRange_) != 0;
    in.partDetached = iolink::readRaw(pd, *partDetached_) != 0;
    in.vacuum = iolink::toValue(*vacuum_, iolink::readRaw(pd, *vacuum_));
    if (deviceStatus_ != nullptr) {
        in.deviceStatus = static_cast<int>(iolink::readRaw(pd, *deviceStatus_));
    }
    return in;
}

Result<EcbpiHardware::Inputs> EcbpiHardware::readInputs(Deadline deadline) {
    const std::lock_guard lock(mutex_);
    return readInputsLocked(deadline);
}

Result<Done> EcbpiHardware::writeOutputsLocked(bool suction, bool blowOff, Deadline deadline) {
    if (!pdOutKnown_) {
        // Learn the other bits of the outputs first (readInputsLocked reads them).
        if (Result<Inputs> in = readInputsLocked(deadline); !in.ok()) return in.error();
    }
    std::vector<std::uint8_t> pd = pdOut_;
    iolink::writeRaw(pd, *suction_, suction ? 1 : 0);
    iolink::writeRaw(pd, *blowOff_, blowOff ? 1 : 0);
    const std::vector<std::uint16_t> regs = iolink::toRegisters(pd);
    if (regs.empty()) return Done{};
    if (Result<Done> t = setTimeout(deadline); !t.ok()) return t.error();
    const int n = static_cast<int>(regs.size());
    if (modbus_write_registers(ctx_->ctx, map_.address(options_.ioLinkPort, map_.pdOutOffset), n,
                               regs.data()) != n) {
        return requestFailed("writing port " + std::to_string(options_.ioLinkPort) +
                             "'s process data out");
    }
    pdOut_ = std::move(pd);
    return Done{};
}

void EcbpiHardware::outputsOffLocked(bool suction, bool blowOff) {
    // Best effort with a deadline of its own: the caller's may already have passed.
    const Deadline own = Clock::now() + options_.requestTimeout;
    const bool keepSuction = !suction && pdOutKnown_ && iolink::readRaw(pdOut_, *suction_) != 0;
    const bool keepBlowOff = !blowOff && pdOutKnown_ && iolink::readRaw(pdOut_, *blowOff_) != 0;
    (void)writeOutputsLocked(keepSuction, keepBlowOff, own);
}

Result<Done> EcbpiHardware::checkIdentityLocked(Deadline deadline) {
    if (identityChecked_ || !map_.identityOffset) return Done{};
    std::uint16_t id[iolink::MasterMap::kIdentityRegisters] = {};
    if (Result<Done> t = setTimeout(deadline); !t.ok()) return t.error();
    const int n = static_cast<int>(iolink::MasterMap::kIdentityRegisters);
    if (modbus_read_registers(ctx_->ctx, map_.address(options_.ioLinkPort, *map_.identityOffset), n,
                              id) != n) {
        return requestFailed("reading port " + std::to_string(options_.ioLinkPort) +
                             "'s device identity");
    }
    const std::uint32_t deviceId = (std::uint32_t{id[1]} << 16) | id[2];
    const bool vendorWrong = table_.vendorId != 0 && id[0] != table_.vendorId;
    const bool deviceWrong = table_.deviceId != 0 && deviceId != table_.deviceId;
    const bool sizeWrong =
        (id[3] != 0 && id[3] != table_.pdInBytes) || (id[4] != 0 && id[4] != table_.pdOutBytes);
    if (vendorWrong || deviceWrong || sizeWrong) {
        return Error{ErrorKind::kFault, "IO-Link port " + std::to_string(options_.ioLinkPort) +
                                            " holds vendor " + std::to_string(id[0]) + " device " +
                                            std::to_string(deviceId) + " (" +
                                            std::to_string(id[3]) + "/" + std::to_string(id[4]) +
                                            " octets in/out), not the " + table_.vendor + " " +
                                            table_.device + " of " + table_.source};
    }
    identityChecked_ = true;
    return Done{};
}

Error EcbpiHardware::noDevice(const Inputs& in) const {
    return Error{ErrorKind::kNoDevice,
                 "no device operating on IO-Link port " + std::to_string(options_.ioLinkPort) +
                     " of " + options_.host + ":" + std::to_string(options_.tcpPort) + " (" +
                     (in.port == PortState::kPreoperate ? "still starting up" : "no device") + ")"};
}

gripper::Status EcbpiHardware::toStatus(const Inputs& in) const {
    gripper::Status s;
    s.ready = in.port == PortState::kOperate;
    s.holding = in.partPresent;
    s.vacuum = in.vacuum;
    s.moving = (in.suction && !in.blowOff && !in.partPresent) ||
               (in.blowOff && in.vacuum >= options_.releasedVacuum);
    if (in.deviceStatus >= 2) {
        s.fault = in.deviceStatus == 3 ? "device status red: not working properly"
                                       : "device status orange: severe warnings";
    }
    return s;
}

// --- GripperHardware -----------------------------------------------------------------------

Result<Done> EcbpiHardware::connect(Deadline deadline) {
    const std::lock_guard lock(mutex_);
    Result<Inputs> in = readInputsLocked(deadline);
    if (!in.ok()) return in.error();
    if (in->port == PortState::kNoDevice) return noDevice(*in);
    return Done{};
}

Result<Done> EcbpiHardware::activate(Deadline deadline, const std::atomic<bool>& cancel) {
    // Wait for OPERATE (a device just powered spends a moment in PREOPERATE).
    for (;;) {
        {
            const std::lock_guard lock(mutex_);
            Result<Inputs> in = readInputsLocked(deadline);
            if (!in.ok()) return in.error();
            if (in->port == PortState::kNoDevice) return noDevice(*in);
            if (in->port == PortState::kOperate) return checkIdentityLocked(deadline);
            if (Clock::now() + options_.pollPeriod >= deadline) return noDevice(*in);
        }
        if (cancel.load()) return Error{ErrorKind::kCancelled, "activation cancelled"};
        std::this_thread::sleep_for(options_.pollPeriod);
    }
}

Result<gripper::Status> EcbpiHardware::grasp(const gripper::GraspRequest&, Deadline deadline,
                                             const std::atomic<bool>& cancel) {
    const auto start = Clock::now();
    const Deadline giveUp = std::min(deadline, start + options_.partTimeout);
    {
        const std::lock_guard lock(mutex_);
        Result<Inputs> in = readInputsLocked(deadline);
        if (!in.ok()) return in.error();
        if (in->port != PortState::kOperate) return noDevice(*in);
        if (Result<Done> id = checkIdentityLocked(deadline); !id.ok()) return id.error();
        if (Result<Done> w = writeOutputsLocked(true, false, deadline); !w.ok()) return w.error();
    }
    return pollUntil(
        deadline, giveUp, cancel, "grasp cancelled: suction switched off",
        [&](Inputs& in) -> std::optional<Result<gripper::Status>> {
            if (in.partPresent) return toStatus(in);
            if (Clock::now() < giveUp) return std::nullopt;
            outputsOffLocked(true, true);
            return Error{ErrorKind::kRefused,
                         "no part present after " + std::to_string(msBetween(start, Clock::now())) +
                             " ms (vacuum " + mbar(in.vacuum) + "): suction switched off"};
        });
}

Result<gripper::Status> EcbpiHardware::release(Deadline deadline, const std::atomic<bool>& cancel) {
    const auto start = Clock::now();
    const Deadline giveUp = std::min(deadline, start + options_.releaseTimeout);
    {
        const std::lock_guard lock(mutex_);
        Result<Inputs> in = readInputsLocked(deadline);
        if (!in.ok()) return in.error();
        if (in->port != PortState::kOperate) return noDevice(*in);
        // Suction off and a blow-off pulse that lasts until the vacuum is gone.
        if (Result<Done> w = writeOutputsLocked(false, true, deadline); !w.ok()) return w.error();
    }
    return pollUntil(
        deadline, giveUp, cancel, "release cancelled: blow-off switched off",
        [&](Inputs& in) -> std::optional<Result<gripper::Status>> {
            if (!in.partPresent && in.vacuum < options_.releasedVacuum) {
                if (Result<Done> w =
                        writeOutputsLocked(false, false, Clock::now() + options_.requestTimeout);
                    !w.ok()) {
                    return w.error();
                }
                in.blowOff = false;
                in.suction = false;
                return toStatus(in);
            }
            if (Clock::now() < giveUp) return std::nullopt;
            outputsOffLocked(true, true);
            return Error{ErrorKind::kTimeout, "vacuum still " + mbar(in.vacuum) + " after " +
                                                  std::to_string(msBetween(start, Clock::now())) +
                                                  " ms of blow-off"};
        });
}

Result<gripper::Status> EcbpiHardware::pollUntil(Deadline deadline, Deadline giveUp,
                                                 const std::atomic<bool>& cancel,
                                                 const std::string& cancelled,
                                                 const PollStep& step) {
    for (;;) {
        if (cancel.load()) {
            const std::lock_guard lock(mutex_);
            outputsOffLocked(true, true);
            return Error{ErrorKind::kCancelled, cancelled};
        }
        {
            const std::lock_guard lock(mutex_);
            Result<Inputs> in = readInputsLocked(deadline);
            if (!in.ok()) {
                outputsOffLocked(true, true);
                return in.error();
            }
            if (in->port != PortState::kOperate) {
                outputsOffLocked(true, true);  // the master would apply it on power-up
                return noDevice(*in);
            }
            if (auto result = step(*in)) return std::move(*result);
        }
        std::this_thread::sleep_until(std::min(giveUp, Clock::now() + options_.pollPeriod));
    }
}

Result<gripper::Status> EcbpiHardware::move(const gripper::MoveRequest&, Deadline,
                                            const std::atomic<bool>&) {
    return Error{ErrorKind::kRefused, "a vacuum gripper has no jaws to move"};
}

void EcbpiHardware::stop(Deadline deadline) {
    // Halt ends a blow-off pulse; suction stays as it is, so a held part is not dropped (a
    // grasp in progress switches suction off itself when its cancel flag is set).
    std::unique_lock lock(mutex_, std::defer_lock);
    while (!lock.try_lock()) {
        if (Clock::now() >= deadline) return;
        std::this_thread::sleep_for(milliseconds(1));
    }
    if (!ctx_ || !pdOutKnown_ || iolink::readRaw(pdOut_, *blowOff_) == 0) return;
    (void)writeOutputsLocked(iolink::readRaw(pdOut_, *suction_) != 0, false, deadline);
}

Result<gripper::Status> EcbpiHardware::status(Deadline deadline) {
    const std::lock_guard lock(mutex_);
    Result<Inputs> in = readInputsLocked(deadline);
    if (!in.ok()) return in.error();
    if (in->port == PortState::kNoDevice) return noDevice(*in);
    return toStatus(*in);
}

gripper::GripPoint EcbpiHardware::gripPoint() const {
    gripper::GripPoint g;
    g.name = "Vacuum";
    g.kind = gripper::GripKind::kVacuum;
    g.offset = options_.offset;
    g.spanMin = 0.0;
    g.spanMax = options_.cupDiameter;
    return g;
}

std::string EcbpiHardware::manufacturer() const { return table_.vendor; }
std::string EcbpiHardware::modelName() const { return table_.device; }
std::string EcbpiHardware::serialNumber() const {
    return options_.serialNumber.empty() ? "unknown" : options_.serialNumber;
}
std::string EcbpiHardware::endpoint() const {
    return "modbus-tcp://" + options_.host + ":" + std::to_string(options_.tcpPort) +
           "?iolink-port=" + std::to_string(options_.ioLinkPort);
}

}  // namespace pnp::device::ecbpi
