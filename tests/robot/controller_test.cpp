#include "robot/controller.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>
#include <thread>
#include <vector>

namespace pnp::robot {
namespace {

using namespace std::chrono_literals;
constexpr double kDt = 0.002;

// An arm in-process: paced at 2 ms like a UR e-Series, it follows each servo command within
// its own velocity limit (a perfect servo otherwise) and records every command. Faults are
// switched on by the test: a dead link, a safety stop, a contact force past a joint angle.
class FakeArm final : public HardwareInterface {
  public:
    explicit FakeArm(Joints q) : q_(q), model_(kinematics::ur5()) { commands_.reserve(200000); }

    Result<Done> connect(Deadline) override {
        if (linkDown) return Error{"connection refused"};
        std::lock_guard lock(mutex_);
        ++connects_;
        next_ = Clock::now();
        return Done{};
    }
    void disconnect() override {}
    Result<State> read(Deadline deadline) override {
        if (linkDown) {
            std::this_thread::sleep_until(deadline);
            return Error{"no data before the deadline"};
        }
        Clock::time_point next;
        {
            std::lock_guard lock(mutex_);
            next_ += std::chrono::microseconds(2000);
            next = next_;
        }
        if (next > deadline) {
            std::this_thread::sleep_until(deadline);
            return Error{"no data before the deadline"};
        }
        std::this_thread::sleep_until(next);
        std::lock_guard lock(mutex_);
        // Late (a slow machine): do not try to catch up with a burst of samples.
        if (Clock::now() - next_ > 20ms) next_ = Clock::now();
        State s;
        s.received = Clock::now();
        s.controllerTime = static_cast<double>(++ticks_) * kDt;
        s.sequence = ticks_;
        s.q = q_;
        s.qd = qd_;
        s.targetQ = q_;
        s.safety = safety.load();
        s.program = ProgramState::kRunning;
        s.following = s.safety == SafetyState::kNormal;
        if (q_[0] > forceAboveQ0.load()) s.force[2] = 40.0;
        return s;
    }
    Result<Done> write(const Command& c, Deadline) override {
        if (linkDown) return Error{"broken pipe"};
        std::lock_guard lock(mutex_);
        commands_.push_back(c);
        if (c.servo) {
            for (std::size_t i = 0; i < 6; ++i) {
                const double step = std::clamp(c.q[i] - q_[i], -4.0 * kDt, 4.0 * kDt);
                qd_[i] = step / kDt;
                q_[i] += step;
            }
        } else {
            qd_ = {};
        }
        return Done{};
    }
    double cycleTime() const override { return kDt; }
    const kinematics::RobotModel& model() const override { return model_; }
    std::string manufacturer() const override { return "test"; }
    std::string modelName() const override { return "fake"; }
    std::string serialNumber() const override { return "0"; }
    std::string endpoint() const override { return "fake://arm"; }

    Joints q() const {
        std::lock_guard lock(mutex_);
        return q_;
    }
    std::vector<Command> commands() const {
        std::lock_guard lock(mutex_);
        return commands_;
    }
    std::size_t commandCount() const {
        std::lock_guard lock(mutex_);
        return commands_.size();
    }
    int connects() const {
        std::lock_guard lock(mutex_);
        return connects_;
    }

    std::atomic<bool> linkDown{false};
    std::atomic<SafetyState> safety{SafetyState::kNormal};
    std::atomic<double> forceAboveQ0{1e9};

