// RobotiqHardware: libmodbus RTU transactions, each bounded by the caller's deadline, and the
// motions as the manual's examples run them (write the request, poll the status until the
// echo shows the request was taken and the fingers stopped).
#include "device/robotiq/robotiq_hardware.hpp"

#include <modbus.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <thread>

namespace pnp::device::robotiq {

using gripper::Clock;
using gripper::Deadline;
using gripper::Done;
using gripper::Error;
using gripper::ErrorKind;

namespace {

// A transaction without an answer, or with the answer to another request (a late answer to one
// that timed out), is sent again while the caller's deadline leaves time, this many times in
// all: one answer lost or late (a noisy line, a loaded host) is not a dead device and must not
// end a motion whose fingers go on moving. Both transactions are idempotent (a status read; the
// same request registers written again).
constexpr int kAttempts = 3;

// errno after a failed transaction: worth sending again (no answer, or not this one's).
bool worthRetrying(int e) { return e == ETIMEDOUT || e == EMBBADDATA; }

std::string newtons(double f) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%g N", f);
    return buf;
}

std::string millimetres(double m) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.1f mm", m * 1e3);
    return buf;
}

}  // namespace

gripper::Status toStatus(const GripperStatus& s, const Calibration& calibration) {
    gripper::Status out;
    out.ready = s.ready();
    out.moving = s.goTo && s.object == ObjectDetection::kMoving;
    out.holding = s.object == ObjectDetection::kContactClosing ||
                  s.object == ObjectDetection::kContactOpening;
    out.width = widthOf(s.position, calibration);
    out.fault = faultText(s.fault);
    return out;
}

RobotiqHardware::RobotiqHardware(RobotiqConfig config) : config_(std::move(config)) {
    if (config_.calibration.open >= config_.calibration.closed)
        throw std::invalid_argument(
            "Robotiq calibration: the open position (" + std::to_string(config_.calibration.open) +
            ") must be below the closed one (" + std::to_string(config_.calibration.closed) + ")");
}

RobotiqHardware::~RobotiqHardware() { disconnect(); }

std::string RobotiqHardware::endpoint() const {
    return "modbus-rtu://" + config_.serialPath + "?slave=" + std::to_string(config_.slave);
}

gripper::GripPoint RobotiqHardware::gripPoint() const {
    gripper::GripPoint p;
    p.name = "Tip";
    p.kind = gripper::GripKind::kParallel;
    p.offset = config_.tipOffset;
    p.spanMin = 0.0;
    p.spanMax = kStroke;
    return p;
}

Error RobotiqHardware::noAnswer(const char* what) const {
    const int e = errno;
    if (e >= EMBXILFUN && e <= EMBXGTAR)
        return {ErrorKind::kProtocol, std::string(what) + ": slave " +
                                          std::to_string(config_.slave) + " on " +
                                          config_.serialPath + " answered " + modbus_strerror(e)};
    if (e == ETIMEDOUT)
        return {ErrorKind::kNoDevice, std::string(what) + ": no answer from slave " +
                                          std::to_string(config_.slave) + " on " +
                                          config_.serialPath};
    if (e == EMBBADCRC || e == EMBBADDATA || e == EMBBADSLAVE || e == EMBMDATA || e == EMBBADEXC)
        return {ErrorKind::kProtocol, std::string(what) + ": a bad answer on " +
                                          config_.serialPath + " (" + modbus_strerror(e) + ")"};
    return {ErrorKind::kNoDevice,
            std::string(what) + ": " + config_.serialPath + ": " + modbus_strerror(e)};
}

// The response timeout of the next transaction: what is left of the deadline, at most one
// transaction's worth. false: nothing left.
bool RobotiqHardware::limitTransaction(Deadline deadline) {
    const auto left =
        std::chrono::duration_cast<std::chrono::microseconds>(deadline - Clock::now());
    if (left.count() <= 0) return false;
    const auto t = std::min<std::chrono::microseconds>(left, config_.transactionTimeout);
    const auto us = static_cast<std::uint32_t>(std::max<std::int64_t>(t.count(), 1000));
    modbus_set_response_timeout(ctx_, us / 1000000, us % 1000000);
    // Between the bytes of one answer: 115200 baud is ~87 µs per byte.
    const std::uint32_t byteUs = std::min<std::uint32_t>(us, 20000);
    modbus_set_byte_timeout(ctx_, byteUs / 1000000, byteUs % 1000000);
    return true;
}

