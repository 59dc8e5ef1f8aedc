// Helpers of the simulator tests: the thesis cell, a fixed-rate stepping thread that records
// the world at every step, and an RTDE client session for the servo program. Own helpers
// (not tests/support, which links the OPC UA transport). Every wait is bounded.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "kinematics/kinematics.hpp"
#include "rtde/client.hpp"
#include "sim/ur/ur_controller.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"

namespace pnp::sim::ur::test {

using world::Joints;
using namespace std::chrono_literals;

inline constexpr double kDt = 0.002;  // s, the e-Series control period

inline world::CellDescription thesisCell() {
    auto cell =
        world::loadCellFile(std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml");
    if (!cell.ok()) {
        ADD_FAILURE() << cell.error().message;
        return {};
    }
    return *cell;
}

// Joints that put the UR5's flange, pointing down as at home, at `point` (world frame).
inline Joints flangeAt(const world::CellDescription& cell, const Eigen::Vector3d& point,
                       const Joints& seed) {
    const world::RobotDescription& r = cell.robots.at(0);
    Eigen::Isometry3d goal = r.base * kinematics::forward(r.model, r.home);
    goal.translation() = point;
    auto q = kinematics::solveNearest(r.model, r.base.inverse() * goal, seed);
    if (!q.ok()) {
        ADD_FAILURE() << q.error().message;
        return seed;
    }
    return *q;
}

template <class Pred>
bool waitFor(Pred pred, std::chrono::milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
        if (pred()) return true;
        std::this_thread::sleep_for(2ms);
    }
    return pred();
}

// One recorded step: the world's robot after world.step().
struct Sample {
    Joints q{};
    Joints qd{};
    double force = 0.0;  // |tcpForce|, N
};

// Steps controller + world every 2 ms of real time (kDt of simulated time) on its own thread,
// as the simulator does, and records every step. It does not catch up after a delay (the
// watchdog counts simulated time, so a burst would look like silence).
class Stepper {
  public:
    // afterStep: e.g. the RTDE server's cycle() (externalCycle), after each publish().
    Stepper(world::World& world, UrController& controller, std::size_t maxSteps = 20000,
            std::function<void()> afterStep = {})
        : world_(world),
          controller_(controller),
          maxSteps_(maxSteps),
          afterStep_(std::move(afterStep)) {
        thread_ = std::thread([this] { run(); });
    }
    ~Stepper() { stop(); }
    Stepper(const Stepper&) = delete;
    Stepper& operator=(const Stepper&) = delete;

    void stop() {
        stop_ = true;
        if (thread_.joinable()) thread_.join();
    }
    std::vector<Sample> samples() const {
        std::lock_guard lock(mutex_);
        return samples_;
    }
    std::size_t count() const {
        std::lock_guard lock(mutex_);
        return samples_.size();
    }
    Sample last() const {
        std::lock_guard lock(mutex_);
        return samples_.empty() ? Sample{} : samples_.back();
    }
    // Waits until `steps` more steps have been made (bounded by real time).
    bool waitSteps(std::size_t steps, std::chrono::milliseconds timeout) {
        const std::size_t target = count() + steps;
        return waitFor([&] { return count() >= target; }, timeout);
    }

  private:
    void run() {
        auto next = std::chrono::steady_clock::now();
        for (std::size_t i = 0; i < maxSteps_ && !stop_; ++i) {
            controller_.step(kDt);
            world_.step(kDt);
            controller_.publish();
            if (afterStep_) afterStep_();
            const world::RobotState& r = world_.robot(0);
            {
                std::lock_guard lock(mutex_);
                samples_.push_back({r.q, r.qd, r.tcpForce.norm()});
            }
            next += 2ms;
            next = std::max(next, std::chrono::steady_clock::now());
            std::this_thread::sleep_until(next);
        }
    }