  private:
    mutable std::mutex mutex_;
    Joints q_;
    Joints qd_{};
    kinematics::RobotModel model_;
    std::vector<Command> commands_;
    Clock::time_point next_{};
    std::uint64_t ticks_ = 0;
    int connects_ = 0;
};

const Joints kStart{0.0, -1.2, 1.4, -1.5, -1.5, 0.0};

motion::JointLimits limits(double v, double a) {
    motion::JointLimits l;
    l.maxVelocity.fill(v);
    l.maxAcceleration.fill(a);
    return l;
}

ControllerConfig config() {
    ControllerConfig c;
    c.readTimeout = 100ms;
    c.reconnectDelay = 100ms;
    c.connectTimeout = 500ms;
    c.limits = limits(3.0, 6.0);
    return c;
}

Joints offset(const Joints& q, const Joints& d) {
    Joints out;
    for (std::size_t i = 0; i < 6; ++i) out[i] = q[i] + d[i];
    return out;
}

template <class Pred>
bool waitFor(Pred pred, std::chrono::milliseconds timeout = 5000ms) {
    const auto end = Clock::now() + timeout;
    while (Clock::now() < end) {
        if (pred()) return true;
        std::this_thread::sleep_for(2ms);
    }
    return pred();
}

double maxAbsDiff(const Joints& a, const Joints& b) {
    double m = 0.0;
    for (std::size_t i = 0; i < 6; ++i) m = std::max(m, std::abs(a[i] - b[i]));
    return m;
}

// Distance of q from the straight joint-space segment a -> b (the PTP path).
double offPath(const Joints& q, const Joints& a, const Joints& b) {
    double num = 0.0, den = 0.0;
    for (std::size_t i = 0; i < 6; ++i) {
        num += (q[i] - a[i]) * (b[i] - a[i]);
        den += (b[i] - a[i]) * (b[i] - a[i]);
    }
    const double s = den > 0.0 ? num / den : 0.0;
    double d = 0.0;
    for (std::size_t i = 0; i < 6; ++i) d = std::max(d, std::abs(a[i] + s * (b[i] - a[i]) - q[i]));
    return d;
}

struct Fixture : ::testing::Test {
    FakeArm arm{kStart};
    // Touched by the loop thread (onState) until the controller is destroyed: declared first.
    std::atomic<int> callbacks{0};
    Controller controller{arm, config()};

