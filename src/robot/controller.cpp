#include "robot/controller.hpp"

#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

namespace pnp::robot {
namespace {

// Cycles a trajectory may advance by at once (samples the loop did not get); a bigger gap in
// the controller's time is a restart or a stall, and counts as one cycle.
constexpr double kMaxCatchUpCycles = 4.0;

constexpr double kStartTolerance = 1e-3;     // rad: a trajectory must start where the robot is
constexpr std::size_t kStatsWindow = 30000;  // samples: one minute at 500 Hz
// stop() lets a running motion brake to rest for at most this long.
constexpr auto kStopBrakeTime = std::chrono::seconds(5);

double seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

std::string safetyText(SafetyState s) {
    switch (s) {
        case SafetyState::kNormal:
            return "normal";
        case SafetyState::kReduced:
            return "in reduced mode";
        case SafetyState::kProtectiveStop:
            return "in a protective stop";
        case SafetyState::kEmergencyStop:
            return "in an emergency stop";
        case SafetyState::kFault:
            return "in a safety fault";
        case SafetyState::kUnknown:
            break;
    }
    return "in an unknown safety state";
}

// Why the robot cannot be commanded now, or empty.
std::string notReadyReason(const State& s) {
    if (s.safety != SafetyState::kNormal) return "the robot is " + safetyText(s.safety);
    if (!s.following)
        return "the robot controller does not follow commands (servo program not running)";
    return {};
}

// State shared by every motion: the result and the requests from other threads.
class MotionCore {
  public:
    std::optional<MotionResult> wait(Deadline deadline, std::stop_token stop) {
        std::unique_lock lock(mutex_);
        cv_.wait_until(lock, stop, deadline, [&] { return result_.has_value(); });
        return result_;
    }
    bool finished() const { return finished_.load(std::memory_order_acquire); }
    // Loop thread (or the controller on stop); the first result wins.
    void finish(MotionResult result) {
        {
            std::lock_guard lock(mutex_);
            if (result_) return;
            result_ = std::move(result);
            finished_.store(true, std::memory_order_release);
        }
        cv_.notify_all();
    }

    std::atomic<bool> halt{false};
    std::atomic<bool> suspend{false};
    std::atomic<double> progress{0.0};

  private:
    mutable std::mutex mutex_;
    std::condition_variable_any cv_;
    std::optional<MotionResult> result_;
    std::atomic<bool> finished_{false};
};

// The loop's side of a motion (loop thread only, apart from the MotionCore).
class LoopMotion {
  public:
    virtual ~LoopMotion() = default;
    // Starts from the command of the previous cycle (the loop's hold position).
    virtual void activate(const Joints& commanded) = 0;
    // One cycle: the joint command, true once the motion has ended (result posted).
    virtual bool step(const State& state, double dt, Joints& command) = 0;
    virtual MotionCore& core() = 0;
};

// The caller's side of a motion (Motion or Stream) on its MotionCore: the same for both kinds.
template <class Interface>
class MotionHandle : public Interface, public LoopMotion {
  public:
    std::optional<MotionResult> wait(Deadline deadline, std::stop_token stop) override {
        return core_.wait(deadline, std::move(stop));
    }
    bool finished() const override { return core_.finished(); }
    void halt() override { core_.halt.store(true); }
    void suspend() override { core_.suspend.store(true); }
    void resume() override { core_.suspend.store(false); }
    bool suspended() const override { return core_.suspend.load(); }
    MotionCore& core() override { return core_; }

  protected:
    MotionCore core_;
};

class TrajectoryMotion final : public MotionHandle<Motion> {
  public:
    TrajectoryMotion(motion::Trajectory trajectory, MotionOptions options)
        : base_(trajectory), current_(std::move(trajectory)), options_(options) {}

    double progress() const override { return core_.progress.load(); }
    void activate(const Joints&) override {}

