// One caller at a time on a GripperHardware, and what the device said last.
//
// A vendor's transport (a libmodbus context, a TCP socket) is not thread-safe, and two
// threads use the hardware: a skill's worker (Grasp, Release, MoveGripper) and the tool
// adapter's power poller (connect, status). HardwareAccess serialises them and keeps the
// device's latest Status and the time it last answered, which the device's status
// variables and the power lifecycle read without touching the hardware.
#pragma once

#include <functional>
#include <mutex>
#include <optional>
#include <utility>

#include "device/gripper/gripper_hardware.hpp"

namespace pnp::device::gripper {

class HardwareAccess {
  public:
    explicit HardwareAccess(GripperHardware& hardware) : hardware_(hardware) {}
    HardwareAccess(const HardwareAccess&) = delete;
    HardwareAccess& operator=(const HardwareAccess&) = delete;

    // The hardware for its constant queries (grip point, identity): no lock needed.
    const GripperHardware& hardware() const { return hardware_; }

    // Runs `call(hardware)` once the hardware is free; waits for it until `deadline`, in
    // slices so that `cancel` is seen. nullopt: not free in time (or cancelled while waiting).
    template <class Call>
    auto with(Call&& call, Deadline deadline, const std::atomic<bool>* cancel = nullptr)
        -> std::optional<decltype(call(std::declval<GripperHardware&>()))> {
        std::unique_lock lock(mutex_, std::defer_lock);
        for (;;) {
            if (cancel != nullptr && cancel->load()) return std::nullopt;
            const auto now = Clock::now();
            if (now >= deadline) {
                if (!lock.try_lock()) return std::nullopt;
                break;
            }
            if (lock.try_lock_for(std::min<Clock::duration>(deadline - now, kSlice))) break;
        }
        auto result = call(hardware_);
        noteResult(result);
        return result;
    }

    // Runs `call` only when the hardware is free at once (the poller: a busy hardware is in
    // the middle of a skill's bounded call, which reports a dead device itself).
    template <class Call>
    auto tryWith(Call&& call) -> std::optional<decltype(call(std::declval<GripperHardware&>()))> {
        std::unique_lock lock(mutex_, std::try_to_lock);
        if (!lock.owns_lock()) return std::nullopt;
        auto result = call(hardware_);
        noteResult(result);
        return result;
    }

    // The device's latest Status (from any call that returned one); nullopt before the first.
    std::optional<Status> lastStatus() const {
        std::lock_guard l(stateMutex_);
        return status_;
    }
    // When the device last answered anything (a refusal is an answer; no answer is not).
    std::optional<Clock::time_point> lastAnswer() const {
        std::lock_guard l(stateMutex_);
        return lastAnswer_;
    }
    // Forget what the device said (it lost power: its state starts anew).
    void forget() {
        std::lock_guard l(stateMutex_);
        status_.reset();
        lastAnswer_.reset();
    }

    // Told of every Status the device reports, on the calling thread (keep it short). One
    // observer; an empty function removes it. Set and cleared while no call runs on it.
    void onStatus(std::function<void(const Status&)> observer) {
        std::lock_guard l(stateMutex_);
        observer_ = std::move(observer);
    }

  private:
    static constexpr std::chrono::milliseconds kSlice{5};

    void answered(const Status* status) {
        std::function<void(const Status&)> observer;
        {
            std::lock_guard l(stateMutex_);
            lastAnswer_ = Clock::now();
            if (status == nullptr) return;
            status_ = *status;
            observer = observer_;
        }
        if (observer) observer(*status);
    }
    template <class T>
    void noteResult(const Result<T>& r) {
        if (r.ok()) {
            if constexpr (std::is_same_v<T, Status>)
                answered(&r.value());
            else
                answered(nullptr);
        } else if (r.error().kind != ErrorKind::kNoDevice &&
                   r.error().kind != ErrorKind::kTimeout) {
            answered(nullptr);
        }
    }
    template <class T>
    void noteResult(const T&) {}

    GripperHardware& hardware_;
    std::timed_mutex mutex_;
    mutable std::mutex stateMutex_;
    std::optional<Status> status_;
    std::optional<Clock::time_point> lastAnswer_;
    std::function<void(const Status&)> observer_;
};

}  // namespace pnp::device::gripper
