// The simulated UR controller behind the real RTDE server, driven over loopback sockets by the
// real RTDE client, with the controller and the world stepped every 2 ms on their own thread,
// as the simulator runs them.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <limits>
#include <optional>

#include "rtde/server.hpp"
#include "sim/ur/ur_controller.hpp"
#include "sim_helpers.hpp"

namespace pnp::sim::ur::test {
namespace {

using Clock = std::chrono::steady_clock;
constexpr double kEps = 1e-12;

rtde::ServerConfig loopback() {
    rtde::ServerConfig c;
    c.bindAddress = "127.0.0.1";
    c.port = 0;
    c.externalCycle = true;  // as pnp sim: the state goes out after every step
    return c;
}

// World, controller, RTDE server on an ephemeral port, stepping thread. Members are destroyed
// in reverse: the stepper stops first, then the server, before the controller goes.
struct Cell {
    explicit Cell(UrControllerConfig config, world::CellDescription cell = thesisCell())
        : world(std::move(cell)), ur(world, config), server(loopback(), ur) {
        const auto& limits = world.description().robots[0].model.limits;
        for (std::size_t j = 0; j < 6; ++j) {
            vmax[j] = limits[j].maxVelocity;
            amax[j] = 4 * limits[j].maxAcceleration;
        }
        server.start();
        stepper.emplace(world, ur, 20000, [this] { server.cycle(); });
    }
    Joints home() const { return world.description().robots[0].home; }

    // Every recorded step within the controller's limits: speed, step size, acceleration.
    void checkLimits(const std::vector<Sample>& samples) const {
        for (std::size_t i = 1; i < samples.size(); ++i) {
            for (std::size_t j = 0; j < 6; ++j) {
                const Sample& a = samples[i - 1];
                const Sample& b = samples[i];
                ASSERT_LE(std::abs(b.qd[j]), vmax[j] + kEps) << "step " << i << " joint " << j;
                ASSERT_LE(std::abs(b.q[j] - a.q[j]), vmax[j] * kDt + kEps)
                    << "step " << i << " joint " << j;
                ASSERT_LE(std::abs(b.qd[j] - a.qd[j]), amax[j] * kDt + 1e-9)
                    << "step " << i << " joint " << j;
            }
        }
    }