    bool step(const State& state, double dt, Joints& command) override {
        for (int i = 0; i < 3; ++i) maxForce_[i] = std::max(maxForce_[i], std::abs(state.force[i]));
        bool forceExceeded = false;
        if (options_.maxForce) {
            for (int i = 0; i < 3; ++i)
                forceExceeded = forceExceeded || std::abs(state.force[i]) > (*options_.maxForce)[i];
        }
        const bool halt = core_.halt.load();
        const bool suspend = core_.suspend.load();

        // Requests act on the state commanded last cycle (t_), so the new command already
        // decelerates: braking starts from the same position and velocity, no jump.
        if (phase_ == Phase::kHeld) {
            if (halt) return end(MotionEnd::kHalted, "halted", command);
            if (forceExceeded) return end(MotionEnd::kForceExceeded, forceText(), command);
            if (!suspend) {
                current_ = base_.resume(current_.endParameter());
                t_ = 0.0;
                phase_ = Phase::kRunning;
            }
        }
        if (phase_ == Phase::kRunning) {
            if (halt || forceExceeded || suspend) {
                current_ = current_.stop(t_);
                t_ = 0.0;
                phase_ = Phase::kBraking;
            }
        }
        if (phase_ == Phase::kBraking) {
            // The most serious reason wins: force > halt > suspend.
            if (forceExceeded)
                reason_ = Reason::kForce;
            else if (halt && reason_ != Reason::kForce)
                reason_ = Reason::kHalt;
            else if (reason_ == Reason::kNone)
                reason_ = Reason::kSuspend;
        }

        if (phase_ == Phase::kHeld) {
            command = heldQ_;
            return false;
        }
        t_ = std::min(t_ + dt, current_.duration());
        command = current_.sample(t_).position;
        core_.progress.store(current_.pathState(t_).s, std::memory_order_relaxed);
        if (t_ < current_.duration()) return false;

        if (phase_ == Phase::kRunning) return end(MotionEnd::kCompleted, {}, command);
        switch (reason_) {
            case Reason::kForce:
                return end(MotionEnd::kForceExceeded, forceText(), command);
            case Reason::kHalt:
                return end(MotionEnd::kHalted, "halted", command);
            default:
                break;
        }
        // Suspended: at rest on the path; resume() continues from here.
        phase_ = Phase::kHeld;
        reason_ = Reason::kNone;
        heldQ_ = command;
        return false;
    }

  private:
    enum class Phase { kRunning, kBraking, kHeld };
    enum class Reason { kNone, kSuspend, kHalt, kForce };

    std::string forceText() const {
        char buf[160];
        const Eigen::Vector3d& m = *options_.maxForce;
        std::snprintf(
            buf, sizeof buf,
            "force limit exceeded: |F| = (%.1f, %.1f, %.1f) N, limit (%.1f, %.1f, %.1f) N",
            maxForce_.x(), maxForce_.y(), maxForce_.z(), m.x(), m.y(), m.z());
        return buf;
    }
    bool end(MotionEnd how, std::string message, Joints& command) {
        if (phase_ == Phase::kHeld) command = heldQ_;
        core_.finish(MotionResult{how, std::move(message), maxForce_});
        return true;
    }

    motion::Trajectory base_;     // the planned path, for resume()
    motion::Trajectory current_;  // the timing law being followed (base, braking, resumed)
    MotionOptions options_;
    Phase phase_ = Phase::kRunning;
    Reason reason_ = Reason::kNone;
    double t_ = 0.0;  // local time of current_ at the last command
    Joints heldQ_{};
    Eigen::Vector3d maxForce_ = Eigen::Vector3d::Zero();
};

class StreamMotion final : public MotionHandle<Stream> {
  public:
    StreamMotion(const motion::JointLimits& limits, const Joints& start, Joints brake)
        : limits_(limits), brakeAcceleration_(brake), target_(start) {}

    double progress() const override { return 0.0; }
    void setTarget(const Joints& q) override {
        std::lock_guard lock(targetMutex_);
        target_ = q;
    }

    void activate(const Joints& commanded) override {
        q_ = commanded;
        v_ = {};
    }

    bool step(const State&, double dt, Joints& command) override {
        const bool halt = core_.halt.load();
        if (halt || core_.suspend.load()) {
            // Brake every axis to rest (each at its own deceleration: along the current
            // direction of motion, never towards a new target).
            bool moving = false;
            for (std::size_t i = 0; i < q_.size(); ++i) {
                const double dv = brakeAcceleration_[i] * dt;
                v_[i] = v_[i] > 0.0 ? std::max(0.0, v_[i] - dv) : std::min(0.0, v_[i] + dv);
                q_[i] += v_[i] * dt;
                moving = moving || v_[i] != 0.0;
            }
            command = q_;
            if (!moving && halt) {
                core_.finish(MotionResult{MotionEnd::kHalted, "halted", {}});
                return true;
            }
            return false;
        }
        Joints target;
        {
            std::lock_guard lock(targetMutex_);
            target = target_;
        }
        for (std::size_t i = 0; i < q_.size(); ++i) {
            // The servo law: as fast as allowed, but slow enough to stop at the target.
            const double e = target[i] - q_[i];
            const double a = limits_.maxAcceleration[i];
            double v = std::min(std::abs(e) / dt, std::sqrt(2.0 * a * std::abs(e)));
            v = std::min(v, limits_.maxVelocity[i]);
            v = std::copysign(v, e);
            const double dvMax = a * dt;
            v_[i] += std::clamp(v - v_[i], -dvMax, dvMax);
            q_[i] += v_[i] * dt;
        }
        command = q_;
        return false;
    }

