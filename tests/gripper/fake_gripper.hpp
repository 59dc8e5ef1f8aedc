// An in-process gripper for the gripper device's tests: a GripperHardware whose jaws move
// at the requested speed in 1 ms steps, stop on an object of `objectWidth` when one is
// there, answer only while `powered`, and count what they were asked.
#pragma once

#include <atomic>
#include <chrono>
#include <cmath>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "device/gripper/gripper_hardware.hpp"

namespace pnp::testing {

namespace gr = pnp::device::gripper;

class FakeGripper : public gr::GripperHardware {
  public:
    explicit FakeGripper(gr::GripKind kind = gr::GripKind::kParallel) : kind_(kind) {}

    // Controls of the test.
    std::atomic<bool> powered{true};
    std::atomic<bool> objectPresent{true};
    std::atomic<double> objectWidth{0.03};  // m
    // Speeds the fake's jaws up (1: real time at the requested speed).
    std::atomic<double> timeScale{1.0};
    // The next grasp fails with this (kind, message) instead of moving.
    std::mutex failMutex;
    std::optional<gr::Error> failNextGrasp;
    // A faulty driver: its grasp reports success with nothing held.
    std::atomic<bool> claimGraspWithoutHolding{false};

    // What happened.
    std::atomic<int> connects{0}, activations{0}, grasps{0}, releases{0}, moves{0}, stops{0},
        statusCalls{0}, cancelled{0};
    std::atomic<double> lastForce{-1.0};
    std::atomic<gr::Clock::rep> graspCalledAt{0};  // Clock ticks of the last grasp() call
    std::atomic<bool> moving{false};
    std::atomic<double> width{0.085};
    std::atomic<bool> holding{false};
    std::atomic<bool> activated{false};

    gr::Result<gr::Done> connect(gr::Deadline) override {
        ++connects;
        if (!powered) return noDevice();
        connected_ = true;
        return gr::Done{};
    }
    void disconnect() override { connected_ = false; }
    gr::Result<gr::Done> activate(gr::Deadline, const std::atomic<bool>&) override {
        if (!answering()) return noDevice();
        ++activations;
        activated = true;
        return gr::Done{};
    }
    gr::Result<gr::Status> grasp(const gr::GraspRequest& r, gr::Deadline deadline,
                                 const std::atomic<bool>& cancel) override {
        if (!answering()) return noDevice();
        graspCalledAt = gr::Clock::now().time_since_epoch().count();
        ++grasps;
        lastForce = r.force;
        {
            std::lock_guard l(failMutex);
            if (failNextGrasp) {
                gr::Error e = *failNextGrasp;
                failNextGrasp.reset();
                return e;
            }
        }
        if (claimGraspWithoutHolding) return status();
        if (kind_ == gr::GripKind::kVacuum) {
            if (!objectPresent) return gr::Error{gr::ErrorKind::kRefused, "no part present"};
            holding = true;
            return status();
        }
        const double stopAt = objectPresent ? objectWidth.load() : r.width;
        auto end = runTo(stopAt, r.speed, deadline, cancel);
        if (!end) return end.error();
        if (!objectPresent)
            return gr::Error{gr::ErrorKind::kRefused, "no object between the fingers"};
        holding = true;
        return status();
    }
    gr::Result<gr::Status> release(gr::Deadline deadline,
                                   const std::atomic<bool>& cancel) override {
        if (!answering()) return noDevice();
        ++releases;
        holding = false;
        if (kind_ == gr::GripKind::kVacuum) return status();
        auto end = runTo(0.085, 0.15, deadline, cancel);
        if (!end) return end.error();
        return status();
    }
    gr::Result<gr::Status> move(const gr::MoveRequest& r, gr::Deadline deadline,
                                const std::atomic<bool>& cancel) override {
        if (!answering()) return noDevice();
        ++moves;
        lastForce = r.force;
        if (kind_ == gr::GripKind::kVacuum)
            return gr::Error{gr::ErrorKind::kRefused, "a vacuum gripper has no jaws"};
        holding = false;
        auto end = runTo(r.width, r.speed, deadline, cancel);
        if (!end) return end.error();
        return status();
    }
    void stop(gr::Deadline) override {
        ++stops;
        moving = false;
    }
    gr::Result<gr::Status> status(gr::Deadline) override {
        ++statusCalls;
        if (!answering()) return noDevice();
        return status();
    }

    gr::GripPoint gripPoint() const override {
        gr::GripPoint p;
        p.name = kind_ == gr::GripKind::kParallel ? "Tip" : "Cup";
        p.kind = kind_;
        p.offset = Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.2028));
        p.spanMin = 0.0;
        p.spanMax = kind_ == gr::GripKind::kParallel ? 0.085 : 0.02;
        return p;
    }
    std::string manufacturer() const override { return "Fake Grippers Inc."; }
    std::string modelName() const override {
        return kind_ == gr::GripKind::kParallel ? "FG-85" : "FV-20";
    }
    std::string serialNumber() const override { return "SN-0042"; }
    std::string endpoint() const override { return "fake://gripper"; }

  private:
    bool answering() const { return powered && connected_; }
    static gr::Error noDevice() { return {gr::ErrorKind::kNoDevice, "no answer from the fake"}; }
    gr::Status status() const {
        gr::Status s;
        s.ready = activated;
        s.moving = moving;
        s.holding = holding;
        s.width = width;
        return s;
    }
    // Moves the jaws towards `target` at `speed` (m/s, scaled) in 1 ms steps.
    gr::Result<gr::Done> runTo(double target, double speed, gr::Deadline deadline,
                               const std::atomic<bool>& cancel) {
        moving = true;
        const double step = std::max(1e-6, speed * 1e-3 * timeScale.load());
        for (int i = 0; i < 200000; ++i) {
            if (cancel) {
                ++cancelled;
                stop({});
                return gr::Error{gr::ErrorKind::kCancelled, "cancelled"};
            }
            if (!powered) {
                moving = false;
                return noDevice();
            }
            if (gr::Clock::now() >= deadline) {
                stop({});
                return gr::Error{gr::ErrorKind::kTimeout, "the jaws did not arrive in time"};
            }
            const double w = width;
            if (std::abs(w - target) <= step) {
                width = target;
                break;
            }
            width = w + (target > w ? step : -step);
            std::this_thread::sleep_for(std::chrono::milliseconds(1));
        }
        moving = false;
        return gr::Done{};
    }

    gr::GripKind kind_;
    std::atomic<bool> connected_{false};
};

}  // namespace pnp::testing