gripper::Result<Done> RobotiqHardware::connect(Deadline deadline) {
    if (ctx_ == nullptr) {
        modbus_t* ctx = modbus_new_rtu(config_.serialPath.c_str(), config_.baud, 'N', 8, 1);
        if (ctx == nullptr)
            return Error{ErrorKind::kNoDevice,
                         "cannot use " + config_.serialPath + ": " + modbus_strerror(errno)};
        if (modbus_set_slave(ctx, config_.slave) != 0) {
            modbus_free(ctx);
            return Error{ErrorKind::kNoDevice,
                         "bad slave address " + std::to_string(config_.slave) + " (1..247)"};
        }
        if (modbus_connect(ctx) != 0) {
            const int e = errno;
            modbus_free(ctx);
            return Error{ErrorKind::kNoDevice,
                         "cannot open " + config_.serialPath + ": " + modbus_strerror(e)};
        }
        ctx_ = ctx;
    }
    auto s = readStatus(deadline);
    if (!s) return s.error();
    return Done{};
}

void RobotiqHardware::disconnect() {
    if (ctx_ == nullptr) return;
    modbus_close(ctx_);
    modbus_free(ctx_);
    ctx_ = nullptr;
}

gripper::Result<GripperStatus> RobotiqHardware::readStatus(Deadline deadline) {
    if (ctx_ == nullptr) return Error{ErrorKind::kNoDevice, "not connected to " + endpoint()};
    if (!limitTransaction(deadline))
        return Error{ErrorKind::kTimeout, "the deadline passed before the status was read"};
    // A late answer to a transaction that timed out (or to one of an earlier connection to
    // this line) that has arrived since must not be taken for this one's.
    modbus_flush(ctx_);
    std::uint16_t regs[kRegisters] = {};
    for (int attempt = 1;; ++attempt) {
        if (modbus_read_input_registers(ctx_, kInputAddress, kRegisters, regs) == kRegisters)
            return decode({regs[0], regs[1], regs[2]});
        const bool again = worthRetrying(errno);
        Error e = noAnswer("reading the status");
        modbus_flush(ctx_);  // a late answer must not be taken for the next one
        if (!again || attempt >= kAttempts || !limitTransaction(deadline)) return e;
    }
}

gripper::Result<Done> RobotiqHardware::writeRequest(const Request& request, Deadline deadline) {
    if (ctx_ == nullptr) return Error{ErrorKind::kNoDevice, "not connected to " + endpoint()};
    if (!limitTransaction(deadline))
        return Error{ErrorKind::kTimeout, "the deadline passed before the request was written"};
    const auto regs = encode(request);
    modbus_flush(ctx_);  // a late answer that has arrived since (readStatus)
    for (int attempt = 1;; ++attempt) {
        if (modbus_write_registers(ctx_, kOutputAddress, kRegisters, regs.data()) == kRegisters)
            break;
        const bool again = worthRetrying(errno);
        Error e = noAnswer("writing the request");
        modbus_flush(ctx_);
        if (!again || attempt >= kAttempts || !limitTransaction(deadline)) return e;
    }
    last_ = request;
    return Done{};
}

gripper::Result<gripper::Status> RobotiqHardware::status(Deadline deadline) {
    auto s = readStatus(deadline);
    if (!s) return s.error();
    return toStatus(*s, config_.calibration);
}

gripper::Result<Done> RobotiqHardware::activate(Deadline deadline,
                                                const std::atomic<bool>& cancel) {
    auto s = readStatus(deadline);
    if (!s) return s.error();
    if (s->ready()) return Done{};
    if (!s->activated) {
        // The manual's sequence: clear rACT, then set it; the gripper opens and closes once.
        if (auto w = writeRequest(Request{}, deadline); !w) return w.error();
        if (auto w = writeRequest(Request{.activate = true}, deadline); !w) return w.error();
    }
    for (;;) {
        std::this_thread::sleep_for(config_.pollPeriod);
        if (cancel) return Error{ErrorKind::kCancelled, "activation cancelled"};
        s = readStatus(deadline);
        if (!s) {
            if (s.error().kind == ErrorKind::kTimeout) break;
            return s.error();
        }
        if (s->ready()) return Done{};
        if ((s->fault & 0x0F) >= 0x0A)
            return Error{ErrorKind::kFault, "activation: " + faultText(s->fault)};
        if (Clock::now() >= deadline) break;
    }
    return Error{ErrorKind::kTimeout, "the activation did not complete in time"};
}

void RobotiqHardware::stop(Deadline deadline) {
    if (ctx_ == nullptr) return;
    Request r = last_;
    r.activate = true;
    r.goTo = false;  // rGTO 0: the fingers stop where they are
    (void)writeRequest(r, deadline);
}