  private:
    motion::JointLimits limits_;
    Joints brakeAcceleration_;
    std::mutex targetMutex_;
    Joints target_;
    Joints q_{};
    Joints v_{};
};

bool finiteJoints(const Joints& q) {
    return std::all_of(q.begin(), q.end(), [](double x) { return std::isfinite(x); });
}

}  // namespace

struct Controller::Impl {
    Impl(HardwareInterface& h, ControllerConfig c) : hw(h), config(c), periods(kStatsWindow) {}

    HardwareInterface& hw;
    ControllerConfig config;

    std::jthread thread;
    std::atomic<bool> connected{false};
    std::atomic<bool> running{false};

    // Guards latest, current, pending, the stats ring and wakeCv.
    mutable std::mutex mutex;
    std::condition_variable_any wakeCv;
    std::optional<State> latest;
    std::shared_ptr<LoopMotion> pending;  // handed over by execute(), taken by the loop
    std::shared_ptr<LoopMotion> current;  // the motion that runs or is about to run

    std::mutex callbackMutex;
    std::function<void(const State&)> callback;

    // Loop statistics: the ring of sample periods (allocated once).
    std::vector<double> periods;
    std::size_t periodNext = 0;
    std::size_t periodCount = 0;
    std::uint64_t cycles = 0;
    std::uint64_t linkLosses = 0;
    // Whether a loss happened since the link was last up (for the "back" line).
    bool lostSinceConnect() {
        std::lock_guard lock(mutex);
        return linkLosses > 0;
    }
    bool realtime = false;

    // Loop thread only.
    std::shared_ptr<LoopMotion> active;
    Joints held{};
    bool haveHeld = false;
    std::optional<Clock::time_point> lastReceived;
    std::optional<double> lastControllerTime;

    void run(std::stop_token stop);
    void cycle(const State& state);
    void linkLost(const std::string& why);
    void failMotions(const std::string& why);
    bool hasPending() const {
        std::lock_guard lock(mutex);
        return pending != nullptr;
    }
};

void Controller::Impl::failMotions(const std::string& why) {
    std::shared_ptr<LoopMotion> a = std::move(active), p;
    {
        std::lock_guard lock(mutex);
        p = std::move(pending);
        current.reset();
    }
    for (auto* m : {a.get(), p.get()})
        if (m) m->core().finish(MotionResult{MotionEnd::kFailed, why, {}});
}

void Controller::Impl::linkLost(const std::string& why) {
    if (config.log) config.log("link to the controller lost (" + why + "); reconnecting");
    failMotions("link to the controller lost (" + why + ")");
    hw.disconnect();
    connected.store(false);
    lastReceived.reset();
    lastControllerTime.reset();
    haveHeld = false;
    std::lock_guard lock(mutex);
    ++linkLosses;
}

void Controller::Impl::cycle(const State& state) {
    std::shared_ptr<LoopMotion> taken;
    bool first = false;
    {
        std::lock_guard lock(mutex);
        first = !latest.has_value();
        latest = state;
        ++cycles;
        if (lastReceived) {
            periods[periodNext] = seconds(state.received - *lastReceived);
            periodNext = (periodNext + 1) % periods.size();
            periodCount = std::min(periodCount + 1, periods.size());
        }
        if (!active && pending) taken = std::move(pending);
    }
    if (first) wakeCv.notify_all();
    lastReceived = state.received;
    // The time the controller moved on since the last sample: normally one cycle; two when a
    // sample did not reach us (the controller went on through that cycle, see README).
    double dt = hw.cycleTime();
    if (lastControllerTime) {
        const double d = state.controllerTime - *lastControllerTime;
        if (d > 0.0 && d <= kMaxCatchUpCycles * dt) dt = d;
    }
    lastControllerTime = state.controllerTime;
    if (!haveHeld) {
        held = state.q;
        haveHeld = true;
    }
    if (taken) {
        taken->activate(held);
        active = std::move(taken);
    }

    const std::string reason = notReadyReason(state);
    Command command;
    if (active && !reason.empty()) {
        active->core().finish(MotionResult{MotionEnd::kFailed, reason, {}});
        active.reset();
    }
    if (active) {
        Joints q;
        const bool ended = active->step(state, dt, q);
        command = Command{true, q};
        held = q;
        if (ended) active.reset();
    } else if (reason.empty()) {
        command = Command{true, held};
    } else {
        // Not following: command nothing and track the actual position, so that the robot
        // does not jump when it follows again.
        held = state.q;
        command = Command{false, state.q};
    }
    if (!active) {
        std::lock_guard lock(mutex);
        if (current && current->core().finished()) current.reset();
    }

    auto written = hw.write(command, Clock::now() + config.readTimeout);
    if (!written) {
        linkLost(written.error().message);
        return;
    }
    std::lock_guard lock(callbackMutex);
    if (callback) callback(state);
}

void Controller::Impl::run(std::stop_token stop) {
    sched_param param{};
    param.sched_priority = std::max(1, sched_get_priority_max(SCHED_FIFO) / 2);
    const bool rt = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param) == 0;
    {
        std::lock_guard lock(mutex);
        realtime = rt;
    }

