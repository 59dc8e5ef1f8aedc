// The simulated Robotiq 2F-85 parallel gripper: the device side of its Modbus RTU interface
// exactly as the "2F-85 & 2F-140 Instruction Manual" (Control, Modbus RTU) maps it, with
// finger motion over the 85 mm stroke and object detection from the world (docs/robotiq-
// 2f85.md). Serve it with modbus::RtuSlave (rtuConfig(): slave 9, 115200 baud) on a
// modbus::PseudoTerminal; call step() on the world's stepping thread.
#pragma once

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <optional>

#include "modbus/modbus.hpp"
#include "world/world.hpp"

namespace pnp::sim::robotiq {

struct Robotiq2f85Config {
    double activationTime = 1.0;  // s from rACT 0 -> 1 until gSTA 3 (the fingers end open)
    // gPO at the ends of the fingers' travel: fully open (the manual's example reads 13 after
    // an opening, "the fingers have reached their software limit") and fingers touching
    // (Robotiq: ≈ 230, the nut cannot reach 255 with the fingers mounted).
    std::uint8_t openPosition = 0x0D;
    std::uint8_t closedPosition = 0xE6;
    // Width change of the opening for rSP 0 and 255 (the 2F-85's 20 .. 150 mm/s), linear.
    double minSpeed = 0.020;  // m/s
    double maxSpeed = 0.150;  // m/s
    // rFR (force) is taken and kept but changes nothing: the world's objects are rigid and
    // the 2F-85 holds without motor current (self-locking), as its reads show (gCU 0).
};

class Robotiq2f85 : public modbus::Registers {
  public:
    static constexpr std::uint8_t kSlave = 9;
    static constexpr std::uint32_t kBaud = 115200;
    // Robot output (requests, FC16 / FC06 / FC23 writes) and robot input (status, FC04 or
    // FC03 reads): 8 registers of 16 bytes each, two bytes per register, high byte first.
    static constexpr std::uint16_t kOutputRegisters = 0x03E8;
    static constexpr std::uint16_t kInputRegisters = 0x07D0;
    static constexpr std::uint16_t kRegisterCount = 8;

    // Fault codes (gFLT) the simulator produces.
    static constexpr std::uint8_t kFaultNone = 0x00;
    static constexpr std::uint8_t kFaultActionDelayed = 0x05;       // activation first
    static constexpr std::uint8_t kFaultActivationBitClear = 0x07;  // rACT before an action
    static constexpr std::uint8_t kFaultAutoReleaseRunning = 0x0B;
    static constexpr std::uint8_t kFaultAutoReleaseDone = 0x0F;  // reset + activate again

    static modbus::RtuSlaveConfig rtuConfig() { return {kSlave, kBaud}; }

    // `tool`: index in world.description().tools (its stroke; 0.085 m if unset). Reads the
    // tool's power once; then the world is touched only by step().
    Robotiq2f85(world::World& world, std::size_t tool, Robotiq2f85Config config = {});

    // Advances the gripper by dt (s) on the world's stepping thread: power, activation,
    // finger motion, contact with an object between the fingers (hold / release).
    void step(double dt);

    // modbus::Registers, called on the serial line's thread.
    modbus::Exception readHolding(std::uint16_t address, std::span<std::uint16_t> out) override;
    modbus::Exception readInput(std::uint16_t address, std::span<std::uint16_t> out) override;
    modbus::Exception writeHolding(std::uint16_t address,
                                   std::span<const std::uint16_t> values) override;
    bool answering() const override { return answering_.load(); }  // powered at the last step

    // The 16 status bytes as the next read would give them (GRIPPER STATUS, reserved, FAULT,
    // gPR, gPO, gCU, reserved...).
    std::array<std::uint8_t, 16> statusBytes() const;
    // The opening between the fingers (m).
    double opening() const;

  private:
    enum class Phase { kReset, kActivating, kActive, kAutoRelease, kAutoReleased };

    // All under mutex_.
    void powerCycle();
    void applyRequest();
    void startMotion();
    void moveFingers(double dt);
    void releaseIfWider();
    double widthAt(double position) const;
    double positionAt(double width) const;
    double countsPerSecond(double metresPerSecond) const;
    bool goRequested() const { return (output_[0] & 0x08) != 0; }
    bool read(std::uint16_t address, std::span<std::uint16_t> out) const;

    world::World& world_;
    const std::size_t tool_;
    const Robotiq2f85Config config_;
    const double stroke_;  // m between the fingers at openPosition

    std::atomic<bool> answering_{false};
    bool powered_ = false;  // as seen at the last step (stepping thread)

    mutable std::mutex mutex_;
    std::array<std::uint8_t, 16> output_{};  // the robot output bytes as written
    Phase phase_ = Phase::kReset;
    bool calibrated_ = false;      // gPO is reported after the first activation
    double activationLeft_ = 0.0;  // s
    double activationFrom_ = 0.0;  // position when the activation began
    double position_ = 0.0;        // counts, the fingers' real position (fractional)
    bool moving_ = false;
    double target_ = 0.0;      // counts
    double speed_ = 0.0;       // counts/s
    std::uint8_t object_ = 0;  // gOBJ while go-to is requested
    std::uint8_t fault_ = 0;
    std::uint8_t current_ = 0;
    std::optional<std::size_t> held_;  // the object the world says we hold
    double heldWidth_ = 0.0;           // m
};

}  // namespace pnp::sim::robotiq