gripper::Result<GripperStatus> RobotiqHardware::runTo(const Request& request, Deadline deadline,
                                                      const std::atomic<bool>& cancel) {
    if (cancel) return Error{ErrorKind::kCancelled, "cancelled"};
    if (auto w = writeRequest(request, deadline); !w) return w.error();
    // Polls at 200 Hz (the device's rate), on fixed instants: a read takes ~2 ms of the
    // 5 ms at 115200 baud, so sleeping a period after each read would poll at ~135 Hz.
    auto next = Clock::now();
    for (;;) {
        if (cancel) {
            stop(Clock::now() + config_.transactionTimeout);
            return Error{ErrorKind::kCancelled, "cancelled: the fingers were stopped"};
        }
        auto s = readStatus(deadline);
        if (!s) {
            if (s.error().kind != ErrorKind::kTimeout) return s.error();
            break;
        }
        if (stopsMotion(s->fault))
            return Error{ErrorKind::kFault, "the gripper reports " + faultText(s->fault)};
        if (s->echo == request.position && s->object != ObjectDetection::kMoving) return *s;
        if (Clock::now() >= deadline) break;
        next += config_.pollPeriod;
        const auto now = Clock::now();
        if (next < now) next = now;  // a late read is not made up by a burst
        std::this_thread::sleep_until(std::min(next, deadline));
    }
    stop(Clock::now() + config_.transactionTimeout);
    return Error{ErrorKind::kTimeout, "the fingers did not stop before the deadline"};
}

gripper::Result<gripper::Status> RobotiqHardware::grasp(const gripper::GraspRequest& request,
                                                        Deadline deadline,
                                                        const std::atomic<bool>& cancel) {
    if (!std::isfinite(request.force) || request.force < 0.0 || request.force > kMaxForce)
        return Error{ErrorKind::kRefused,
                     "force " + newtons(request.force) + " is outside the 2F-85's 0 .. 235 N"};
    if (!std::isfinite(request.width) || request.width < 0.0 || request.width > kStroke ||
        !std::isfinite(request.speed) || request.speed <= 0.0)
        return Error{ErrorKind::kRefused,
                     "grasp width must be within 0 .. 85 mm and the speed > 0"};
    const Request r{.activate = true,
                    .goTo = true,
                    .position = request.width <= 0.0
                                    ? std::uint8_t{255}
                                    : positionOf(request.width, config_.calibration),
                    .speed = speedByteOf(request.speed),
                    .force = forceByteOf(request.force)};
    auto s = runTo(r, deadline, cancel);
    if (!s) return s.error();
    if (s->object == ObjectDetection::kAtPosition)
        return Error{ErrorKind::kRefused,
                     "no object between the fingers (closed to " +
                         millimetres(widthOf(s->position, config_.calibration)) + ")"};
    return toStatus(*s, config_.calibration);
}

gripper::Result<gripper::Status> RobotiqHardware::release(Deadline deadline,
                                                          const std::atomic<bool>& cancel) {
    const Request r{.activate = true,
                    .goTo = true,
                    .position = 0,
                    .speed = speedByteOf(config_.releaseSpeed),
                    .force = forceByteOf(config_.releaseForce)};
    auto s = runTo(r, deadline, cancel);
    if (!s) return s.error();
    if (s->object == ObjectDetection::kContactOpening)
        return Error{ErrorKind::kRefused,
                     "something stopped the fingers while opening (at " +
                         millimetres(widthOf(s->position, config_.calibration)) + ")"};
    return toStatus(*s, config_.calibration);
}

gripper::Result<gripper::Status> RobotiqHardware::move(const gripper::MoveRequest& request,
                                                       Deadline deadline,
                                                       const std::atomic<bool>& cancel) {
    if (!std::isfinite(request.width) || request.width < 0.0 || request.width > kStroke)
        return Error{ErrorKind::kRefused, "width " + millimetres(request.width) +
                                              " is outside the 2F-85's stroke 0 .. 85 mm"};
    if (!std::isfinite(request.force) || request.force < 0.0 || request.force > kMaxForce)
        return Error{ErrorKind::kRefused,
                     "force " + newtons(request.force) + " is outside the 2F-85's 0 .. 235 N"};
    if (!std::isfinite(request.speed) || request.speed <= 0.0)
        return Error{ErrorKind::kRefused, "the speed must be > 0"};
    const Request r{.activate = true,
                    .goTo = true,
                    .position = positionOf(request.width, config_.calibration),
                    .speed = speedByteOf(request.speed),
                    .force = forceByteOf(request.force)};
    auto s = runTo(r, deadline, cancel);
    if (!s) return s.error();
    if (s->object != ObjectDetection::kAtPosition)
        return Error{ErrorKind::kRefused,
                     "an object stopped the fingers at " +
                         millimetres(widthOf(s->position, config_.calibration)) +
                         " (asked: " + millimetres(request.width) + ")"};
    return toStatus(*s, config_.calibration);
}

}  // namespace pnp::device::robotiq
