// UrHardware against the real RTDE server (pnp_rtde) on loopback, with a RegisterStore as the
// controller's variables and a trivial "controller" thread that copies the servo targets into
// actual_q every 2 ms while input_int_register_0 = 1 (what servoj would do, without limits).
#include "device/ur/ur_hardware.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <numbers>
#include <thread>

#include "robot/controller.hpp"
#include "rtde/server.hpp"

namespace pnp::device::ur {
namespace {

using namespace std::chrono_literals;
using robot::Clock;

const rtde::Vector6d kStart{0.1, -1.2, 1.4, -1.5, -1.5, 0.2};

class TrivialController {
  public:
    explicit TrivialController(rtde::ServerConfig config = {}) {
        store.set("robot_mode", std::int32_t{7});
        store.set("safety_mode", std::int32_t{1});
        store.set("runtime_state", std::uint32_t{2});
        store.set("actual_q", kStart);
        store.set("target_q", kStart);
        config.bindAddress = "127.0.0.1";
        config.port = 0;
        server = std::make_unique<rtde::Server>(config, store);
        server->start();
        thread = std::jthread([this](std::stop_token stop) { run(stop); });
    }
    ~TrivialController() {
        thread.request_stop();
        thread.join();
        server->stop();
    }
    UrConfig urConfig() const {
        UrConfig c;
        c.host = "127.0.0.1";
        c.port = server->port();
        return c;
    }

    rtde::RegisterStore store;
    std::unique_ptr<rtde::Server> server;