    // stop(): a running motion brakes along its path first (bounded), then the link closes.
    bool stopping = false;
    Clock::time_point stopBy{};
    for (;;) {
        if (stop.stop_requested() && !stopping) {
            stopping = true;
            stopBy = Clock::now() + kStopBrakeTime;
            std::lock_guard lock(mutex);
            for (auto* m : {active.get(), pending.get()})
                if (m) m->core().halt.store(true);
        }
        if (stopping &&
            (!connected.load() || Clock::now() > stopBy || (!active && !hasPending()))) {
            break;
        }
        if (!connected.load()) {
            {
                std::unique_lock lock(mutex);
                wakeCv.wait_for(lock, stop, config.reconnectDelay, [] { return false; });
            }
            if (stop.stop_requested()) continue;
            auto r = hw.connect(Clock::now() + config.connectTimeout);
            if (!r) {
                hw.disconnect();
                continue;
            }
            if (config.log && lostSinceConnect()) config.log("link to the controller back");
            connected.store(true);
        }
        auto state = hw.read(Clock::now() + config.readTimeout);
        if (!state) {
            linkLost(state.error().message);
            continue;
        }
        cycle(*state);
    }
    failMotions("the robot controller was stopped");
    if (connected.exchange(false)) hw.disconnect();
}

Controller::Controller(HardwareInterface& hardware, ControllerConfig config)
    : impl_(std::make_unique<Impl>(hardware, config)) {}

Controller::~Controller() { stop(); }

Result<Done> Controller::start(Deadline deadline) {
    Impl& d = *impl_;
    if (d.running.load()) return Error{"the robot controller is already started"};
    auto r = d.hw.connect(deadline);
    if (!r) {
        d.hw.disconnect();
        return Error{"cannot connect to the robot controller at " + d.hw.endpoint() + ": " +
                     r.error().message};
    }
    {
        std::lock_guard lock(d.mutex);
        d.latest.reset();
    }
    d.haveHeld = false;
    d.lastReceived.reset();
    d.connected.store(true);
    d.running.store(true);
    d.thread = std::jthread([&d](std::stop_token stop) { d.run(std::move(stop)); });
    // Hand back a usable controller: the first sample is there (execute() needs it).
    std::unique_lock lock(d.mutex);
    const bool got = d.wakeCv.wait_until(lock, deadline, [&] { return d.latest.has_value(); });
    lock.unlock();
    if (!got) {
        stop();
        return Error{"no state from the robot controller at " + d.hw.endpoint() +
                     " before the deadline"};
    }
    return Done{};
}

void Controller::stop() {
    Impl& d = *impl_;
    d.running.store(false);  // execute() refuses from now on
    if (d.thread.joinable()) {
        d.thread.request_stop();
        d.wakeCv.notify_all();
        d.thread.join();
    }
    d.running.store(false);
}

bool Controller::connected() const { return impl_->connected.load(); }

std::optional<State> Controller::state() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->latest;
}