    world::World world;
    UrController ur;
    rtde::Server server;
    std::optional<Stepper> stepper;
    Joints vmax{};
    Joints amax{};
};

bool atRest(const Sample& s) { return s.qd == Joints{}; }

UrControllerConfig patientWatchdog() {
    // Tests that are not about the watchdog: a loaded machine may delay the sender.
    UrControllerConfig c;
    c.watchdogTimeout = 2.0;
    return c;
}

// Sends (mode, targets(t)) every 2 ms for `duration` of real time; t is the time since the
// start in s. False if a send failed.
template <class Targets>
bool stream(Session& session, std::int32_t mode, std::chrono::milliseconds duration,
            Targets targets) {
    const auto start = Clock::now();
    double t0 = -1.0;
    for (int i = 0; i < 100000; ++i) {
        // One target per published state, as the adapter's control loop streams, for the
        // controller's time of that state (wall-clock time would make an uneven, infeasible
        // stream out of a smooth one), stamped with it.
        const auto sample = session.next(100ms);
        if (!sample) return false;
        const double now = Session::get<double>(*sample, "timestamp");
        if (t0 < 0.0) t0 = now;
        if (Clock::now() - start >= duration) return true;
        if (!session.send(mode, targets(now - t0))) return false;
    }
    return true;
}

TEST(UrRtde, HandshakeAndOutputs) {
    Cell cell(patientWatchdog());
    Session session;
    ASSERT_TRUE(session.open(cell.server.port()));
    const auto first = session.latest();
    ASSERT_TRUE(first.has_value());
    EXPECT_EQ(Session::get<std::int32_t>(*first, "robot_mode"), 7);
    EXPECT_EQ(Session::get<std::int32_t>(*first, "safety_mode"), 1);
    EXPECT_EQ(Session::get<std::uint32_t>(*first, "runtime_state"), 2u);
    EXPECT_EQ(Session::get<rtde::Vector6d>(*first, "actual_q"), cell.home());
    EXPECT_EQ(Session::get<rtde::Vector6d>(*first, "target_q"), cell.home());
    EXPECT_EQ(Session::get<rtde::Vector6d>(*first, "actual_qd"), rtde::Vector6d{});
    EXPECT_EQ(Session::get<rtde::Vector6d>(*first, "tcp_offset"), rtde::Vector6d{});
    EXPECT_EQ(Session::get<rtde::Vector6d>(*first, "actual_TCP_force"), rtde::Vector6d{});
    EXPECT_EQ(Session::get<rtde::Vector6d>(*first, "actual_TCP_speed"), rtde::Vector6d{});
    const auto pose = Session::get<rtde::Vector6d>(*first, "actual_TCP_pose");
    EXPECT_EQ(Session::get<rtde::Vector6d>(*first, "target_TCP_pose"), pose);
    const Eigen::Isometry3d fk =
        kinematics::forward(cell.world.description().robots[0].model, cell.home());
    EXPECT_NEAR(pose[0], fk.translation().x(), 1e-12);
    EXPECT_NEAR(pose[1], fk.translation().y(), 1e-12);
    EXPECT_NEAR(pose[2], fk.translation().z(), 1e-12);
    // Simulated time goes on.
    const double t0 = Session::get<double>(*first, "timestamp");
    ASSERT_TRUE(cell.stepper->waitSteps(50, 3000ms));
    const auto later = session.latest();
    ASSERT_TRUE(later.has_value());
    EXPECT_GT(Session::get<double>(*later, "timestamp"), t0);
}

TEST(UrRtde, FollowsAStreamedRampAndConverges) {
    Cell cell(patientWatchdog());
    Session session;
    ASSERT_TRUE(session.open(cell.server.port()));
    const Joints home = cell.home();
    const Joints delta{0.4, -0.2, 0.1, 0.0, 0.3, 0.6};
    // A smooth ramp that ends at rest (at most 1.125 rad/s, 5.6 rad/s²: within the limits). A
    // stream that stops dead at speed cannot be followed without passing its end; one that
    // brakes within the limits must be followed without passing it.
    const double duration = 0.8;
    auto ramp = [&](double t) {
        Joints q = home;
        const double u = std::min(t / duration, 1.0);
        const double s = u * u * (3.0 - 2.0 * u);
        for (std::size_t j = 0; j < 6; ++j) q[j] += s * delta[j];
        return q;
    };
    Joints final = ramp(duration);
    ASSERT_TRUE(stream(session, 1, 1000ms, ramp));
    EXPECT_TRUE(cell.ur.following());
    // actual_q (over RTDE) converges on the end of the ramp.
    bool converged = false;
    for (int i = 0; i < 1500 && !converged; ++i) {
        ASSERT_TRUE(session.send(1, final));
        const auto sample = session.latest(200ms);
        ASSERT_TRUE(sample.has_value());
        const auto q = Session::get<rtde::Vector6d>(*sample, "actual_q");
        converged = true;
        for (std::size_t j = 0; j < 6; ++j)
            converged = converged && std::abs(q[j] - final[j]) < 1e-9;
        std::this_thread::sleep_for(2ms);
    }
    EXPECT_TRUE(converged);
    cell.stepper->stop();
    const std::vector<Sample> samples = cell.stepper->samples();
    ASSERT_GT(samples.size(), 100u);
    cell.checkLimits(samples);
    // The ramp is monotonic: the robot never passes its end — unless the stream ran dry (the
    // client later than the jitter buffer holds, e.g. on a loaded CI machine): then it coasts
    // on for at most two steps before braking, and passes the end by no more than that.
    const bool starved = cell.ur.starvedSteps() > 0;
    Joints fastest{};
    for (const Sample& s : samples)
        for (std::size_t j = 0; j < 6; ++j) fastest[j] = std::max(fastest[j], std::abs(s.qd[j]));
    for (const Sample& s : samples) {
        for (std::size_t j = 0; j < 6; ++j) {
            const double slack = starved ? 2.0 * fastest[j] * kDt : kEps;
            if (delta[j] > 0) {
                ASSERT_LE(s.q[j], final[j] + std::max(kEps, slack)) << "starved " << starved;
            } else if (delta[j] < 0) {
                ASSERT_GE(s.q[j], final[j] - std::max(kEps, slack)) << "starved " << starved;
            }
        }
    }
    EXPECT_FALSE(cell.ur.watchdogTripped());
}

TEST(UrRtde, WatchdogStopsTheRobotWhenInputsStop) {
    UrControllerConfig config;
    config.watchdogTimeout = 0.1;
    Cell cell(config);
    Session session;
    ASSERT_TRUE(session.open(cell.server.port()));
    const Joints far = [&] {
        Joints q = cell.home();
        q[0] += 2.0;
        q[1] -= 0.5;
        return q;
    }();
    ASSERT_TRUE(stream(session, 1, 300ms, [&](double) { return far; }));
    ASSERT_GT(std::abs(cell.stepper->last().qd[0]), 0.5);  // moving fast
    const std::size_t silenceFrom = cell.stepper->count();

    // Silence: the watchdog trips and the robot brakes to rest.
    ASSERT_TRUE(waitFor([&] { return cell.ur.watchdogTripped(); }, 3000ms));
    EXPECT_FALSE(cell.ur.following());
    ASSERT_TRUE(waitFor([&] { return atRest(cell.stepper->last()); }, 3000ms));
    const Joints rest = cell.stepper->last().q;
    {
        const std::vector<Sample> samples = cell.stepper->samples();
        cell.checkLimits(samples);
        std::size_t firstRest = silenceFrom;
        while (firstRest < samples.size() && !atRest(samples[firstRest])) ++firstRest;
        // Within the timeout (50 steps) + braking from π rad/s at 4π rad/s² (125 steps) + the
        // last packages in flight.
        EXPECT_LE(firstRest - silenceFrom, 50u + 125u + 25u);
    }

    // Inputs again with the register at 1: ignored.
    const Joints back = cell.home();
    ASSERT_TRUE(stream(session, 1, 200ms, [&](double) { return back; }));
    EXPECT_EQ(cell.stepper->last().q, rest);
    EXPECT_TRUE(cell.ur.watchdogTripped());
    const auto sample = session.latest();
    ASSERT_TRUE(sample.has_value());
    EXPECT_EQ(Session::get<rtde::Vector6d>(*sample, "actual_q"), rest);

    // Re-arm: 0, then 1: it follows again.
    ASSERT_TRUE(stream(session, 0, 20ms, [&](double) { return back; }));
    EXPECT_EQ(cell.stepper->last().q, rest);
    ASSERT_TRUE(stream(session, 1, 200ms, [&](double) { return back; }));
    EXPECT_FALSE(cell.ur.watchdogTripped());
    EXPECT_TRUE(cell.ur.following());
    EXPECT_NE(cell.stepper->last().q, rest);
    cell.stepper->stop();
    cell.checkLimits(cell.stepper->samples());
}

TEST(UrRtde, BadTargetsDoNotMoveTheRobot) {
    Cell cell(patientWatchdog());
    Session session;
    ASSERT_TRUE(session.open(cell.server.port()));
    const Joints home = cell.home();
    Joints nan = home;
    nan[4] = std::numeric_limits<double>::quiet_NaN();
    Joints beyond = home;
    beyond[0] = 6.5;  // the limit is 2π
    ASSERT_TRUE(stream(session, 1, 200ms, [&](double) { return nan; }));
    EXPECT_GT(cell.ur.rejectedTargets(), 0u);
    const std::uint64_t rejected = cell.ur.rejectedTargets();
    ASSERT_TRUE(stream(session, 1, 200ms, [&](double) { return beyond; }));
    EXPECT_GT(cell.ur.rejectedTargets(), rejected);
    EXPECT_TRUE(cell.ur.following());
    const auto sample = session.latest();
    ASSERT_TRUE(sample.has_value());
    EXPECT_EQ(Session::get<rtde::Vector6d>(*sample, "actual_q"), home);
    cell.stepper->stop();
    const std::vector<Sample> samples = cell.stepper->samples();
    ASSERT_GT(samples.size(), 50u);
    for (const Sample& s : samples) {
        ASSERT_EQ(s.q, home);
        ASSERT_TRUE(atRest(s));
    }
}

TEST(UrRtde, ProtectiveStopWhenTheTcpIsDrivenIntoTheTable) {
    world::CellDescription description = thesisCell();
    // Start 5 mm above the table, flange down, away from the cube.
    const Joints start = flangeAt(description, {0.1, -0.1, 0.005}, description.robots[0].home);
    description.robots[0].home = start;
    Cell cell(patientWatchdog(), description);
    Session session;
    ASSERT_TRUE(session.open(cell.server.port()));
    // Down at 2 cm/s of simulated time (250 N = 12.5 mm deep after about 0.9 s), then on
    // down. Simulated, not real time: a stalled stepping thread must not make the target run
    // ahead (the robot would catch up at full speed and brake deeper).
    const world::CellDescription& d = cell.world.description();
    auto down = [&](double t) { return flangeAt(d, {0.1, -0.1, 0.005 - 0.02 * t}, start); };
    const auto begin = Clock::now();
    bool stopped = false;
    for (int i = 0; i < 5000 && !stopped; ++i) {
        ASSERT_LT(Clock::now() - begin, 20s);
        // One target per published state, for (and stamped with) its time.
        const auto sample = session.next(100ms);
        ASSERT_TRUE(sample.has_value());
        ASSERT_TRUE(session.send(1, down(Session::get<double>(*sample, "timestamp"))));
        stopped = cell.ur.protectiveStop();
    }
    ASSERT_TRUE(stopped);
    // Reported over RTDE: safety mode 3, the contact force in the base frame.
    std::optional<rtde::DataSample> report;
    ASSERT_TRUE(waitFor(
        [&] {
            report = session.latest(100ms);
            return report && Session::get<std::int32_t>(*report, "safety_mode") == 3;
        },
        3000ms));
    EXPECT_GT(Session::get<rtde::Vector6d>(*report, "actual_TCP_force")[2], 250.0);
    // It brakes to rest and stays there, whatever is streamed.
    const double tStop = static_cast<double>(cell.stepper->count()) * kDt;
    ASSERT_TRUE(stream(session, 1, 300ms, [&](double t) { return down(tStop + t); }));
    ASSERT_TRUE(atRest(cell.stepper->last()));
    const Joints rest = cell.stepper->last().q;
    ASSERT_TRUE(stream(session, 1, 200ms, [&](double t) { return down(tStop + 0.3 + t); }));
    EXPECT_EQ(cell.stepper->last().q, rest);
    EXPECT_TRUE(cell.ur.protectiveStop());
    EXPECT_GT(cell.stepper->last().force, 250.0);
    EXPECT_LT(cell.stepper->last().force, 300.0);  // stopped within a few steps
    cell.stepper->stop();
    cell.checkLimits(cell.stepper->samples());
}

}  // namespace
}  // namespace pnp::sim::ur::test
