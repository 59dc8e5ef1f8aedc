#include "sim/ur/ur_controller.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "rtde/catalogue.hpp"

namespace pnp::sim::ur {

namespace {

using world::Joints;
constexpr std::size_t kAxes = static_cast<std::size_t>(kinematics::kAxes);
// The jitter buffer (latch()): targets waiting before the first is followed (2 steps = 4 ms
// at 500 Hz of latency, and as much lateness of the adapter absorbed), and at most.
constexpr std::size_t kBufferDepth = 2;
constexpr std::size_t kMaxBuffered = 6;
// The adapter writes the timestamp of the state each target answers here (see latch()).
constexpr std::string_view kStampRegister = "input_double_register_6";
// Steps without a new target that a stream is carried across (see servo()).
constexpr int kBridgeSteps = 2;

// UR codes as RTDE reports them.
constexpr std::int32_t kRobotModeRunning = 7;
constexpr std::int32_t kSafetyNormal = 1;
constexpr std::int32_t kSafetyProtectiveStop = 3;
constexpr std::uint32_t kRuntimePlaying = 2;
constexpr std::int32_t kJointRunning = 253;
constexpr std::uint32_t kStatusPowerOnProgramRunning = 0b11;  // bits 0, 1
constexpr std::uint32_t kSafetyBitNormal = 1u << 0;
constexpr std::uint32_t kSafetyBitProtectiveStop = 1u << 2;

const std::string kModeRegister = "input_int_register_0";

rtde::Vector6d toVector(const Joints& j) {
    rtde::Vector6d v{};
    std::copy(j.begin(), j.end(), v.begin());
    return v;
}

// UR pose convention: position and rotation vector (axis * angle).
rtde::Vector6d toUrPose(const Eigen::Isometry3d& pose) {
    const Eigen::AngleAxisd aa(pose.linear());
    const Eigen::Vector3d r = aa.angle() * aa.axis();
    const Eigen::Vector3d p = pose.translation();
    return {p.x(), p.y(), p.z(), r.x(), r.y(), r.z()};
}

bool isOutputRegister(std::string_view name) {
    return name.starts_with("output_int_register_") ||
           name.starts_with("output_double_register_") || name.starts_with("output_bit_register");
}

}  // namespace

UrController::UrController(world::World& world, UrControllerConfig config)
    : world_(world), config_(config) {
    if (config_.robot >= world_.robotCount()) {
        throw std::out_of_range("UrController: the world has no robot " +
                                std::to_string(config_.robot));
    }
    if (!std::isfinite(config_.watchdogTimeout) || config_.watchdogTimeout <= 0.0) {
        throw std::invalid_argument("UrController: watchdogTimeout must be finite and > 0");
    }
    for (double limit :
         {config_.maxVelocity, config_.maxAcceleration, config_.protectiveStopForce}) {
        if (!std::isfinite(limit) || limit < 0.0) {
            throw std::invalid_argument("UrController: limits must be finite and >= 0");
        }
    }
    const auto& limits = world_.description().robots[config_.robot].model.limits;
    for (std::size_t j = 0; j < kAxes; ++j) {
        maxVelocity_[j] = config_.maxVelocity > 0.0 ? config_.maxVelocity : limits[j].maxVelocity;
        maxAcceleration_[j] = config_.maxAcceleration > 0.0 ? config_.maxAcceleration
                                                            : 4.0 * limits[j].maxAcceleration;
    }
    for (const rtde::Variable& v : rtde::catalogue()) {
        auto& map = v.kind == rtde::VariableKind::output ? outputs_ : inputs_;
        map.emplace(v.name, rtde::defaultValue(v.type));
    }
    // A UR that is powered on and runs the servo program; the TCP offset stays zero (the
    // controller does not know our tools: a real UR's TCP is configured on the pendant).
    outputs_["robot_mode"] = kRobotModeRunning;
    outputs_["runtime_state"] = kRuntimePlaying;
    outputs_["joint_mode"] = rtde::Vector6Int32{kJointRunning, kJointRunning, kJointRunning,
                                                kJointRunning, kJointRunning, kJointRunning};
    outputs_["robot_status_bits"] = kStatusPowerOnProgramRunning;
    outputs_["speed_scaling"] = 1.0;
    outputs_["target_speed_fraction"] = 1.0;
    target_ = world_.robot(config_.robot).q;
    publish();
}

rtde::Value UrController::read(std::string_view name) {
    std::lock_guard lock(mutex_);
    if (auto it = outputs_.find(name); it != outputs_.end()) return it->second;
    if (auto it = inputs_.find(name); it != inputs_.end()) return it->second;
    return rtde::Value{};  // unknown: the server sends the recipe type's zero
}

void UrController::write(std::string_view name, const rtde::Value& value) {
    std::lock_guard lock(mutex_);
    auto it = inputs_.find(name);
    // The server only writes names of an accepted input recipe, with their types; anything
    // else is ignored rather than trusted.
    if (it == inputs_.end() || rtde::typeOf(value) != rtde::typeOf(it->second)) return;
    it->second = value;
    ++inputWrites_;
    if (name == kModeRegister && std::get<std::int32_t>(value) == 0) zeroSeen_ = true;
    if (name == kStampRegister) stampWritten_ = true;
}

bool UrController::setOutputRegister(std::string_view name, const rtde::Value& value) {
    if (!isOutputRegister(name)) return false;
    std::lock_guard lock(mutex_);
    auto it = outputs_.find(name);
    if (it == outputs_.end() || rtde::typeOf(value) != rtde::typeOf(it->second)) return false;
    it->second = value;
    return true;
}

std::optional<rtde::Value> UrController::input(std::string_view name) const {
    std::lock_guard lock(mutex_);
    if (auto it = inputs_.find(name); it != inputs_.end()) return it->second;
    return std::nullopt;
}

void UrController::endInputPackage() {
    std::lock_guard lock(mutex_);
    packaged_ = true;
    Package p;
    for (std::size_t j = 0; j < kAxes; ++j)
        p.targets[j] =
            std::get<double>(inputs_.find("input_double_register_" + std::to_string(j))->second);
    if (std::exchange(stampWritten_, false) && dt_ > 0.0) {
        const double stamp = std::get<double>(inputs_.find(kStampRegister)->second);
        if (std::isfinite(stamp) && stamp >= 0.0 && stamp / dt_ < 1e15)
            p.answers = static_cast<std::uint64_t>(std::llround(stamp / dt_));
    }
    packages_.push_back(p);
    // Bounded latency: a client that sends faster than we step loses its oldest targets.
    while (packages_.size() > kMaxBuffered) packages_.pop_front();
}

UrController::Inputs UrController::latch(double dt) {
    std::lock_guard lock(mutex_);
    Inputs in;
    in.mode = std::get<std::int32_t>(inputs_.find(kModeRegister)->second);
    for (std::size_t j = 0; j < kAxes; ++j) {
        in.targets[j] =
            std::get<double>(inputs_.find("input_double_register_" + std::to_string(j))->second);
    }
    in.writes = inputWrites_;
    in.zeroSeen = std::exchange(zeroSeen_, false);
    in.target = in.writes != lastWrites_;
    if (packaged_) {
        // A jitter buffer, as a servo interface needs on a machine without real-time
        // scheduling: the adapter answers each published state within the cycle most of the
        // time, but now and then one answer comes a step late and the next two in one step.
        // Taking exactly one target per step, kBufferDepth steps behind, follows every
        // target of the stream in order, so the robot stays on the streamed path.
        if (std::exchange(flush_, false)) {
            packages_.clear();
            primed_ = false;
        }
        dt_ = dt;
        if (!packages_.empty() && packages_.front().answers) {
            // Stamped targets: the answer to the state after step n is followed in step
            // n + kBufferDepth, whenever it arrived before; a later one is dropped (the robot
            // coasted through that step), so a late answer never shifts the stream.
            const std::uint64_t done = world_.steps();  // this step is done + 1
            const std::uint64_t due = done + 1 >= kBufferDepth ? done + 1 - kBufferDepth : 0;
            while (!packages_.empty() && packages_.front().answers &&
                   *packages_.front().answers < due) {
                packages_.pop_front();
                ++lateTargets_;
            }
            in.target = !packages_.empty() && packages_.front().answers &&
                        *packages_.front().answers == due;
        } else {
            // Unstamped: in order of arrival, kBufferDepth behind.
            if (!primed_ && packages_.size() >= kBufferDepth) primed_ = true;
            in.target = primed_ && !packages_.empty();
            if (!in.target) primed_ = false;  // ran dry: fill up again before following on
        }
        if (in.target) {
            in.targets = packages_.front().targets;
            packages_.pop_front();
        }
    }
    return in;
}

void UrController::step(double dt) {
    // No time passes for a bad dt: nothing moves (and the watchdog does not count it).
    if (!std::isfinite(dt) || dt <= 0.0) return;
    const Inputs in = latch(dt);
    servo(in, dt);
    std::lock_guard lock(mutex_);
    followingShared_ = following_;
    trippedShared_ = tripped_;
    protectiveStopShared_ = protective_;
    rejectedShared_ = rejected_;
    starvedShared_ = starved_;
    outputs_["target_qdd"] = toVector(commandAcceleration_);
}

void UrController::logProtectiveStop(const world::RobotState& robot) const {
    const Eigen::Vector3d& f = robot.tcpForce;
    const Eigen::Vector3d p = robot.tcp.translation();
    char text[256];
    std::snprintf(text, sizeof text,
                  ": protective stop: TCP force %.1f N (%.1f, %.1f, %.1f) > %.1f N at TCP "
                  "(%.4f, %.4f, %.4f) m, tool %s",
                  f.norm(), f.x(), f.y(), f.z(), config_.protectiveStopForce, p.x(), p.y(), p.z(),
                  robot.tool ? robot.tool->c_str() : "none");
    config_.log(world_.description().robots[config_.robot].name + text);
}

void UrController::servo(const Inputs& in, double dt) {
    const world::RobotState& robot = world_.robot(config_.robot);
    Joints q = robot.q;  // the world is the truth; the controller moves it
    Joints v = robot.qd;

    // Watchdog: counts steps (simulated time) without a new input value.
    if (in.writes != lastWrites_) {
        lastWrites_ = in.writes;
        silentSteps_ = 0;
    } else if (silentSteps_ < std::numeric_limits<std::uint64_t>::max()) {
        ++silentSteps_;
    }
    const bool fresh = silentSteps_ == 0;
    const auto watchdogSteps =
        static_cast<std::uint64_t>(std::max(1.0, std::ceil(config_.watchdogTimeout / dt - 1e-9)));
    const bool on = in.mode == 1;
    const bool forceHigh = robot.tcpForce.norm() > config_.protectiveStopForce;

    if (armed_ && !tripped_ && silentSteps_ >= watchdogSteps) {
        tripped_ = true;
        rearmZero_ = false;
    }
    if (!protective_ && forceHigh) {
        protective_ = true;
        rearmZero_ = false;
        if (config_.log) logProtectiveStop(robot);
    }
    if (tripped_ || protective_) {
        // Re-arm: the register seen 0 after the stop, then 1 with fresh inputs (and, after
        // a protective stop, the force back below the limit).
        if (in.zeroSeen || !on) rearmZero_ = true;
        if (rearmZero_ && on && fresh && !forceHigh) {
            if (protective_ && config_.log)
                config_.log(world_.description().robots[config_.robot].name +
                            ": protective stop cleared (re-armed)");
            tripped_ = false;
            protective_ = false;
            rearmZero_ = false;
        }
    }
    if (on && !tripped_) armed_ = true;

    const bool follow = on && !tripped_ && !protective_;
    const bool entering = follow && !following_;
    if (entering) target_ = q;  // hold where it is until a valid target comes
    following_ = follow;
    if (!following_) {
        std::lock_guard lock(mutex_);
        flush_ = true;  // targets sent while not following are not followed later
    }
    if (following_ && (in.target || entering)) {
        const auto& limits = world_.description().robots[config_.robot].model.limits;
        bool valid = true;
        for (std::size_t j = 0; j < kAxes; ++j) {
            const double t = in.targets[j];
            if (!std::isfinite(t) || t < limits[j].minPosition || t > limits[j].maxPosition) {
                valid = false;
            }
        }
        if (valid) {
            target_ = in.targets;
        } else {
            ++rejected_;  // the whole vector; the old target stays
        }
    }

    // A stream that skipped a step (the adapter was late beyond what the jitter buffer
    // holds): the last motion of a robot that was on its target is carried on for up to
    // kBridgeSteps steps (the target moved on by the speed), so the robot neither brakes nor
    // leaves the streamed path; a stream that really stopped is then braked to.
    if (following_ && tracking_ && !in.target && !entering) ++starved_;
    if (following_ && tracking_ && !in.target && !entering && bridged_ < kBridgeSteps) {
        const auto& limits = world_.description().robots[config_.robot].model.limits;
        for (std::size_t j = 0; j < kAxes; ++j)
            target_[j] =
                std::clamp(target_[j] + v[j] * dt, limits[j].minPosition, limits[j].maxPosition);
        ++bridged_;
    } else if (in.target) {
        bridged_ = 0;
    }

    // Tracking a streamed target (servoj's normal case): one step along the straight joint-
    // space segment to the target, shortened by one common factor until every joint keeps its
    // speed and acceleration limits. A common factor keeps the joints in step, so the robot
    // stays on the streamed path (a per-joint law would lag each joint differently and bend a
    // Cartesian line). Where no common factor exists (a jump, a stream that stopped dead),
    // the per-joint law below brakes each joint without overshoot.

    // A fixed target (not moved since the last step) must also be reached at rest: then the
    // speed is capped, by the same factor, to what each joint can still brake from.
    const bool fixedTarget = target_ == previousTarget_;
    previousTarget_ = target_;
    if (following_) {
        double lo = 0.0;
        double hi = 1.0;
        double brake = 1.0;
        for (std::size_t j = 0; j < kAxes && lo <= hi; ++j) {
            const double e = target_[j] - q[j];
            const double a = maxAcceleration_[j] * dt;  // speed change allowed in one step
            if (e == 0.0) {
                if (std::abs(v[j]) > a) lo = 2.0;  // cannot stop this joint within the step
                continue;
            }
            hi = std::min(hi, maxVelocity_[j] * dt / std::abs(e));
            if (fixedTarget) {
                const double am = maxAcceleration_[j];
                const double reach =
                    std::sqrt(am * am * dt * dt + 2.0 * am * std::abs(e)) - am * dt;
                brake = std::min(brake, reach * dt / std::abs(e));
            }
            // (v[j] - a) dt <= s e <= (v[j] + a) dt
            double b1 = (v[j] - a) * dt / e;
            double b2 = (v[j] + a) * dt / e;
            if (b1 > b2) std::swap(b1, b2);
            lo = std::max(lo, b1);
            hi = std::min(hi, b2);
        }
        // Braking to a fixed target as hard as the limits allow along the path; when even
        // that is not enough (a stream that paused for a step) it goes on at the least speed.
        if (lo <= hi) hi = std::max(lo, std::min(hi, brake));
        tracking_ = lo <= hi && hi == 1.0;
        if (lo <= hi && hi > 0.0) {
            for (std::size_t j = 0; j < kAxes; ++j) {
                const double vPrevious = v[j];
                const double vNext = hi * (target_[j] - q[j]) / dt;
                v[j] = vNext;
                q[j] = hi == 1.0 ? target_[j] : q[j] + vNext * dt;
                commandAcceleration_[j] = (vNext - vPrevious) / dt;
            }
            world_.setJoints(config_.robot, q, v);
            return;
        }
    }

    tracking_ = false;
    for (std::size_t j = 0; j < kAxes; ++j) {
        const double a = maxAcceleration_[j];
        const double vPrevious = v[j];
        double vNext = 0.0;
        if (following_) {
            // Servo: the fastest speed from which the robot still stops at the target with
            // deceleration a, in whole steps (sqrt(2 a |e|) corrected for the discrete step:
            // |e| >= v^2 / 2a + v dt keeps it from overshooting), and never past the target
            // in one step.
            const double e = target_[j] - q[j];
            const double reach = std::sqrt(a * a * dt * dt + 2.0 * a * std::abs(e)) - a * dt;
            const double speed = std::min({std::abs(e) / dt, reach, maxVelocity_[j]});
            vNext = std::copysign(speed, e);
            if (e == 0.0) vNext = 0.0;
        }
        // else: stop (the script's stopj): towards 0 at a, which never reverses.
        vNext = std::clamp(vNext, vPrevious - a * dt, vPrevious + a * dt);
        v[j] = vNext;
        q[j] += vNext * dt;
        commandAcceleration_[j] = (vNext - vPrevious) / dt;
    }
    world_.setJoints(config_.robot, q, v);
}

void UrController::publish() {
    const world::RobotState& robot = world_.robot(config_.robot);
    const Eigen::Isometry3d& base = world_.description().robots[config_.robot].base;
    // tcp_offset is zero: the UR's TCP is the flange, in the robot's base frame.
    const Eigen::Isometry3d tcp = base.inverse() * robot.flange;
    const double time = world_.time();
    rtde::Vector6d speed{};
    // At rest the pose is bit for bit the same: report exactly 0 (AngleAxis of a rounded
    // identity would give a speck of rotation).
    if (previousTcp_ && time > previousTime_ && !tcp.isApprox(*previousTcp_, 0.0)) {
        const double dt = time - previousTime_;
        const Eigen::Vector3d linear = (tcp.translation() - previousTcp_->translation()) / dt;
        const Eigen::AngleAxisd turn(tcp.linear() * previousTcp_->linear().transpose());
        const Eigen::Vector3d angular = turn.angle() / dt * turn.axis();
        speed = {linear.x(), linear.y(), linear.z(), angular.x(), angular.y(), angular.z()};
    }
    previousTcp_ = tcp;
    previousTime_ = time;
    const Eigen::Vector3d force = base.linear().transpose() * robot.tcpForce;
    const rtde::Vector6d pose = toUrPose(tcp);
    const rtde::Vector6d q = toVector(robot.q);
    const rtde::Vector6d qd = toVector(robot.qd);

    std::lock_guard lock(mutex_);
    outputs_["timestamp"] = time;
    // The servo writes its command straight into the joints: target = actual.
    outputs_["target_q"] = q;
    outputs_["actual_q"] = q;
    outputs_["target_qd"] = qd;
    outputs_["actual_qd"] = qd;
    outputs_["actual_TCP_pose"] = pose;
    outputs_["target_TCP_pose"] = pose;
    outputs_["actual_TCP_speed"] = speed;
    outputs_["target_TCP_speed"] = speed;
    outputs_["actual_TCP_force"] = rtde::Vector6d{force.x(), force.y(), force.z(), 0, 0, 0};
    const bool stopped = protectiveStopShared_;
    outputs_["safety_mode"] = stopped ? kSafetyProtectiveStop : kSafetyNormal;
    outputs_["safety_status"] = stopped ? kSafetyProtectiveStop : kSafetyNormal;
    outputs_["safety_status_bits"] = stopped ? kSafetyBitProtectiveStop : kSafetyBitNormal;
}

std::uint64_t UrController::lateTargets() const {
    std::lock_guard lock(mutex_);
    return lateTargets_;
}

std::uint64_t UrController::starvedSteps() const {
    std::lock_guard lock(mutex_);
    return starvedShared_;
}

bool UrController::following() const {
    std::lock_guard lock(mutex_);
    return followingShared_;
}

bool UrController::watchdogTripped() const {
    std::lock_guard lock(mutex_);
    return trippedShared_;
}

bool UrController::protectiveStop() const {
    std::lock_guard lock(mutex_);
    return protectiveStopShared_;
}

std::uint64_t UrController::rejectedTargets() const {
    std::lock_guard lock(mutex_);
    return rejectedShared_;
}

}  // namespace pnp::sim::ur
