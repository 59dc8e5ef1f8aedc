// An in-process robot for the device tests: a robot::HardwareInterface whose arm follows the
// joint commands within the model's speed and acceleration limits, paced like a controller
// (a sample every 2 ms, sleep_until). It records what a test needs to judge the commands: how
// far the arm ever got from a marked position, and the largest per-cycle speed and
// acceleration asked of it relative to the limits (a jump shows as a ratio > 1).
#pragma once

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <mutex>
#include <thread>

#include "kinematics/kinematics.hpp"
#include "robot/hardware.hpp"

namespace pnp::testing {

class FakeArm : public robot::HardwareInterface {
  public:
    using Joints = robot::Joints;
    // Force at the TCP (base frame, N then N·m) as a function of the time since connect().
    using ForceModel = std::function<std::array<double, 6>(double t, const Joints& q)>;

    explicit FakeArm(Joints start, kinematics::RobotModel model = kinematics::ur5())
        : model_(std::move(model)), q_(start), mark_(start) {}

    robot::Result<robot::Done> connect(robot::Deadline) override {
        std::lock_guard l(mutex_);
        connected_ = true;
        next_ = robot::Clock::now();
        start_ = next_;
        sequence_ = 0;
        return robot::Done{};
    }
    void disconnect() override {
        std::lock_guard l(mutex_);
        connected_ = false;
    }
    robot::Result<robot::State> read(robot::Deadline deadline) override {
        robot::Clock::time_point due;
        {
            std::lock_guard l(mutex_);
            if (!connected_) return robot::Error{"not connected"};
            next_ += kCycle;
            const auto now = robot::Clock::now();
            if (next_ < now - 50 * kCycle) next_ = now;  // fell far behind: no burst
            due = next_;
        }
        if (due > deadline) {
            std::this_thread::sleep_until(deadline);
            return robot::Error{"no sample before the deadline"};
        }
        std::this_thread::sleep_until(due);
        std::lock_guard l(mutex_);
        step();
        robot::State s;
        s.received = robot::Clock::now();
        s.controllerTime = static_cast<double>(sequence_) * dt();
        s.sequence = ++sequence_;
        s.q = q_;
        s.qd = qd_;
        s.targetQ = command_.q;
        s.flange = kinematics::forward(model_, q_);
        if (force_) {
            const auto f = force_(s.controllerTime, q_);
            for (std::size_t i = 0; i < 3; ++i) s.force[i] = f[i];
            for (std::size_t i = 3; i < 6; ++i) s.force[i] = f[i];
        }
        s.safety = robot::SafetyState::kNormal;
        s.program = robot::ProgramState::kRunning;
        s.following = true;
        return s;
    }
    robot::Result<robot::Done> write(const robot::Command& command, robot::Deadline) override {
        std::lock_guard l(mutex_);
        command_ = command;
        return robot::Done{};
    }

    double cycleTime() const override { return dt(); }
    const kinematics::RobotModel& model() const override { return model_; }
    std::string manufacturer() const override { return "pnp tests"; }
    std::string modelName() const override { return "FakeArm"; }
    std::string serialNumber() const override { return "FA-0001"; }
    std::string endpoint() const override { return "fake://arm"; }

    // ---- for the tests ------------------------------------------------------------------
    Joints q() const {
        std::lock_guard l(mutex_);
        return q_;
    }
    Joints qd() const {
        std::lock_guard l(mutex_);
        return qd_;
    }
    bool atRest() const {
        std::lock_guard l(mutex_);
        return std::all_of(qd_.begin(), qd_.end(), [](double v) { return std::abs(v) < 1e-9; });
    }
    void setForce(ForceModel f) {
        std::lock_guard l(mutex_);
        force_ = std::move(f);
    }
    // Starts a new observation: distance from here, speed and acceleration ratios.
    void mark() {
        std::lock_guard l(mutex_);
        mark_ = q_;
        maxDistance_ = 0.0;
        maxSpeedRatio_ = 0.0;
        maxAccelerationRatio_ = 0.0;
    }
    // The largest |q_i - mark_i| since mark().
    double maxDistanceFromMark() const {
        std::lock_guard l(mutex_);
        return maxDistance_;
    }
    // Largest |commanded per-cycle speed| / limit, and the same for the acceleration.
    double maxSpeedRatio() const {
        std::lock_guard l(mutex_);
        return maxSpeedRatio_;
    }
    double maxAccelerationRatio() const {
        std::lock_guard l(mutex_);
        return maxAccelerationRatio_;
    }

  private:
    static constexpr std::chrono::microseconds kCycle{2000};
    static double dt() { return std::chrono::duration<double>(kCycle).count(); }

    // One cycle: towards the command within the limits (mutex_ held).
    void step() {
        const double h = dt();
        for (std::size_t i = 0; i < q_.size(); ++i) {
            const double vmax = model_.limits[i].maxVelocity;
            const double amax = model_.limits[i].maxAcceleration;
            // Commands stop: brake to rest at the acceleration limit.
            double v = command_.servo ? (command_.q[i] - q_[i]) / h : 0.0;
            if (command_.servo) {
                maxSpeedRatio_ = std::max(maxSpeedRatio_, std::abs(v) / vmax);
                maxAccelerationRatio_ =
                    std::max(maxAccelerationRatio_, std::abs(v - qd_[i]) / h / amax);
            }
            v = std::clamp(v, -vmax, vmax);
            v = std::clamp(v, qd_[i] - amax * h, qd_[i] + amax * h);
            // Lands exactly on a command within reach (no rounding drift at the goal).
            if (command_.servo && std::abs(command_.q[i] - q_[i]) <= std::abs(v) * h + 1e-15)
                q_[i] = command_.q[i];
            else
                q_[i] += v * h;
            qd_[i] = v;
            maxDistance_ = std::max(maxDistance_, std::abs(q_[i] - mark_[i]));
        }
    }

    kinematics::RobotModel model_;
    mutable std::mutex mutex_;
    bool connected_ = false;
    robot::Clock::time_point next_{}, start_{};
    std::uint64_t sequence_ = 0;
    Joints q_{}, qd_{};
    robot::Command command_{};
    ForceModel force_;
    Joints mark_{};
    double maxDistance_ = 0.0;
    double maxSpeedRatio_ = 0.0;
    double maxAccelerationRatio_ = 0.0;
};

}  // namespace pnp::testing