    world::World& world_;
    UrController& controller_;
    const std::size_t maxSteps_;
    std::function<void()> afterStep_;
    std::atomic<bool> stop_{false};
    mutable std::mutex mutex_;
    std::vector<Sample> samples_;
    std::thread thread_;
};

inline const std::vector<std::string> kOutputs = {
    "timestamp",       "target_q",        "actual_q",         "actual_qd",
    "actual_TCP_pose", "target_TCP_pose", "actual_TCP_speed", "actual_TCP_force",
    "tcp_offset",      "robot_mode",      "safety_mode",      "runtime_state"};
inline const std::vector<std::string> kInputs = {
    "input_int_register_0",    "input_double_register_0", "input_double_register_1",
    "input_double_register_2", "input_double_register_3", "input_double_register_4",
    "input_double_register_5", "input_double_register_6"};

// An RTDE client as the adapter uses it: outputs at 500 Hz, the servo program's inputs.
class Session {
  public:
    // Connects and sets up; check with ASSERT_TRUE(session.open(port)).
    bool open(std::uint16_t port) {
        const auto deadline = rtde::deadlineIn(3000ms);
        if (auto s = client_.connect("127.0.0.1", port, deadline); !s.ok()) {
            return fail(s.message);
        }
        if (auto s = client_.negotiateProtocolVersion(deadline); !s.ok()) return fail(s.message);
        auto out = client_.setupOutputs(500.0, kOutputs, deadline);
        if (!out.ok() || !out->valid()) return fail("output recipe refused");
        outputs_ = out.value();
        auto in = client_.setupInputs(kInputs, deadline);
        if (!in.ok() || !in->valid()) return fail("input recipe refused");
        inputs_ = in.value();
        if (auto s = client_.start(deadline); !s.ok()) return fail(s.message);
        return true;
    }

    // Stamped with the timestamp of the last sample taken (input_double_register_6), as
    // the adapter answers each state.
    bool send(std::int32_t mode, const Joints& targets) {
        std::vector<rtde::Value> values{mode};
        for (double t : targets) values.emplace_back(t);
        values.emplace_back(answering_);
        return client_.send(inputs_.id, values, rtde::deadlineIn(1000ms)).ok();
    }

    // The next sample in order (as the adapter's loop takes them), waiting up to `timeout`.
    std::optional<rtde::DataSample> next(std::chrono::milliseconds timeout = 1000ms) {
        const auto end = rtde::Clock::now() + timeout;
        for (int i = 0; i < 1000; ++i) {
            auto r = client_.receive(end);
            if (!r.ok()) return std::nullopt;
            if (auto* d = std::get_if<rtde::DataSample>(&r.value())) {
                answering_ = get<double>(*d, "timestamp");
                return std::move(*d);
            }
        }
        return std::nullopt;
    }

    // The newest sample: drains what has arrived, waits up to `timeout` if nothing has.
    std::optional<rtde::DataSample> latest(std::chrono::milliseconds timeout = 1000ms) {
        std::optional<rtde::DataSample> newest;
        const auto end = rtde::Clock::now() + timeout;
        for (int i = 0; i < 200000; ++i) {
            auto r = client_.receive(newest ? rtde::Clock::now() : end);
            if (!r.ok()) break;
            if (auto* d = std::get_if<rtde::DataSample>(&r.value())) {
                answering_ = get<double>(*d, "timestamp");
                newest = std::move(*d);
            }
        }
        return newest;
    }

    template <class T>
    static T get(const rtde::DataSample& sample, const std::string& name) {
        const auto it = std::find(kOutputs.begin(), kOutputs.end(), name);
        return std::get<T>(sample.values.at(static_cast<std::size_t>(it - kOutputs.begin())));
    }

  private:
    bool fail(const std::string& message) {
        ADD_FAILURE() << message;
        return false;
    }
    rtde::Client client_;
    double answering_ = 0.0;
    rtde::Recipe outputs_;
    rtde::Recipe inputs_;
};

}  // namespace pnp::sim::ur::test
