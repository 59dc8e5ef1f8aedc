// The Robotiq 2F-85's register map as RobotiqHardware encodes and decodes it, against the
// register values of the instruction manual's example frames (§4.7, "Modbus RTU example").
#include "device/robotiq/robotiq_registers.hpp"

#include <gtest/gtest.h>

#include <stdexcept>

#include "device/robotiq/robotiq_hardware.hpp"

using namespace pnp::device::robotiq;

namespace {

TEST(RobotiqRegisters, RequestsEncodeAsInTheManualsFrames) {
    // "09 10 03 E8 00 03 06 00 00 00 00 00 00 73 30": clear rACT.
    EXPECT_EQ(encode(Request{}), (std::array<std::uint16_t, 3>{0x0000, 0x0000, 0x0000}));
    // "... 06 01 00 00 00 00 00 72 E1": activation request (rACT = 1).
    EXPECT_EQ(encode(Request{.activate = true}),
              (std::array<std::uint16_t, 3>{0x0100, 0x0000, 0x0000}));
    // "... 06 09 00 00 FF FF FF 42 29": close at full speed and force (rACT, rGTO, rPR 255).
    EXPECT_EQ(encode(Request{
                  .activate = true, .goTo = true, .position = 0xFF, .speed = 0xFF, .force = 0xFF}),
              (std::array<std::uint16_t, 3>{0x0900, 0x00FF, 0xFFFF}));
    // "... 06 09 00 00 00 FF FF 72 19": open at full speed and force.
    EXPECT_EQ(encode(Request{
                  .activate = true, .goTo = true, .position = 0x00, .speed = 0xFF, .force = 0xFF}),
              (std::array<std::uint16_t, 3>{0x0900, 0x0000, 0xFFFF}));
    // rATR is bit 4 of the ACTION REQUEST byte.
    EXPECT_EQ(encode(Request{.activate = true, .autoRelease = true})[0], 0x1100);
}

TEST(RobotiqRegisters, StatusDecodesAsInTheManualsFrames) {
    // "09 04 06 B9 00 00 FF BD 00 ...": grasp completed, an object between the fingers.
    const GripperStatus grasped = decode({0xB900, 0x00FF, 0xBD00});
    EXPECT_TRUE(grasped.activated);
    EXPECT_TRUE(grasped.goTo);
    EXPECT_EQ(grasped.activation, 3);
    EXPECT_TRUE(grasped.ready());
    EXPECT_EQ(grasped.object, ObjectDetection::kContactClosing);
    EXPECT_EQ(grasped.fault, 0);
    EXPECT_EQ(grasped.echo, 0xFF);
    EXPECT_EQ(grasped.position, 0xBD);
    EXPECT_EQ(grasped.current, 0);
    const auto s = toStatus(grasped);
    EXPECT_TRUE(s.holding);
    EXPECT_FALSE(s.moving);
    // gPO 0xBD between 0x0D (85 mm) and 0xE6 (touching): 20.0 mm.
    EXPECT_NEAR(s.width, 0.085 * (0xE6 - 0xBD) / (0xE6 - 0x0D), 1e-12);

    // "09 04 06 F9 00 00 00 0D 00 ...": opened, at the requested position.
    const GripperStatus opened = decode({0xF900, 0x0000, 0x0D00});
    EXPECT_EQ(opened.object, ObjectDetection::kAtPosition);
    EXPECT_EQ(opened.echo, 0x00);
    EXPECT_EQ(opened.position, 0x0D);
    EXPECT_FALSE(toStatus(opened).holding);
    EXPECT_DOUBLE_EQ(toStatus(opened).width, 0.085);  // the manual's "fully open" reading

    // "09 04 06 31 00 00 00 00 00 ...": activation completed, fingers idle (gSTA 3, gACT 1).
    const GripperStatus activated = decode({0x3100, 0x0000, 0x0000});
    EXPECT_TRUE(activated.ready());
    EXPECT_FALSE(activated.goTo);
    // Activation in progress (gSTA 1) is not ready.
    EXPECT_FALSE(decode({0x1100, 0x0000, 0x0000}).ready());
}

TEST(RobotiqRegisters, WidthSpeedAndForceMapLinearly) {
    // The default calibration: 0x0D fully open, 0xE6 fingers touching.
    EXPECT_EQ(positionOf(0.085), 0x0D);
    EXPECT_EQ(positionOf(0.0), 0xE6);
    EXPECT_EQ(positionOf(0.0425), 122);  // 13 + 217 / 2 = 121.5 rounds up
    EXPECT_EQ(positionOf(1.0), 0x0D);    // clamped to the stroke
    EXPECT_EQ(positionOf(-1.0), 0xE6);
    EXPECT_DOUBLE_EQ(widthOf(0x0D), 0.085);
    EXPECT_DOUBLE_EQ(widthOf(0xE6), 0.0);
    EXPECT_NEAR(widthOf(122), 0.0425 - 0.085 / 217 / 2, 1e-12);
    EXPECT_DOUBLE_EQ(widthOf(0), 0.085);  // beyond the ends (gPO 0 before the activation)
    EXPECT_DOUBLE_EQ(widthOf(255), 0.0);
    for (int p = 0x0D; p <= 0xE6; ++p)
        EXPECT_EQ(positionOf(widthOf(static_cast<std::uint8_t>(p))), p);
    // Another unit's ends.
    const Calibration other{.open = 3, .closed = 228};
    EXPECT_EQ(positionOf(0.085, other), 3);
    EXPECT_EQ(positionOf(0.0, other), 228);
    EXPECT_DOUBLE_EQ(widthOf(3, other), 0.085);
    EXPECT_NEAR(widthOf(0x0D, other), 0.085 * (228 - 0x0D) / 225.0, 1e-12);
    EXPECT_EQ(speedByteOf(kMinSpeed), 0);
    EXPECT_EQ(speedByteOf(kMaxSpeed), 255);
    EXPECT_EQ(speedByteOf(1.0), 255);
    EXPECT_EQ(forceByteOf(kMinForce), 0);
    EXPECT_EQ(forceByteOf(0.0), 0);
    EXPECT_EQ(forceByteOf(kMaxForce), 255);
}

TEST(RobotiqRegisters, FaultsAreNamedAndMajorOnesStopMotion) {
    EXPECT_EQ(faultText(0x00), "");
    EXPECT_EQ(faultText(0x07), "the activation bit must be set first (gFLT 0x07)");
    EXPECT_EQ(faultText(0x0E), "overcurrent triggered (gFLT 0x0E)");
    EXPECT_FALSE(stopsMotion(0x00));
    EXPECT_FALSE(stopsMotion(0x05));  // delayed until the activation completes
    EXPECT_FALSE(stopsMotion(0x09));
    EXPECT_TRUE(stopsMotion(0x07));
    EXPECT_TRUE(stopsMotion(0x0A));
    EXPECT_TRUE(stopsMotion(0x0F));
}

TEST(RobotiqHardware, ADeadSerialLineIsNoDevice) {
    RobotiqHardware h({.serialPath = "/nonexistent/tty-for-pnp-tests"});
    auto c = h.connect(pnp::device::gripper::Clock::now() + std::chrono::milliseconds(50));
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.error().kind, pnp::device::gripper::ErrorKind::kNoDevice);
    EXPECT_NE(c.error().message.find("/nonexistent/tty-for-pnp-tests"), std::string::npos);
    auto s = h.status(pnp::device::gripper::Clock::now() + std::chrono::milliseconds(50));
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.error().kind, pnp::device::gripper::ErrorKind::kNoDevice);
    EXPECT_EQ(h.gripPoint().name, "Tip");
    EXPECT_DOUBLE_EQ(h.gripPoint().offset.translation().z(), 0.2028);
    EXPECT_DOUBLE_EQ(h.gripPoint().spanMax, 0.085);
    EXPECT_EQ(h.endpoint(), "modbus-rtu:///nonexistent/tty-for-pnp-tests?slave=9");
}

TEST(RobotiqHardware, AnInvertedCalibrationIsRefused) {
    EXPECT_THROW(
        RobotiqHardware({.serialPath = "/dev/null", .calibration = {.open = 230, .closed = 13}}),
        std::invalid_argument);
    EXPECT_THROW(
        RobotiqHardware({.serialPath = "/dev/null", .calibration = {.open = 13, .closed = 13}}),
        std::invalid_argument);
}

}  // namespace
