#include "sim/robotiq/robotiq_2f85.hpp"

#include <algorithm>
#include <cmath>

namespace pnp::sim::robotiq {

using modbus::Exception;

namespace {

// ACTION REQUEST (output byte 0) bits.
constexpr std::uint8_t kActivate = 0x01;        // rACT
constexpr std::uint8_t kAutoRelease = 0x10;     // rATR
constexpr std::uint8_t kReleaseOpening = 0x20;  // rARD: 1 opens, 0 closes

// The motor current while the fingers move, in gCU units (10 mA): the manual's example reads
// at full speed (0x0A closing, 0x10 opening), halved at the slowest speed. 0 at rest: the
// 2F-85's drive is self-locking and holds a grip without current.
constexpr double kClosingCurrent = 10.0;
constexpr double kOpeningCurrent = 16.0;

bool inBlock(std::uint16_t base, std::uint16_t address, std::size_t count) {
    return address >= base &&
           std::size_t{address} + count <= std::size_t{base} + Robotiq2f85::kRegisterCount;
}

}  // namespace

Robotiq2f85::Robotiq2f85(world::World& world, std::size_t tool, Robotiq2f85Config config)
    : world_(world),
      tool_(tool),
      config_(config),
      stroke_(world.description().tools.at(tool).stroke > 0.0
                  ? world.description().tools.at(tool).stroke
                  : 0.085) {
    position_ = config_.openPosition;
    powered_ = world_.toolPowered(tool_);
    answering_ = powered_;
}

// --- Registers (serial thread)

bool Robotiq2f85::read(std::uint16_t address, std::span<std::uint16_t> out) const {
    std::array<std::uint8_t, 16> bytes{};
    if (inBlock(kInputRegisters, address, out.size())) {
        bytes = statusBytes();
        address = static_cast<std::uint16_t>(address - kInputRegisters);
    } else if (inBlock(kOutputRegisters, address, out.size())) {
        std::lock_guard lock(mutex_);
        bytes = output_;
        address = static_cast<std::uint16_t>(address - kOutputRegisters);
    } else {
        return false;
    }
    for (std::size_t i = 0; i < out.size(); ++i) {
        const std::size_t at = 2 * (address + i);
        out[i] = static_cast<std::uint16_t>(bytes[at] << 8 | bytes[at + 1]);
    }
    return true;
}

Exception Robotiq2f85::readHolding(std::uint16_t address, std::span<std::uint16_t> out) {
    return read(address, out) ? Exception::kNone : Exception::kIllegalDataAddress;
}

Exception Robotiq2f85::readInput(std::uint16_t address, std::span<std::uint16_t> out) {
    return read(address, out) ? Exception::kNone : Exception::kIllegalDataAddress;
}

Exception Robotiq2f85::writeHolding(std::uint16_t address, std::span<const std::uint16_t> values) {
    if (!inBlock(kOutputRegisters, address, values.size())) return Exception::kIllegalDataAddress;
    std::lock_guard lock(mutex_);
    const std::size_t first = 2u * (address - kOutputRegisters);
    for (std::size_t i = 0; i < values.size(); ++i) {
        output_[first + 2 * i] = static_cast<std::uint8_t>(values[i] >> 8);
        output_[first + 2 * i + 1] = static_cast<std::uint8_t>(values[i] & 0xFF);
    }
    applyRequest();
    return Exception::kNone;
}

std::array<std::uint8_t, 16> Robotiq2f85::statusBytes() const {
    std::lock_guard lock(mutex_);
    std::array<std::uint8_t, 16> s{};
    std::uint8_t gSTA = 0;
    if (phase_ == Phase::kActivating) gSTA = 1;
    if (phase_ == Phase::kActive) gSTA = 3;
    const bool active = phase_ != Phase::kReset;
    const bool go = phase_ == Phase::kActive && goRequested();
    s[0] = static_cast<std::uint8_t>((active ? 0x01 : 0) | (go ? 0x08 : 0) | gSTA << 4 |
                                     (go ? object_ : 0) << 6);
    s[2] = fault_;
    s[3] = active ? output_[3] : 0;
    s[4] = calibrated_ ? static_cast<std::uint8_t>(std::lround(position_)) : 0;
    s[5] = current_;
    return s;
}

double Robotiq2f85::opening() const {
    std::lock_guard lock(mutex_);
    return widthAt(position_);
}

// --- The device's logic (under mutex_)

void Robotiq2f85::applyRequest() {
    const std::uint8_t action = output_[0];
    if ((action & kActivate) == 0) {
        // Reset: stops, forgets the activation; asking for an action meanwhile is a fault.
        phase_ = Phase::kReset;
        moving_ = false;
        object_ = 0;
        current_ = 0;
        fault_ = (action & (0x08 | kAutoRelease)) ? kFaultActivationBitClear : kFaultNone;
        return;
    }
    if (phase_ == Phase::kReset) {
        phase_ = Phase::kActivating;
        activationLeft_ = config_.activationTime;
        activationFrom_ = position_;
        moving_ = false;
        fault_ = kFaultNone;
    }
    if (phase_ == Phase::kAutoReleased) return;  // only a reset and a new activation help
    if ((action & kAutoRelease) != 0 && phase_ != Phase::kAutoRelease) {
        // Automatic release overrides everything but rACT: slow, to the end of the travel.
        phase_ = Phase::kAutoRelease;
        target_ = (action & kReleaseOpening) ? config_.openPosition : config_.closedPosition;
        speed_ = countsPerSecond(config_.minSpeed);
        moving_ = true;
        object_ = 0;
        fault_ = kFaultAutoReleaseRunning;
        return;
    }
    if (phase_ == Phase::kAutoRelease) return;
    if (phase_ == Phase::kActivating) {
        fault_ = goRequested() ? kFaultActionDelayed : kFaultNone;  // done after activation
        return;
    }
    fault_ = kFaultNone;
    if (goRequested()) {
        startMotion();
    } else {
        moving_ = false;
        current_ = 0;
        object_ = 0;
    }
}

void Robotiq2f85::startMotion() {
    target_ = std::clamp<double>(output_[3], config_.openPosition, config_.closedPosition);
    speed_ = countsPerSecond(config_.minSpeed +
                             (config_.maxSpeed - config_.minSpeed) * output_[4] / 255.0);
    moving_ = true;
    object_ = 0;  // fingers in motion towards the requested position
}

void Robotiq2f85::powerCycle() {
    output_.fill(0);
    phase_ = Phase::kReset;
    calibrated_ = false;
    moving_ = false;
    object_ = 0;
    fault_ = kFaultNone;
    current_ = 0;
}

double Robotiq2f85::widthAt(double position) const {
    const double span = config_.closedPosition - config_.openPosition;
    return std::clamp(stroke_ * (config_.closedPosition - position) / span, 0.0, stroke_);
}

double Robotiq2f85::positionAt(double width) const {
    const double span = config_.closedPosition - config_.openPosition;
    return std::clamp(config_.closedPosition - width / stroke_ * span,
                      static_cast<double>(config_.openPosition),
                      static_cast<double>(config_.closedPosition));
}

double Robotiq2f85::countsPerSecond(double metresPerSecond) const {
    return metresPerSecond * (config_.closedPosition - config_.openPosition) / stroke_;
}

void Robotiq2f85::releaseIfWider() {
    if (held_ && widthAt(position_) > heldWidth_) {
        world_.release(tool_);
        held_.reset();
    }
}

void Robotiq2f85::step(double dt) {
    const bool powered = world_.toolPowered(tool_);
    std::lock_guard lock(mutex_);
    // Whatever this step did, the world learns where the finger tips are (its contact).
    struct TellOpening {
        Robotiq2f85& g;
        ~TellOpening() { g.world_.setFingerOpening(g.tool_, g.widthAt(g.position_)); }
    } tell{*this};
    if (!powered) {
        if (powered_) {
            // Power gone: a power cycle for the registers; what the fingers held is let go.
            powerCycle();
            if (held_) world_.release(tool_);
            held_.reset();
        }
        powered_ = false;
        answering_ = false;
        return;
    }
    if (!powered_) powerCycle();  // a fresh start: everything 0, activation needed
    powered_ = true;
    answering_ = true;
    if (!std::isfinite(dt) || dt <= 0.0) return;

    // Someone took the object out of our fingers: closing goes on to the requested position.
    if (held_ && world_.held(tool_) != held_) {
        held_.reset();
        if (phase_ == Phase::kActive && object_ == 2 && goRequested()) {
            moving_ = true;
            object_ = 0;
        }
    }

    if (phase_ == Phase::kActivating) {
        // The fingers travel to fully open during the activation (its calibration stroke).
        activationLeft_ -= dt;
        const double done =
            config_.activationTime > 0.0
                ? std::clamp(1.0 - activationLeft_ / config_.activationTime, 0.0, 1.0)
                : 1.0;
        const double before = position_;
        position_ = activationFrom_ + (config_.openPosition - activationFrom_) * done;
        current_ = position_ != before ? static_cast<std::uint8_t>(kOpeningCurrent) : 0;
        releaseIfWider();
        if (activationLeft_ <= 0.0) {
            phase_ = Phase::kActive;
            calibrated_ = true;
            position_ = config_.openPosition;
            current_ = 0;
            fault_ = kFaultNone;
            if (goRequested()) startMotion();  // the delayed action
        }
        return;
    }
    if (moving_) moveFingers(dt);
}

void Robotiq2f85::moveFingers(double dt) {
    const bool closing = target_ > position_;
    const double step = speed_ * dt;
    const double next =
        closing ? std::min(target_, position_ + step) : std::max(target_, position_ - step);
    const double speedFraction = std::clamp(
        (speed_ / countsPerSecond(1.0) - config_.minSpeed) / (config_.maxSpeed - config_.minSpeed),
        0.0, 1.0);
    const double base = closing ? kClosingCurrent : kOpeningCurrent;
    current_ = static_cast<std::uint8_t>(std::lround(base * (0.5 + 0.5 * speedFraction)));
    if (closing) {
        // An object narrower than the opening, between the fingers: they stop on it.
        const auto contact = world_.objectBetweenFingers(tool_, widthAt(position_));
        if (contact && widthAt(next) <= contact->width) {
            position_ = std::max(position_, positionAt(contact->width));
            moving_ = false;
            current_ = 0;
            if (phase_ == Phase::kActive) object_ = 2;  // stopped on contact while closing
            if (held_ != contact->object && world_.hold(tool_, contact->object)) {
                held_ = contact->object;
                heldWidth_ = contact->width;
            }
            return;
        }
    }
    position_ = next;
    releaseIfWider();
    if (position_ == target_) {
        moving_ = false;
        current_ = 0;
        if (phase_ == Phase::kActive) object_ = 3;  // at the requested position
        if (phase_ == Phase::kAutoRelease) {
            phase_ = Phase::kAutoReleased;
            fault_ = kFaultAutoReleaseDone;
        }
    }
}

}  // namespace pnp::sim::robotiq
