#include "sim/ecbpi/ecbpi.hpp"

#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace pnp::sim::ecbpi {

namespace {

using iolink::Direction;

// First-order step towards `target` with time constant `tau`, exact for any dt.
double approach(double value, double target, double tau, double dt) {
    if (tau <= 0.0) return target;
    return target + (value - target) * std::exp(-dt / tau);
}

iolink::DeviceTable tableOrDefault(iolink::DeviceTable table) {
    if (!table.fields.empty()) return table;
    iolink::Result<iolink::DeviceTable> loaded = iolink::loadDeviceTable(Ecbpi::defaultTablePath());
    if (!loaded.ok()) throw std::runtime_error(loaded.error().message);
    return *loaded;
}

}  // namespace

std::filesystem::path Ecbpi::defaultTablePath() {
    return iolink::modelsDirectory() / "schmalz-ecbpi.yaml";
}

Ecbpi::Ecbpi(world::World& world, std::size_t tool, EcbpiConfig config)
    : world_(world), tool_(tool), config_(std::move(config)) {
    config_.table = tableOrDefault(std::move(config_.table));
    const world::ToolDescription& d = world_.description().tools.at(tool_);
    if (d.kind != world::ToolKind::kVacuumGripper) {
        throw std::invalid_argument("tool '" + d.name + "' is not a vacuum gripper");
    }
    const iolink::DeviceTable& t = config_.table;
    auto need = [&](const char* name, Direction direction, bool required) {
        const iolink::Field* f = t.find(name, direction);
        if (f == nullptr && required) {
            throw std::invalid_argument(t.source + ": no process data " +
                                        (direction == Direction::kIn ? "in" : "out") + " field '" +
                                        name + "' (the ECBPi model needs it)");
        }
        return f;
    };
    partPresent_ = need("part-present", Direction::kIn, true);
    inControlRange_ = need("in-control-range", Direction::kIn, true);
    partDetached_ = need("part-detached", Direction::kIn, true);
    vacuum_ = need("vacuum", Direction::kIn, true);
    deviceStatus_ = need("device-status", Direction::kIn, false);
    pumpPower_ = need("pump-power", Direction::kIn, false);
    suction_ = need("suction", Direction::kOut, true);
    blowOff_ = need("blow-off", Direction::kOut, true);
}

void Ecbpi::setProcessDataOut(std::span<const std::uint8_t> pd) {
    if (pd.size() != config_.table.pdOutBytes) return;  // the master sized it; never happens
    requestedSuction_ = iolink::readRaw(pd, *suction_) != 0;
    requestedBlowOff_ = iolink::readRaw(pd, *blowOff_) != 0;
}

void Ecbpi::setOutputs(bool suction, bool blowOff) {
    requestedSuction_ = suction;
    requestedBlowOff_ = blowOff;
}

