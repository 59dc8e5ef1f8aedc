// The analog input of the Kelvin tool changer's ADC board, device side (cell.md §2): the
// changer's state voltage (24 V scale) through the board's 10 kΩ / 1.5 kΩ divider into a
// 12-bit ADC with a 3.3 V reference, served as Modbus input registers so that the ADC
// adapter (`pnp device kelvin-adc`) reads it over Modbus TCP like any remote I/O.
//
// Register map (FC04, input registers; no holding registers):
//   0  pin voltage, mV (0..3300)
//   1  raw ADC count, 12 bit (0..4095 = 0..3.3 V at the pin)
// The 24 V-scale voltage is pin × 11.5 / 1.5. Any other address: exception 0x02.
//
//   sim::kelvin::KelvinAdcInput adc(world, robotIndex);
//   modbus::TcpServer server({.port = 0}, adc);  server.start();
//   // on the stepping thread, after world.step(dt):
//   adc.step(dt);
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <span>

#include "modbus/modbus.hpp"

namespace pnp::world {
class World;
}

namespace pnp::sim::kelvin {

// The board's divider and ADC (facts of the thesis's board; the reference is the ESP32's
// nominal 3.3 V full scale).
inline constexpr double kDividerTop = 10000.0;    // Ω, from the 24 V-scale signal
inline constexpr double kDividerBottom = 1500.0;  // Ω, to ground; the pin is across it
inline constexpr double kDividerRatio = kDividerBottom / (kDividerTop + kDividerBottom);
inline constexpr double kAdcReference = 3.3;  // V at full scale
inline constexpr int kAdcMaxCount = 4095;     // 12 bit

// Input register addresses.
inline constexpr std::uint16_t kRegPinMillivolts = 0;
inline constexpr std::uint16_t kRegRawCount = 1;
inline constexpr std::uint16_t kInputRegisterCount = 2;

// Pin voltage (V) for a 24 V-scale voltage, and back.
inline double pinVoltage(double changerVoltage) { return changerVoltage * kDividerRatio; }
inline double changerVoltageOfPin(double pin) { return pin / kDividerRatio; }
// The ADC count of a pin voltage (clamped to 0..4095).
int adcCount(double pinVolts);

struct KelvinAdcOptions {
    // Deterministic pseudo-noise on the pin voltage, V peak (0: none). ±10 mV at the pin is
    // about ±77 mV on the 24 V scale, far inside the narrowest band (±0.35 V).
    double noise = 0.010;
    std::uint32_t seed = 1;
};

class KelvinAdcInput : public modbus::Registers {
  public:
    // Reads world.robot(robot).changerVoltage in step() (the only access to the world).
    KelvinAdcInput(world::World& world, std::size_t robot, KelvinAdcOptions options = {});
    // Any source of the 24 V-scale voltage (tests, a bench supply model).
    explicit KelvinAdcInput(std::function<double()> voltage, KelvinAdcOptions options = {});

    // On the simulator's stepping thread: samples the voltage into the registers.
    void step(double dt);

    // The registers' current values (any thread).
    std::uint16_t pinMillivolts() const;
    std::uint16_t rawCount() const;

    // modbus::Registers (the transport's thread).
    modbus::Exception readHolding(std::uint16_t address, std::span<std::uint16_t> out) override;
    modbus::Exception readInput(std::uint16_t address, std::span<std::uint16_t> out) override;
    modbus::Exception writeHolding(std::uint16_t address,
                                   std::span<const std::uint16_t> values) override;

  private:
    double nextNoise();  // stepping thread only

    std::function<double()> voltage_;
    KelvinAdcOptions options_;
    std::uint32_t noiseState_;
    mutable std::mutex mutex_;
    std::uint16_t registers_[kInputRegisterCount] = {0, 0};
};

}  // namespace pnp::sim::kelvin
