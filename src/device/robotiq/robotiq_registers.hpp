// The Robotiq 2F-85's Modbus register map (instruction manual §4: "Control"), as values:
// three output registers from 0x03E8 (robot -> gripper, FC16) and three input registers
// from 0x07D0 (gripper -> robot, FC03/FC04). Each register holds two of the manual's bytes,
// the lower-numbered byte in the high half (the manual's example frames: 0x0900 = ACTION
// REQUEST 0x09, byte 1 reserved). No I/O here: pure encoding, unit-testable.
#pragma once

#include <array>
#include <cstdint>
#include <string>

namespace pnp::device::robotiq {

inline constexpr int kOutputAddress = 0x03E8;  // ACTION REQUEST ... FORCE
inline constexpr int kInputAddress = 0x07D0;   // GRIPPER STATUS ... CURRENT
inline constexpr int kRegisters = 3;

// The 2F-85: 85 mm stroke between the finger positions of a Calibration.
inline constexpr double kStroke = 0.085;    // m
inline constexpr double kMinSpeed = 0.020;  // m/s at rSP 0
inline constexpr double kMaxSpeed = 0.150;  // m/s at rSP 255
inline constexpr double kMinForce = 20.0;   // N at rFR 0
inline constexpr double kMaxForce = 235.0;  // N at rFR 255

// Robot output (bytes 0, 3, 4, 5).
struct Request {
    bool activate = false;      // rACT (byte 0 bit 0)
    bool goTo = false;          // rGTO (bit 3)
    bool autoRelease = false;   // rATR (bit 4)
    std::uint8_t position = 0;  // rPR
    std::uint8_t speed = 0;     // rSP
    std::uint8_t force = 0;     // rFR
};
std::array<std::uint16_t, kRegisters> encode(const Request& request);

// gOBJ: what stopped the fingers.
enum class ObjectDetection : std::uint8_t {
    kMoving = 0,          // fingers in motion towards the requested position
    kContactOpening = 1,  // stopped by a contact while opening
    kContactClosing = 2,  // stopped by a contact while closing
    kAtPosition = 3,      // at the requested position: no object
};

// Robot input (bytes 0, 2, 3, 4, 5).
struct GripperStatus {
    bool activated = false;       // gACT
    bool goTo = false;            // gGTO
    std::uint8_t activation = 0;  // gSTA: 0 reset / auto-release, 1 in progress, 3 complete
    ObjectDetection object = ObjectDetection::kMoving;  // gOBJ
    std::uint8_t fault = 0;                             // gFLT (low nibble) and kFLT (high nibble)
    std::uint8_t echo = 0;      // gPR: the position request the gripper took
    std::uint8_t position = 0;  // gPO
    std::uint8_t current = 0;   // gCU, about 10 mA per unit

    bool ready() const { return activated && activation == 3; }
};
GripperStatus decode(const std::array<std::uint16_t, kRegisters>& registers);

// The position bytes (rPR / gPO) at the ends of the fingers' travel; the opening is linear
// between them. The manual gives no mapping: after the activation a 2F-85 with its fingers
// reads gPO 13 fully open (the manual's example frame "... 00 0D 00" after an opening) and
// about 230 with the fingers touching (Robotiq's support: the nut cannot reach 255 with the
// fingers mounted) — the values `pnp sim`'s gripper uses (docs/robotiq-2f85.md). Units
// differ by a few counts: read gPO open and closed after the activation to calibrate one.
struct Calibration {
    std::uint8_t open = 0x0D;    // 85 mm
    std::uint8_t closed = 0xE6;  // 0 mm
};

// Width (m, clamped to the stroke) <-> position byte.
std::uint8_t positionOf(double width, const Calibration& calibration = {});
double widthOf(std::uint8_t position, const Calibration& calibration = {});
// Speed (m/s) and force (N) -> request bytes, clamped to the gripper's range.
std::uint8_t speedByteOf(double speed);
std::uint8_t forceByteOf(double force);

// gFLT's meaning ("" for 0x00).
std::string faultText(std::uint8_t fault);
// A fault that ends a motion (the activation bit missing, or a major fault).
bool stopsMotion(std::uint8_t fault);

}  // namespace pnp::device::robotiq