void Ecbpi::step(double dt) {
    if (!std::isfinite(dt) || dt < 0.0) dt = 0.0;
    const EcbpiConfig& c = config_;

    // Power and the IO-Link start-up: outputs act in OPERATE only.
    state_.powered = world_.toolPowered(tool_);
    if (!state_.powered) {
        sincePowerOn_ = 0.0;
        state_.port = iolink::PortState::kNoDevice;
    } else {
        sincePowerOn_ += dt;
        state_.port = sincePowerOn_ >= c.startupTime ? iolink::PortState::kOperate
                                                     : iolink::PortState::kPreoperate;
    }
    const bool operating = state_.port == iolink::PortState::kOperate;
    const bool wasSucking = state_.suction;
    state_.suction = operating && requestedSuction_;
    state_.blowOff = operating && requestedBlowOff_;
    const bool suctionOn = state_.suction && !state_.blowOff;  // blow-off has priority

    // Someone else took the held object (an operator removed it): it is gone from the cup.
    if (state_.holding && world_.held(tool_) != state_.holding) state_.holding.reset();
    // The cup is sealed on the object it holds, or on a flat top face under it.
    std::optional<std::size_t> sealedOn = state_.holding;
    if (!sealedOn) sealedOn = world_.objectUnderCup(tool_);

    double& p = state_.vacuum;
    if (state_.blowOff) {
        state_.pumpRunning = false;
        p = approach(p, 0.0, c.blowOffTau, dt);
    } else if (suctionOn && sealedOn) {
        // The control function: stop at H1, start again below H1 - h1.
        if (state_.pumpRunning && p >= c.h1) state_.pumpRunning = false;
        if (!state_.pumpRunning && p < c.h1 - c.h1Hysteresis) state_.pumpRunning = true;
        p = state_.pumpRunning ? approach(p, c.maxVacuum, c.evacuationTau, dt)
                               : approach(p, 0.0, c.sealedLeakTau, dt);
        if (state_.pumpRunning && p >= c.h1) state_.pumpRunning = false;
    } else if (suctionOn) {
        state_.pumpRunning = true;
        p = approach(p, c.freeFlowVacuum, c.freeFlowTau, dt);
    } else {
        state_.pumpRunning = false;
        p = approach(p, 0.0, c.ventTau, dt);
    }
    if (p < 0.5 && !suctionOn) p = 0.0;  // below the sensor's resolution

    // A new suction cycle clears "part detached".
    if (state_.suction && !wasSucking) state_.partDetached = false;
    updateFlags(suctionOn);
    updateWorld(sealedOn);

    if (suctionOn && !state_.partPresent) {
        suctionWithoutPart_ += dt;
    } else {
        suctionWithoutPart_ = 0.0;
    }
    state_.deviceStatus = suctionWithoutPart_ > c.warningTime ? 1 : 0;
    if (!operating) {
        state_.partPresent = false;
        state_.inControlRange = false;
        state_.partDetached = false;
        state_.deviceStatus = 0;
    }
}

void Ecbpi::updateFlags(bool suctionOn) {
    const EcbpiConfig& c = config_;
    const double p = state_.vacuum;
    const bool wasPresent = state_.partPresent;
    if (p >= c.h2) state_.partPresent = true;
    if (p < c.h2 - c.h2Hysteresis) state_.partPresent = false;
    if (p >= c.h1) state_.inControlRange = true;
    if (p < c.h1 - c.h1Hysteresis) state_.inControlRange = false;
    if (wasPresent && !state_.partPresent && suctionOn) state_.partDetached = true;
    if (state_.blowOff) state_.partDetached = false;
}

void Ecbpi::updateWorld(std::optional<std::size_t> sealedOn) {
    if (state_.holding && (state_.blowOff || state_.vacuum < config_.holdingVacuum)) {
        world_.release(tool_);
        state_.holding.reset();
    }
    if (!state_.holding && state_.partPresent && sealedOn && !state_.blowOff) {
        if (world_.hold(tool_, *sealedOn)) state_.holding = sealedOn;
    }
}

std::vector<std::uint8_t> Ecbpi::processDataIn() const {
    std::vector<std::uint8_t> pd(config_.table.pdInBytes, 0);
    iolink::writeRaw(pd, *partPresent_, state_.partPresent ? 1 : 0);
    iolink::writeRaw(pd, *inControlRange_, state_.inControlRange ? 1 : 0);
    iolink::writeRaw(pd, *partDetached_, state_.partDetached ? 1 : 0);
    iolink::writeRaw(pd, *vacuum_, iolink::fromValue(*vacuum_, state_.vacuum));
    if (deviceStatus_ != nullptr) {
        iolink::writeRaw(pd, *deviceStatus_, static_cast<std::uint32_t>(state_.deviceStatus));
    }
    if (pumpPower_ != nullptr) {
        iolink::writeRaw(pd, *pumpPower_,
                         iolink::fromValue(*pumpPower_, state_.pumpRunning ? 100.0 : 0.0));
    }
    return pd;
}

}  // namespace pnp::sim::ecbpi