    void SetUp() override {
        auto r = controller.start(Clock::now() + 2s);
        ASSERT_TRUE(r.ok()) << r.error().message;
    }
    motion::Trajectory ptp(const Joints& goal, double v = 1.0, double a = 2.0) {
        auto t = motion::planPtp(arm.q(), goal, limits(v, a));
        EXPECT_TRUE(t.ok());
        return *t;
    }
    std::shared_ptr<Motion> run(motion::Trajectory t, MotionOptions o = {}) {
        auto m = controller.execute(std::move(t), o);
        EXPECT_TRUE(m.ok()) << (m.ok() ? "" : m.error().message);
        return m.ok() ? *m : nullptr;
    }
};

TEST_F(Fixture, PtpRunsToCompletionAndEndsAtTheGoal) {
    controller.onState([this](const State&) { ++callbacks; });
    const Joints goal = offset(kStart, {0.4, -0.2, 0.3, 0.0, 0.1, -0.5});
    auto m = run(ptp(goal));
    ASSERT_TRUE(m);
    auto r = m->wait(Clock::now() + 10s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kCompleted) << r->message;
    EXPECT_TRUE(m->finished());
    EXPECT_DOUBLE_EQ(m->progress(), 1.0);
    EXPECT_TRUE(waitFor([&] { return maxAbsDiff(arm.q(), goal) < 1e-9; }));
    // Every command within the limits: no step larger than vmax * dt.
    const auto cmds = arm.commands();
    for (std::size_t k = 1; k < cmds.size(); ++k) {
        ASSERT_TRUE(cmds[k].servo);
        EXPECT_LE(maxAbsDiff(cmds[k].q, cmds[k - 1].q), 1.0 * kDt + 1e-9) << k;
    }
    EXPECT_GT(callbacks.load(), 100);
    const LoopStats s = controller.stats();
    EXPECT_GT(s.cycles, 100u);
    EXPECT_GT(s.window, 100u);
    EXPECT_NEAR(s.periodMedian, kDt, 0.5e-3);
    EXPECT_GE(s.periodErrorMax, s.periodErrorP99);
    EXPECT_EQ(s.linkLosses, 0u);
    // The robot holds still afterwards (the watchdog is fed with the goal).
    const std::size_t n = arm.commandCount();
    ASSERT_TRUE(waitFor([&] { return arm.commandCount() > n + 20; }));
    const auto after = arm.commands();
    EXPECT_TRUE(after.back().servo);
    EXPECT_LT(maxAbsDiff(after.back().q, goal), 1e-12);
}

TEST_F(Fixture, HaltDeceleratesAlongThePathWithoutAJump) {
    const Joints goal = offset(kStart, {1.5, -0.5, 0.5, 0.0, 0.0, 0.0});
    auto m = run(ptp(goal, 1.0, 2.0));
    ASSERT_TRUE(m);
    ASSERT_TRUE(waitFor([&] { return m->progress() > 0.4; }));
    const std::size_t haltAt = arm.commandCount();
    m->halt();
    auto r = m->wait(Clock::now() + 10s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kHalted) << r->message;
    EXPECT_LT(m->progress(), 1.0);
    const auto cmds = arm.commands();
    ASSERT_GT(cmds.size(), haltAt + 10);
    // Axis 0 leads (1.5 rad): its step per cycle shrinks from the first cycle after halt()
    // until rest, by at most amax * dt² per cycle (no velocity jump).
    double previous = cmds[haltAt].q[0] - cmds[haltAt - 1].q[0];
    EXPECT_GT(previous, 0.5 * kDt);  // it was moving fast
    for (std::size_t k = haltAt + 1; k < cmds.size(); ++k) {
        const double step = cmds[k].q[0] - cmds[k - 1].q[0];
        EXPECT_LE(step, previous + 1e-12) << k;
        EXPECT_GE(step, -1e-12) << k;
        EXPECT_LE(std::abs(step - previous), 1.5 * 2.0 * kDt * kDt + 1e-9) << k;
        EXPECT_LT(offPath(cmds[k].q, kStart, goal), 1e-9) << k;
        previous = step;
    }
    EXPECT_LT(cmds.back().q[0], goal[0] - 0.1);  // stopped well before the goal
    EXPECT_TRUE(waitFor([&] { return maxAbsDiff(arm.q(), cmds.back().q) < 1e-12; }));
}

TEST_F(Fixture, SuspendAndResumeEndAtTheGoalOnTheSamePath) {
    const Joints goal = offset(kStart, {1.0, -0.4, 0.6, 0.2, 0.0, 0.0});
    auto m = run(ptp(goal));
    ASSERT_TRUE(m);
    ASSERT_TRUE(waitFor([&] { return m->progress() > 0.3; }));
    m->suspend();
    EXPECT_TRUE(m->suspended());
    // At rest (no change over 10 arm cycles), not finished.
    Joints last{};
    bool still = false;
    for (int i = 0; i < 250 && !still; ++i) {
        last = arm.q();
        std::this_thread::sleep_for(20ms);
        still = maxAbsDiff(arm.q(), last) < 1e-12;
    }
    ASSERT_TRUE(still);
    std::this_thread::sleep_for(50ms);
    EXPECT_FALSE(m->finished());
    EXPECT_LT(m->progress(), 1.0);
    EXPECT_LT(maxAbsDiff(arm.q(), last), 1e-12);
    m->resume();
    EXPECT_FALSE(m->suspended());
    auto r = m->wait(Clock::now() + 10s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kCompleted) << r->message;
    EXPECT_TRUE(waitFor([&] { return maxAbsDiff(arm.q(), goal) < 1e-9; }));
    for (const Command& c : arm.commands()) EXPECT_LT(offPath(c.q, kStart, goal), 1e-9);
}

TEST_F(Fixture, HaltWhileSuspendedEndsHalted) {
    auto m = run(ptp(offset(kStart, {1.0, 0, 0, 0, 0, 0})));
    ASSERT_TRUE(m);
    ASSERT_TRUE(waitFor([&] { return m->progress() > 0.2; }));
    m->suspend();
    std::this_thread::sleep_for(300ms);
    m->halt();
    auto r = m->wait(Clock::now() + 5s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kHalted);
}

TEST_F(Fixture, ForceLimitStopsTheMotionAlongThePath) {
    const Joints goal = offset(kStart, {1.2, 0.0, 0.3, 0.0, 0.0, 0.0});
    arm.forceAboveQ0 = kStart[0] + 0.4;  // contact: 40 N on z past this angle
    auto m = run(ptp(goal), MotionOptions{Eigen::Vector3d(100.0, 100.0, 30.0)});
    ASSERT_TRUE(m);
    auto r = m->wait(Clock::now() + 10s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kForceExceeded) << r->message;
    EXPECT_NEAR(r->maxForce.z(), 40.0, 1e-9);
    EXPECT_NE(r->message.find("force"), std::string::npos);
    const auto cmds = arm.commands();
    EXPECT_LT(cmds.back().q[0], goal[0] - 0.1);
    for (const Command& c : cmds) EXPECT_LT(offPath(c.q, kStart, goal), 1e-9);
    // Without a limit the same contact does not stop a motion (it is only reported).
    arm.forceAboveQ0 = 1e9;
    auto back = run(ptp(kStart));
    ASSERT_TRUE(back);
    auto rb = back->wait(Clock::now() + 10s);
    ASSERT_TRUE(rb.has_value());
    EXPECT_EQ(rb->end, MotionEnd::kCompleted);
}

TEST_F(Fixture, LinkLossFailsTheMotionAndTheControllerReconnects) {
    auto m = run(ptp(offset(kStart, {1.5, 0, 0, 0, 0, 0})));
    ASSERT_TRUE(m);
    ASSERT_TRUE(waitFor([&] { return m->progress() > 0.1; }));
    arm.linkDown = true;
    auto r = m->wait(Clock::now() + 5s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kFailed);
    EXPECT_NE(r->message.find("link to the controller lost"), std::string::npos) << r->message;
    EXPECT_TRUE(waitFor([&] { return !controller.connected(); }));
    EXPECT_FALSE(controller.execute(ptp(arm.q())).ok());  // not connected
    std::this_thread::sleep_for(300ms);                   // reconnect attempts fail meanwhile
    arm.linkDown = false;
    ASSERT_TRUE(waitFor([&] { return controller.connected(); }));
    EXPECT_GE(arm.connects(), 2);
    EXPECT_GE(controller.stats().linkLosses, 1u);
    // Usable again: a motion from where the arm stopped.
    ASSERT_TRUE(waitFor(
        [&] { return controller.state() && maxAbsDiff(controller.state()->q, arm.q()) < 1e-12; }));
    auto again = run(ptp(kStart));
    ASSERT_TRUE(again);
    auto r2 = again->wait(Clock::now() + 10s);
    ASSERT_TRUE(r2.has_value());
    EXPECT_EQ(r2->end, MotionEnd::kCompleted) << r2->message;
}

TEST_F(Fixture, SafetyStopFailsTheMotion) {
    auto m = run(ptp(offset(kStart, {1.0, 0, 0, 0, 0, 0})));
    ASSERT_TRUE(m);
    ASSERT_TRUE(waitFor([&] { return m->progress() > 0.1; }));
    arm.safety = SafetyState::kProtectiveStop;
    auto r = m->wait(Clock::now() + 5s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kFailed);
    EXPECT_NE(r->message.find("protective stop"), std::string::npos) << r->message;
    // No servo commands while the robot does not follow; refused until it does again.
    const std::size_t n = arm.commandCount();
    ASSERT_TRUE(waitFor([&] { return arm.commandCount() > n + 5; }));
    EXPECT_FALSE(arm.commands().back().servo);
    auto refused = controller.execute(ptp(arm.q()));
    ASSERT_FALSE(refused.ok());
    EXPECT_NE(refused.error().message.find("protective stop"), std::string::npos);
    arm.safety = SafetyState::kNormal;
    ASSERT_TRUE(waitFor([&] { return controller.state()->safety == SafetyState::kNormal; }));
    auto m2 = run(ptp(kStart));
    ASSERT_TRUE(m2);
    auto r2 = m2->wait(Clock::now() + 10s);
    ASSERT_TRUE(r2.has_value());
    EXPECT_EQ(r2->end, MotionEnd::kCompleted);
}

TEST_F(Fixture, ExecuteRefusesAStartElsewhereAndASecondMotion) {
    auto elsewhere = motion::planPtp(offset(kStart, {0.01, 0, 0, 0, 0, 0}),
                                     offset(kStart, {0.5, 0, 0, 0, 0, 0}), limits(1, 1));
    ASSERT_TRUE(elsewhere.ok());
    auto r = controller.execute(*elsewhere);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("starts at"), std::string::npos) << r.error().message;
    EXPECT_EQ(arm.q(), kStart);  // nothing moved