void Controller::onState(std::function<void(const State&)> callback) {
    std::lock_guard lock(impl_->callbackMutex);
    impl_->callback = std::move(callback);
}

namespace {

std::string jointsText(const Joints& q) {
    char buf[160];
    std::snprintf(buf, sizeof buf, "(%.4f, %.4f, %.4f, %.4f, %.4f, %.4f)", q[0], q[1], q[2], q[3],
                  q[4], q[5]);
    return buf;
}

}  // namespace

Result<std::shared_ptr<Motion>> Controller::execute(motion::Trajectory trajectory,
                                                    MotionOptions options) {
    Impl& d = *impl_;
    if (options.maxForce) {
        const Eigen::Vector3d& f = *options.maxForce;
        if (!f.allFinite() || (f.array() <= 0.0).any())
            return Error{"MaxForce must be finite and > 0 on every axis"};
    }
    const Joints start = trajectory.sample(0.0).position;
    auto motion = std::make_shared<TrajectoryMotion>(std::move(trajectory), options);
    std::lock_guard lock(d.mutex);
    if (!d.running.load() || !d.connected.load())
        return Error{"not connected to the robot controller"};
    if (d.current && !d.current->core().finished()) return Error{"another motion is running"};
    if (!d.latest) return Error{"no state from the robot controller yet"};
    if (auto why = notReadyReason(*d.latest); !why.empty()) return Error{why};
    for (std::size_t i = 0; i < start.size(); ++i) {
        if (!(std::abs(start[i] - d.latest->q[i]) <= kStartTolerance))
            return Error{"the trajectory starts at " + jointsText(start) +
                         ", not at the robot's position " + jointsText(d.latest->q)};
    }
    d.pending = motion;
    d.current = motion;
    return std::shared_ptr<Motion>(motion);
}

Result<std::shared_ptr<Stream>> Controller::stream(const motion::JointLimits& limits) {
    Impl& d = *impl_;
    for (std::size_t i = 0; i < limits.maxVelocity.size(); ++i) {
        if (!(std::isfinite(limits.maxVelocity[i]) && limits.maxVelocity[i] > 0.0 &&
              std::isfinite(limits.maxAcceleration[i]) && limits.maxAcceleration[i] > 0.0))
            return Error{"stream limits of axis " + std::to_string(i) + " must be finite and > 0"};
    }
    // Braking on halt: the configured deceleration when given, else the stream's own.
    Joints brake = limits.maxAcceleration;
    for (std::size_t i = 0; i < brake.size(); ++i) {
        const double c = d.config.limits.maxAcceleration[i];
        if (std::isfinite(c) && c > 0.0) brake[i] = std::max(brake[i], c);
    }
    std::lock_guard lock(d.mutex);
    if (!d.running.load() || !d.connected.load())
        return Error{"not connected to the robot controller"};
    if (d.current && !d.current->core().finished()) return Error{"another motion is running"};
    if (!d.latest) return Error{"no state from the robot controller yet"};
    if (auto why = notReadyReason(*d.latest); !why.empty()) return Error{why};
    if (!finiteJoints(d.latest->q)) return Error{"the robot's position is not finite"};
    auto s = std::make_shared<StreamMotion>(limits, d.latest->q, brake);
    d.pending = s;
    d.current = s;
    return std::shared_ptr<Stream>(s);
}

LoopStats Controller::stats() const {
    Impl& d = *impl_;
    LoopStats out;
    std::vector<double> window;
    double cycleTime = d.hw.cycleTime();
    {
        std::lock_guard lock(d.mutex);
        out.cycles = d.cycles;
        out.linkLosses = d.linkLosses;
        out.realtime = d.realtime;
        window.reserve(d.periodCount);
        for (std::size_t i = 0; i < d.periodCount; ++i) window.push_back(d.periods[i]);
    }
    out.window = window.size();
    if (window.empty()) return out;
    const auto mid = window.begin() + static_cast<std::ptrdiff_t>(window.size() / 2);
    std::nth_element(window.begin(), mid, window.end());
    out.periodMedian = *mid;
    for (double& p : window) p = std::abs(p - cycleTime);
    const auto p99 = window.begin() + static_cast<std::ptrdiff_t>((window.size() - 1) * 99 / 100);
    std::nth_element(window.begin(), p99, window.end());
    out.periodErrorP99 = *p99;
    out.periodErrorMax = *std::max_element(window.begin(), window.end());
    return out;
}

}  // namespace pnp::robot
