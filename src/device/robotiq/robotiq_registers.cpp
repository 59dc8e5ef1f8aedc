#include "device/robotiq/robotiq_registers.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace pnp::device::robotiq {

namespace {

std::uint8_t byteOf(double fraction) {
    return static_cast<std::uint8_t>(std::lround(std::clamp(fraction, 0.0, 1.0) * 255.0));
}

}  // namespace

std::array<std::uint16_t, kRegisters> encode(const Request& r) {
    const std::uint16_t action = static_cast<std::uint16_t>(
        (r.activate ? 0x01 : 0) | (r.goTo ? 0x08 : 0) | (r.autoRelease ? 0x10 : 0));
    return {static_cast<std::uint16_t>(action << 8), r.position,
            static_cast<std::uint16_t>((r.speed << 8) | r.force)};
}

GripperStatus decode(const std::array<std::uint16_t, kRegisters>& reg) {
    GripperStatus s;
    const std::uint8_t status = static_cast<std::uint8_t>(reg[0] >> 8);
    s.activated = (status & 0x01) != 0;
    s.goTo = (status & 0x08) != 0;
    s.activation = static_cast<std::uint8_t>((status >> 4) & 0x03);
    s.object = static_cast<ObjectDetection>((status >> 6) & 0x03);
    s.fault = static_cast<std::uint8_t>(reg[1] >> 8);
    s.echo = static_cast<std::uint8_t>(reg[1] & 0xFF);
    s.position = static_cast<std::uint8_t>(reg[2] >> 8);
    s.current = static_cast<std::uint8_t>(reg[2] & 0xFF);
    return s;
}

std::uint8_t positionOf(double width, const Calibration& c) {
    const double closed = std::clamp(1.0 - width / kStroke, 0.0, 1.0);  // 0 open .. 1 touching
    return static_cast<std::uint8_t>(std::lround(c.open + closed * (c.closed - c.open)));
}

double widthOf(std::uint8_t position, const Calibration& c) {
    const double span = c.closed - c.open;
    return std::clamp(kStroke * (c.closed - position) / span, 0.0, kStroke);
}

std::uint8_t speedByteOf(double speed) {
    return byteOf((speed - kMinSpeed) / (kMaxSpeed - kMinSpeed));
}

std::uint8_t forceByteOf(double force) {
    return byteOf((force - kMinForce) / (kMaxForce - kMinForce));
}

std::string faultText(std::uint8_t fault) {
    const std::uint8_t code = fault & 0x0F;
    std::string text;
    switch (code) {
        case 0x00:
            return "";
        case 0x05:
            text = "action delayed: the activation must complete first";
            break;
        case 0x07:
            text = "the activation bit must be set first";
            break;
        case 0x08:
            text = "maximum operating temperature exceeded";
            break;
        case 0x09:
            text = "no communication for at least 1 s";
            break;
        case 0x0A:
            text = "under minimum operating voltage";
            break;
        case 0x0B:
            text = "automatic release in progress";
            break;
        case 0x0C:
            text = "internal fault";
            break;
        case 0x0D:
            text = "activation fault";
            break;
        case 0x0E:
            text = "overcurrent triggered";
            break;
        case 0x0F:
            text = "automatic release completed";
            break;
        default:
            text = "fault";
            break;
    }
    char code_text[16];
    std::snprintf(code_text, sizeof code_text, " (gFLT 0x%02X)", fault);
    return text + code_text;
}

bool stopsMotion(std::uint8_t fault) {
    const std::uint8_t code = fault & 0x0F;
    return code == 0x07 || code >= 0x0A;
}

}  // namespace pnp::device::robotiq