    auto m = run(ptp(offset(kStart, {0.5, 0, 0, 0, 0, 0})));
    ASSERT_TRUE(m);
    auto second = controller.execute(ptp(arm.q()));
    ASSERT_FALSE(second.ok());
    EXPECT_NE(second.error().message.find("another motion"), std::string::npos);
    EXPECT_FALSE(controller.stream(limits(1, 1)).ok());
    ASSERT_TRUE(m->wait(Clock::now() + 10s).has_value());

    EXPECT_FALSE(controller.execute(ptp(arm.q()), MotionOptions{Eigen::Vector3d(1, -1, 1)}).ok());
    motion::JointLimits bad = limits(1, 1);
    bad.maxVelocity[3] = std::nan("");
    EXPECT_FALSE(controller.stream(bad).ok());
}

TEST(Controller, RefusesBeforeStartAndReportsAFailedConnect) {
    FakeArm arm{kStart};
    Controller controller{arm, config()};
    EXPECT_FALSE(controller.connected());
    auto t = motion::planPtp(kStart, kStart, limits(1, 1));
    ASSERT_TRUE(t.ok());
    EXPECT_FALSE(controller.execute(*t).ok());
    arm.linkDown = true;
    auto r = controller.start(Clock::now() + 500ms);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("fake://arm"), std::string::npos);
}

