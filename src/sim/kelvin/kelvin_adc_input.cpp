#include "sim/kelvin/kelvin_adc_input.hpp"

#include <algorithm>
#include <cmath>

#include "world/world.hpp"

namespace pnp::sim::kelvin {

int adcCount(double pinVolts) {
    if (!std::isfinite(pinVolts) || pinVolts <= 0.0) return 0;
    const double count = std::round(pinVolts / kAdcReference * kAdcMaxCount);
    return static_cast<int>(std::min(count, static_cast<double>(kAdcMaxCount)));
}

KelvinAdcInput::KelvinAdcInput(world::World& world, std::size_t robot, KelvinAdcOptions options)
    : KelvinAdcInput([&world, robot] { return world.robot(robot).changerVoltage; }, options) {
    (void)world.robot(robot);  // an unknown robot index throws std::out_of_range here, not later
}

KelvinAdcInput::KelvinAdcInput(std::function<double()> voltage, KelvinAdcOptions options)
    : voltage_(std::move(voltage)), options_(options), noiseState_(options.seed | 1u) {}

double KelvinAdcInput::nextNoise() {
    if (options_.noise <= 0.0) return 0.0;
    // xorshift32: deterministic, the same sequence for the same seed.
    noiseState_ ^= noiseState_ << 13;
    noiseState_ ^= noiseState_ >> 17;
    noiseState_ ^= noiseState_ << 5;
    const double unit = static_cast<double>(noiseState_) / 4294967295.0;  // 0..1
    return (2.0 * unit - 1.0) * options_.noise;
}

void KelvinAdcInput::step(double /*dt*/) {
    double volts = voltage_ ? voltage_() : 0.0;
    if (!std::isfinite(volts)) volts = 0.0;
    // The pin cannot go below ground or above the reference (the ADC saturates).
    const double pin = std::clamp(pinVoltage(volts) + nextNoise(), 0.0, kAdcReference);
    const auto mv = static_cast<std::uint16_t>(std::lround(pin * 1000.0));
    const auto count = static_cast<std::uint16_t>(adcCount(pin));
    std::lock_guard l(mutex_);
    registers_[kRegPinMillivolts] = mv;
    registers_[kRegRawCount] = count;
}

std::uint16_t KelvinAdcInput::pinMillivolts() const {
    std::lock_guard l(mutex_);
    return registers_[kRegPinMillivolts];
}

std::uint16_t KelvinAdcInput::rawCount() const {
    std::lock_guard l(mutex_);
    return registers_[kRegRawCount];
}

modbus::Exception KelvinAdcInput::readHolding(std::uint16_t, std::span<std::uint16_t>) {
    return modbus::Exception::kIllegalDataAddress;  // the board has no holding registers
}

modbus::Exception KelvinAdcInput::readInput(std::uint16_t address, std::span<std::uint16_t> out) {
    if (out.empty() || address >= kInputRegisterCount ||
        out.size() > static_cast<std::size_t>(kInputRegisterCount - address))
        return modbus::Exception::kIllegalDataAddress;
    std::lock_guard l(mutex_);
    std::copy_n(registers_ + address, out.size(), out.begin());
    return modbus::Exception::kNone;
}

modbus::Exception KelvinAdcInput::writeHolding(std::uint16_t, std::span<const std::uint16_t>) {
    return modbus::Exception::kIllegalDataAddress;
}

}  // namespace pnp::sim::kelvin