  private:
    void run(const std::stop_token& stop) {
        auto next = Clock::now();
        double t = 0.0;
        while (!stop.stop_requested()) {
            next += 2ms;
            std::this_thread::sleep_until(next);
            t += 0.002;
            store.set("timestamp", t);
            auto servo = store.get("input_int_register_0");
            if (servo && std::get<std::int32_t>(*servo) == 1) {
                rtde::Vector6d q{};
                for (int i = 0; i < 6; ++i)
                    q[i] =
                        std::get<double>(*store.get("input_double_register_" + std::to_string(i)));
                store.set("actual_q", q);
                store.set("target_q", q);
            }
        }
    }
    std::jthread thread;
};

template <class Pred>
bool waitFor(Pred pred, std::chrono::milliseconds timeout = 3000ms) {
    const auto end = Clock::now() + timeout;
    while (Clock::now() < end) {
        if (pred()) return true;
        std::this_thread::sleep_for(2ms);
    }
    return pred();
}

TEST(UrHardware, ConnectsAndReadsStatesAt500Hz) {
    TrivialController ctl;
    UrHardware hw(ctl.urConfig());
    auto c = hw.connect(Clock::now() + 2s);
    ASSERT_TRUE(c.ok()) << c.error().message;
    ASSERT_TRUE(hw.controllerVersion().has_value());
    EXPECT_EQ(hw.controllerVersion()->major, 5u);
    EXPECT_DOUBLE_EQ(hw.cycleTime(), 0.002);
    EXPECT_EQ(hw.endpoint(), "rtde://127.0.0.1:" + std::to_string(ctl.server->port()));
    EXPECT_EQ(hw.manufacturer(), "Universal Robots");
    EXPECT_EQ(hw.modelName(), "UR5");

    constexpr int kSamples = 500;
    const auto t0 = Clock::now();
    robot::State first, last;
    for (int k = 0; k < kSamples; ++k) {
        auto s = hw.read(Clock::now() + 100ms);
        ASSERT_TRUE(s.ok()) << s.error().message;
        if (k == 0) first = *s;
        last = *s;
    }
    const double elapsed = std::chrono::duration<double>(Clock::now() - t0).count();
    // 500 samples at 500 Hz: one second (the first may have been queued already).
    EXPECT_GT(elapsed, 0.8);
    EXPECT_LT(elapsed, 2.0);
    EXPECT_EQ(last.sequence - first.sequence, static_cast<std::uint64_t>(kSamples - 1));
    EXPECT_EQ(last.q, kStart);
    EXPECT_EQ(last.safety, robot::SafetyState::kNormal);
    EXPECT_EQ(last.program, robot::ProgramState::kRunning);
    EXPECT_TRUE(last.following);
    EXPECT_GT(last.controllerTime, first.controllerTime);
}

TEST(UrHardware, MapsTcpPoseSafetyAndProgramStates) {
    TrivialController ctl;
    // TCP at (0.3, 0.2, 0.5) turned 90° about z; the pendant's TCP is 0.1 m along the flange z.
    ctl.store.set("actual_TCP_pose", rtde::Vector6d{0.3, 0.2, 0.5, 0.0, 0.0, std::numbers::pi / 2});
    ctl.store.set("tcp_offset", rtde::Vector6d{0.0, 0.0, 0.1, 0.0, 0.0, 0.0});
    ctl.store.set("actual_TCP_force", rtde::Vector6d{1.0, -2.0, 30.0, 0.0, 0.0, 0.0});
    UrHardware hw(ctl.urConfig());
    ASSERT_TRUE(hw.connect(Clock::now() + 2s).ok());
    auto s = hw.read(Clock::now() + 100ms);
    ASSERT_TRUE(s.ok());
    EXPECT_LT((s->flange.translation() - Eigen::Vector3d(0.3, 0.2, 0.4)).norm(), 1e-12);
    EXPECT_LT((s->flange.rotation() * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(),
              1e-12);
    EXPECT_DOUBLE_EQ(s->force[2], 30.0);

    auto expectState = [&](robot::SafetyState safety, robot::ProgramState program, bool following) {
        EXPECT_TRUE(waitFor([&] {
            auto r = hw.read(Clock::now() + 100ms);
            return r.ok() && r->safety == safety && r->program == program &&
                   r->following == following;
        })) << static_cast<int>(safety)
            << " " << static_cast<int>(program);
    };
    ctl.store.set("safety_mode", std::int32_t{3});
    expectState(robot::SafetyState::kProtectiveStop, robot::ProgramState::kRunning, false);
    ctl.store.set("safety_mode", std::int32_t{7});
    expectState(robot::SafetyState::kEmergencyStop, robot::ProgramState::kRunning, false);
    ctl.store.set("safety_mode", std::int32_t{2});
    expectState(robot::SafetyState::kReduced, robot::ProgramState::kRunning, false);
    ctl.store.set("safety_mode", std::int32_t{1});
    ctl.store.set("runtime_state", std::uint32_t{4});
    expectState(robot::SafetyState::kNormal, robot::ProgramState::kPaused, false);
    ctl.store.set("runtime_state", std::uint32_t{2});
    ctl.store.set("robot_mode", std::int32_t{5});  // idle: brakes engaged
    expectState(robot::SafetyState::kNormal, robot::ProgramState::kRunning, false);
    ctl.store.set("robot_mode", std::int32_t{7});
    expectState(robot::SafetyState::kNormal, robot::ProgramState::kRunning, true);

    EXPECT_EQ(safetyFromUr(9), robot::SafetyState::kFault);
    EXPECT_EQ(safetyFromUr(5), robot::SafetyState::kProtectiveStop);
    EXPECT_EQ(safetyFromUr(42), robot::SafetyState::kUnknown);
    EXPECT_EQ(programFromUr(1), robot::ProgramState::kStopped);
}

TEST(UrHardware, WrittenCommandsAppearInTheRegisters) {
    TrivialController ctl;
    UrHardware hw(ctl.urConfig());
    ASSERT_TRUE(hw.connect(Clock::now() + 2s).ok());
    // connect() leaves the servo off.
    ASSERT_TRUE(waitFor([&] { return ctl.store.writeCount() >= 7; }));
    EXPECT_EQ(std::get<std::int32_t>(*ctl.store.get("input_int_register_0")), 0);

    const robot::Joints target{0.15, -1.1, 1.3, -1.4, -1.6, 0.25};
    ASSERT_TRUE(hw.write(robot::Command{true, target}, Clock::now() + 100ms).ok());
    ASSERT_TRUE(waitFor(
        [&] { return std::get<std::int32_t>(*ctl.store.get("input_int_register_0")) == 1; }));
    for (int i = 0; i < 6; ++i)
        EXPECT_EQ(std::get<double>(*ctl.store.get("input_double_register_" + std::to_string(i))),
                  target[i]);
    EXPECT_TRUE(waitFor([&] {
        auto s = hw.read(Clock::now() + 100ms);
        return s.ok() && s->q == target;
    }));

    ASSERT_TRUE(hw.write(robot::Command{}, Clock::now() + 100ms).ok());
    EXPECT_TRUE(waitFor(
        [&] { return std::get<std::int32_t>(*ctl.store.get("input_int_register_0")) == 0; }));
    // A non-finite target never reaches the controller.
    robot::Joints bad = target;
    bad[2] = std::nan("");
    auto w = hw.write(robot::Command{true, bad}, Clock::now() + 100ms);
    ASSERT_FALSE(w.ok());
    EXPECT_NE(w.error().message.find("non-finite"), std::string::npos);
}

TEST(UrHardware, InUseInputsGiveAClearError) {
    TrivialController ctl;
    UrHardware first(ctl.urConfig());
    ASSERT_TRUE(first.connect(Clock::now() + 2s).ok());
    UrHardware second(ctl.urConfig());
    auto r = second.connect(Clock::now() + 2s);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("input_int_register_0: IN_USE — another RTDE client or the "
                                     "teach pendant program uses it"),
              std::string::npos)
        << r.error().message;
    EXPECT_FALSE(second.read(Clock::now() + 10ms).ok());
    // Free again once the first client has gone.
    first.disconnect();
    EXPECT_TRUE(waitFor([&] { return second.connect(Clock::now() + 1s).ok(); }));
}

TEST(UrHardware, RefusedFrequencyAndUnknownModel) {
    rtde::ServerConfig cb3;
    cb3.maxFrequency = 125.0;
    TrivialController ctl(cb3);
    UrHardware hw(ctl.urConfig());
    auto r = hw.connect(Clock::now() + 2s);
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("500 Hz"), std::string::npos) << r.error().message;
    UrConfig slow = ctl.urConfig();
    slow.frequency = 125.0;
    UrHardware ok(slow);
    ASSERT_TRUE(ok.connect(Clock::now() + 2s).ok());
    EXPECT_DOUBLE_EQ(ok.cycleTime(), 0.008);