TEST_F(Fixture, StreamFollowsTheTargetWithinTheLimitsAndHalts) {
    auto s = controller.stream(limits(0.5, 2.0));
    ASSERT_TRUE(s.ok()) << s.error().message;
    const Joints target = offset(kStart, {0.3, -0.2, 0.0, 0.0, 0.1, 0.0});
    (*s)->setTarget(target);
    ASSERT_TRUE(waitFor([&] { return maxAbsDiff(arm.q(), target) < 1e-6; }));
    auto cmds = arm.commands();
    for (std::size_t k = 2; k < cmds.size(); ++k) {
        EXPECT_LE(maxAbsDiff(cmds[k].q, cmds[k - 1].q), 0.5 * kDt + 1e-9);
        for (std::size_t i = 0; i < 6; ++i) {
            const double a = (cmds[k].q[i] - 2 * cmds[k - 1].q[i] + cmds[k - 2].q[i]) / (kDt * kDt);
            EXPECT_LE(std::abs(a), 2.0 + 1e-6) << k;
        }
    }
    EXPECT_FALSE((*s)->finished());
    // Moving again, then halted: decelerates to rest and ends kHalted.
    (*s)->setTarget(kStart);
    ASSERT_TRUE(waitFor([&] { return std::abs(arm.q()[0] - target[0]) > 0.05; }));
    (*s)->halt();
    auto r = (*s)->wait(Clock::now() + 5s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kHalted);
    EXPECT_GT(arm.q()[0], kStart[0] + 0.01);  // stopped before the new target
}

TEST_F(Fixture, WaitHonoursTheDeadlineAndTheStopToken) {
    auto m = run(ptp(offset(kStart, {1.5, 0, 0, 0, 0, 0}), 0.5, 1.0));
    ASSERT_TRUE(m);
    const auto t0 = Clock::now();
    EXPECT_FALSE(m->wait(t0 + 50ms).has_value());
    EXPECT_LT(Clock::now() - t0, 1s);
    std::stop_source stop;
    std::thread stopper([&] {
        std::this_thread::sleep_for(50ms);
        stop.request_stop();
    });
    EXPECT_FALSE(m->wait(Clock::now() + 10s, stop.get_token()).has_value());
    stopper.join();
    m->halt();
    ASSERT_TRUE(m->wait(Clock::now() + 5s).has_value());
}

TEST_F(Fixture, StopBrakesARunningMotionToRestFirst) {
    const Joints goal = offset(kStart, {1.5, 0, 0, 0, 0, 0});
    auto m = run(ptp(goal));
    ASSERT_TRUE(m);
    ASSERT_TRUE(waitFor([&] { return m->progress() > 0.3; }));
    controller.stop();
    auto r = m->wait(Clock::now() + 1s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, MotionEnd::kHalted);
    EXPECT_FALSE(controller.connected());
    const auto cmds = arm.commands();
    ASSERT_GE(cmds.size(), 3u);
    // At rest: the last step is the end of the braking ramp (a dt² / 2 with a = 2 rad/s²).
    EXPECT_LE(std::abs(cmds.back().q[0] - cmds[cmds.size() - 2].q[0]), 2.0 * kDt * kDt + 1e-12);
    EXPECT_LT(cmds.back().q[0], goal[0]);
    EXPECT_FALSE(controller.execute(ptp(arm.q())).ok());
}

}  // namespace
}  // namespace pnp::robot