    EXPECT_EQ(modelByName("UR10e")->name, "UR10");
    EXPECT_EQ(modelByName("ur3")->name, "UR3");
    EXPECT_FALSE(modelByName("ur7").has_value());
    UrConfig bad = ctl.urConfig();
    bad.frequency = std::nan("");
    EXPECT_FALSE(UrHardware(bad).connect(Clock::now() + 1s).ok());
}

TEST(UrHardware, TimeoutsAreHonoured) {
    // A listener that accepts and never answers: the handshake times out at the deadline.
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    ASSERT_GE(fd, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    ASSERT_EQ(::listen(fd, 4), 0);
    socklen_t len = sizeof addr;
    ASSERT_EQ(::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len), 0);
    UrConfig silent;
    silent.port = ntohs(addr.sin_port);
    silent.requestTimeout = 5000ms;
    UrHardware hw(silent);
    auto t0 = Clock::now();
    auto r = hw.connect(t0 + 200ms);
    auto took = Clock::now() - t0;
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.error().message.find("timeout"), std::string::npos) << r.error().message;
    EXPECT_GE(took, 190ms);
    EXPECT_LT(took, 1000ms);
    // requestTimeout bounds each request below the caller's deadline.
    silent.requestTimeout = 100ms;
    UrHardware quick(silent);
    t0 = Clock::now();
    EXPECT_FALSE(quick.connect(t0 + 5s).ok());
    EXPECT_LT(Clock::now() - t0, 1000ms);
    ::close(fd);

    // A slow stream (1 Hz): a read with a 100 ms deadline returns at it.
    TrivialController ctl;
    UrConfig oneHz = ctl.urConfig();
    oneHz.frequency = 1.0;
    UrHardware slow(oneHz);
    ASSERT_TRUE(slow.connect(Clock::now() + 2s).ok());
    (void)slow.read(Clock::now() + 1500ms);  // the first sample
    t0 = Clock::now();
    auto s = slow.read(t0 + 100ms);
    took = Clock::now() - t0;
    ASSERT_FALSE(s.ok());
    EXPECT_NE(s.error().message.find("before the deadline"), std::string::npos);
    EXPECT_GE(took, 90ms);
    EXPECT_LT(took, 600ms);

    // Nobody listening: refused at once.
    UrConfig closed = ctl.urConfig();
    ctl.server->stop();
    t0 = Clock::now();
    auto c = UrHardware(closed).connect(t0 + 2s);
    ASSERT_FALSE(c.ok());
    EXPECT_NE(c.error().message.find("cannot reach the UR controller"), std::string::npos);
    EXPECT_LT(Clock::now() - t0, 1000ms);
}

// The whole chain: the vendor-neutral loop drives the RTDE "controller" to a goal.
TEST(UrHardware, ControllerRunsAPtpOverRtde) {
    TrivialController ctl;
    UrHardware hw(ctl.urConfig());
    robot::ControllerConfig cc;
    robot::Controller controller(hw, cc);
    auto started = controller.start(Clock::now() + 2s);
    ASSERT_TRUE(started.ok()) << started.error().message;
    robot::Joints goal = kStart;
    goal[0] += 0.3;
    goal[2] -= 0.2;
    motion::JointLimits l;
    l.maxVelocity.fill(1.0);
    l.maxAcceleration.fill(2.0);
    auto t = motion::planPtp(controller.state()->q, goal, l);
    ASSERT_TRUE(t.ok());
    auto m = controller.execute(*t);
    ASSERT_TRUE(m.ok()) << m.error().message;
    auto r = (*m)->wait(Clock::now() + 10s);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->end, robot::MotionEnd::kCompleted) << r->message;
    EXPECT_TRUE(waitFor([&] {
        auto q = std::get<rtde::Vector6d>(*ctl.store.get("actual_q"));
        for (int i = 0; i < 6; ++i)
            if (std::abs(q[i] - goal[i]) > 1e-9) return false;
        return true;
    }));
    const robot::LoopStats s = controller.stats();
    EXPECT_GT(s.window, 100u);
    EXPECT_NEAR(s.periodMedian, 0.002, 0.5e-3);
    controller.stop();
}

}  // namespace
}  // namespace pnp::device::ur
