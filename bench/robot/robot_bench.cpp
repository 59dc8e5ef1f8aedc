// pnp_bench_robot: the robot chain of the simulated cell without OPC UA — the world and the
// simulated UR controller stepped at 500 Hz behind a real RTDE server, the UR hardware
// interface and the vendor-neutral control loop on the other side of a loopback socket:
//   (a) the thesis's square (PTP to a corner, LIN along four edges at 0.1 m/s): the largest
//       distance of the world's flange from the ideal square at every world step, and the
//       end pose error of every move;
//   (b) the control loop's period error (p99 over --seconds, default 60), next to a plain
//       sleep_until loop at the same 2 ms measured in the same run (what the machine gives);
//   (c) execute() -> first moving target seen by the controller (RTDE input register),
//       median of 50, next to the RTDE round trip (output sample -> input seen) measured
//       the same way;
//   (d) halt() -> the first commanded target at which the acceleration drops;
//   (e) the CPU of a `pnp sim` process (stepping, RTDE, ground-truth server) per wall
//       second, % of a core, with an adapter streaming at 500 Hz, next to a bare 500 Hz sleep
//       loop's; (b) is measured on that adapter's loop;
//   (f) a JointPtpMove skill's Start call over OPC UA -> the first moving target at the
//       controller, next to a Read round trip of the same client.
// Usage: pnp_bench_robot [--seconds N]
#include <pthread.h>
#include <signal.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <numbers>
#include <string>
#include <thread>
#include <vector>

#include "device/robot/robot_device.hpp"
#include "device/ur/ur_hardware.hpp"
#include "robot/controller.hpp"
#include "robot/planner.hpp"
#include "rtde/server.hpp"
#include "sim/cell/simulator.hpp"
#include "sim/ur/ur_controller.hpp"
#include "skill/client/skill_client.hpp"
#include "ua/client/client.hpp"
#include "ua/server/server.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"

namespace {

using namespace std::chrono;
using Clock = steady_clock;
using pnp::kinematics::Joints;

double threadCpuSeconds(pthread_t thread) {
    clockid_t id;
    if (pthread_getcpuclockid(thread, &id) != 0) return 0.0;
    timespec ts{};
    clock_gettime(id, &ts);
    return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
}

double quantile(std::vector<double> v, double q) {
    if (v.empty()) return 0.0;
    const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5);
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
    return v[k];
}

// The simulated cell in process (as `pnp sim` runs it), with a hook on every world step.
class Cell {
  public:
    explicit Cell(pnp::world::CellDescription cell) : sim_(std::move(cell), config(this)) {}
    void start() { sim_.start(); }
    void stop() { sim_.stop(); }
    std::uint16_t port() const { return sim_.endpoints().at(0).port; }
    const pnp::sim::ur::UrController& controller() const { return sim_.urController(0); }
    // At rest only (a snapshot, up to 8 ms old).
    Eigen::Isometry3d tcp() const { return sim_.snapshot()->robots.at(0).tcp; }
    void onStep(std::function<void(const pnp::world::World&)> f) {
        std::lock_guard lock(hookMutex_);
        hook_ = std::move(f);
    }

  private:
    static pnp::sim::cell::SimulatorConfig config(Cell* self) {
        pnp::sim::cell::SimulatorConfig c;
        c.ephemeralPorts = true;
        c.onStep = [self](const pnp::world::World& w) {
            std::lock_guard lock(self->hookMutex_);
            if (self->hook_) self->hook_(w);
        };
        return c;
    }
    std::mutex hookMutex_;
    std::function<void(const pnp::world::World&)> hook_;
    pnp::sim::cell::Simulator sim_;
};

// CPU seconds (user + system) of a process so far, from /proc.
double processCpuSeconds(pid_t pid) {
    std::FILE* f = std::fopen(("/proc/" + std::to_string(pid) + "/stat").c_str(), "r");
    if (!f) return 0.0;
    char buf[4096];
    const std::size_t n = std::fread(buf, 1, sizeof buf - 1, f);
    std::fclose(f);
    buf[n] = 0;
    const char* p = std::strrchr(buf, ')');  // the command name may hold spaces
    if (!p) return 0.0;
    unsigned long utime = 0, stime = 0;
    // Fields after the name: state(3) ... utime(14) stime(15).
    std::sscanf(p + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %lu %lu", &utime, &stime);
    return static_cast<double>(utime + stime) / static_cast<double>(sysconf(_SC_CLK_TCK));
}

double segmentDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                       const Eigen::Vector3d& b) {
    const Eigen::Vector3d ab = b - a;
    const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
    return (a + t * ab - p).norm();
}

Eigen::Isometry3d downAt(const Eigen::Vector3d& p) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX()).toRotationMatrix();
    t.translation() = p;
    return t;
}

bool runMotion(pnp::robot::Controller& c, pnp::robot::Result<pnp::motion::Trajectory> plan,
               const char* what) {
    if (!plan) {
        std::fprintf(stderr, "%s: %s\n", what, plan.error().message.c_str());
        return false;
    }
    auto m = c.execute(std::move(plan).value());
    if (!m) {
        std::fprintf(stderr, "%s: %s\n", what, m.error().message.c_str());
        return false;
    }
    auto r = (*m)->wait(Clock::now() + 60s);
    if (!r || r->end != pnp::robot::MotionEnd::kCompleted) {
        std::fprintf(stderr, "%s did not complete: %s\n", what, r ? r->message.c_str() : "timeout");
        return false;
    }
    return true;
}

}  // namespace

int main(int argc, char** argv) {
    int seconds = 60;
    for (int i = 1; i + 1 < argc; ++i)
        if (std::strcmp(argv[i], "--seconds") == 0) seconds = std::max(1, std::atoi(argv[i + 1]));

    auto cellFile = pnp::world::loadCellFile(PNP_THESIS_CELL);
    if (!cellFile) {
        std::fprintf(stderr, "%s\n", cellFile.error().message.c_str());
        return 1;
    }
    const auto description = cellFile.value();
    const auto& robot = description.robots.at(0);
    Cell cell(description);
    cell.start();

    pnp::device::ur::UrConfig uc;
    uc.host = "127.0.0.1";
    uc.port = cell.port();
    uc.model = robot.model;
    pnp::device::ur::UrHardware hardware(uc);
    pnp::robot::ControllerConfig cc;
    for (int i = 0; i < 6; ++i) {
        cc.limits.maxVelocity[i] = robot.model.limits[i].maxVelocity;
        cc.limits.maxAcceleration[i] = robot.model.limits[i].maxAcceleration;
    }
    pnp::robot::Controller controller(hardware, cc);
    if (auto s = controller.start(Clock::now() + 5s); !s) {
        std::fprintf(stderr, "controller: %s\n", s.error().message.c_str());
        return 1;
    }
    pnp::robot::PlannerConfig pc;
    pc.model = robot.model;
    pc.worldToBase = robot.base;
    pc.defaults.joint = cc.limits;
    pnp::robot::Planner planner(pc);
    auto current = [&] { return controller.state()->q; };

    std::printf("%-52s %12s %12s %8s\n", "figure", "value", "baseline", "ratio");

    // (a) the square.
    const Eigen::Vector3d centre(0.0, 0.35, 0.25);
    const double h = 0.05;
    const std::vector<Eigen::Vector3d> corners = {
        centre + Eigen::Vector3d(-h, h, 0), centre + Eigen::Vector3d(h, h, 0),
        centre + Eigen::Vector3d(h, -h, 0), centre + Eigen::Vector3d(-h, -h, 0)};
    std::mutex m;
    bool recording = false;
    double deviation = 0.0;
    std::size_t steps = 0;
    cell.onStep([&](const pnp::world::World& w) {
        std::lock_guard lock(m);
        if (!recording) return;
        const Eigen::Vector3d p = w.robot(0).tcp.translation();
        double d = 1e9;
        for (int k = 0; k < 4; ++k)
            d = std::min(d, segmentDistance(p, corners[k], corners[(k + 1) % 4]));
        deviation = std::max(deviation, d);
        ++steps;
    });
    auto endError = [&](const Eigen::Vector3d& goal) {
        std::this_thread::sleep_for(20ms);
        return (cell.tcp().translation() - goal).norm();
    };
    pnp::robot::CartesianTarget t;
    t.pose = downAt(corners[0]);
    double ptpError = 0.0, linError = 0.0;
    if (!runMotion(controller, planner.cartesianPtp(current(), t, {}), "PTP")) return 1;
    ptpError = endError(corners[0]);
    {
        std::lock_guard lock(m);
        recording = true;
    }
    pnp::robot::LinLimits ll;
    ll.maxVelocity = {0.1};
    for (int k = 1; k <= 4; ++k) {
        t.pose = downAt(corners[k % 4]);
        if (!runMotion(controller, planner.cartesianLinear(current(), t, ll), "LIN")) return 1;
        linError = std::max(linError, endError(corners[k % 4]));
    }
    {
        std::lock_guard lock(m);
        recording = false;
    }
    cell.onStep({});
    std::printf("%-52s %12.4f %12s %8s\n", "(a) LIN deviation from the square, mm (world)",
                deviation * 1e3, "-", "-");
    std::printf("%-52s %12.5f %12s %8s\n", "(a) PTP end pose error, mm", ptpError * 1e3, "-", "-");
    std::printf("%-52s %12.5f %12s %8s\n", "(a) LIN end pose error (max of 4), mm", linError * 1e3,
                "-", "-");
    std::printf("%-52s %12zu\n", "(a) world steps checked", steps);
    std::printf("%-52s %12llu\n", "(a) steps without a target (adapter late)",
                static_cast<unsigned long long>(cell.controller().starvedSteps()));
    std::printf("%-52s %12llu\n", "(a) targets dropped as late",
                static_cast<unsigned long long>(cell.controller().lateTargets()));

    // (c) execute() -> the first moving target at the controller, and (d) halt() -> the first
    // smaller step: targets watched by polling the simulated controller's input registers.
    auto target0 = [&] {
        auto v = cell.controller().input("input_double_register_0");
        return v ? std::get<double>(*v) : 0.0;
    };
    std::vector<double> startLatency, haltLatency;
    for (int rep = 0; rep < 50; ++rep) {
        Joints goal = current();
        goal[0] += (rep % 2 == 0 ? 0.6 : -0.6);
        auto plan = planner.jointPtp(current(), std::vector<double>(goal.begin(), goal.end()), {});
        if (!plan) return 1;
        const double before = target0();
        const auto t0 = Clock::now();
        auto motion = controller.execute(std::move(plan).value());
        if (!motion) return 1;
        while (target0() == before && Clock::now() - t0 < 1s) std::this_thread::yield();
        startLatency.push_back(duration<double, std::milli>(Clock::now() - t0).count());
        // Moving, then halt: the first target at which the arm's acceleration drops (the
        // second difference of the targets; accelerating +a·dt², cruising 0, braking -a·dt²),
        // judged against the three targets before the call.
        std::this_thread::sleep_for(300ms);
        auto nextTarget = [&](double from) {
            double now = target0();
            for (int spin = 0; now == from && spin < 10000000; ++spin) {
                std::this_thread::yield();
                now = target0();
            }
            return now;
        };
        const double z = nextTarget(target0());
        const double a = nextTarget(z);
        double b = nextTarget(a);
        const double trend = (b - a) - (a - z);
        double previousStep = b - a;
        const auto h0 = Clock::now();
        (*motion)->halt();
        for (int k = 0; k < 100 && Clock::now() - h0 < 1s; ++k) {
            const double c = nextTarget(b);
            const double second = (c - b) - previousStep;
            if (std::abs(second - trend) > 1e-7) break;
            previousStep = c - b;
            b = c;
        }
        haltLatency.push_back(duration<double, std::milli>(Clock::now() - h0).count());
        (*motion)->wait(Clock::now() + 10s);
    }
    std::printf("%-52s %12.3f %12.3f %8.2f\n", "(c) execute -> first moving target, ms (median)",
                quantile(startLatency, 0.5), 2.0, quantile(startLatency, 0.5) / 2.0);
    std::printf("%-52s %12.3f %12.3f %8.2f\n", "(d) halt -> first braking target, ms (median)",
                quantile(haltLatency, 0.5), 2.0, quantile(haltLatency, 0.5) / 2.0);
    std::printf("%-52s %12.3f %12.3f %8.2f\n", "(d) halt -> first braking target, ms (max)",
                *std::max_element(haltLatency.begin(), haltLatency.end()), 2.0,
                *std::max_element(haltLatency.begin(), haltLatency.end()) / 2.0);

    // (f) The skill's Start call (OPC UA, from a client on loopback) -> the first moving
    // target at the controller: the adapter as a whole (method call, parameters, planning,
    // hand-over to the loop, the next cycle). Baseline: a Read round trip of the same client.
    std::vector<double> skillLatency, readRtt;
    {
        pnp::ua::server::ServerConfig sc;
        sc.host = "127.0.0.1";
        sc.publicHost = "127.0.0.1";
        sc.port = 0;
        pnp::ua::server::Server server(sc);
        auto device = std::make_unique<pnp::device::robot::RobotDevice>(
            server, controller, planner,
            pnp::device::robot::RobotDeviceOptions{
                .name = "UR5", .identity = pnp::device::robot::identityOf(hardware)});
        server.start();
        auto ua = std::make_shared<pnp::ua::client::Client>();
        ua->connect("opc.tcp://127.0.0.1:" + std::to_string(server.port()));
        pnp::skill::client::SkillClient skill(
            ua, device->skillNode(pnp::device::robot::skill_names::JointPtpMove));
        for (int rep = 0; rep < 30; ++rep) {
            Joints goal = current();
            goal[0] += (rep % 2 == 0 ? 0.3 : -0.3);
            skill.setParameter("TargetJointPosition",
                               pnp::ua::Variant(std::vector<double>(goal.begin(), goal.end())));
            const double before = target0();
            const auto t0 = Clock::now();
            skill.start();
            while (target0() == before && Clock::now() - t0 < 1s) std::this_thread::yield();
            skillLatency.push_back(duration<double, std::milli>(Clock::now() - t0).count());
            for (int i = 0; i < 500; ++i) {
                if (skill.state() == pnp::skill::ProgramState::Ready) break;
                std::this_thread::sleep_for(10ms);
            }
            const auto r0 = Clock::now();
            (void)ua->readValue(pnp::ua::NodeId(0, 2258));  // Server_ServerStatus_CurrentTime
            readRtt.push_back(duration<double, std::milli>(Clock::now() - r0).count());
        }
        ua->disconnect();
        device.reset();
        server.stop();
    }
    std::printf("%-52s %12.3f %12.3f %8.2f\n", "(f) skill Start -> first moving target, ms",
                quantile(skillLatency, 0.5), quantile(readRtt, 0.5),
                quantile(skillLatency, 0.5) / std::max(1e-9, quantile(readRtt, 0.5)));

    controller.stop();
    cell.stop();

    // (b) + (e): `pnp sim` as a process, as a user runs it, with a fresh adapter loop holding
    // the robot for `seconds` (streaming at 500 Hz): the loop's period error and the whole
    // simulator process's CPU (stepping, RTDE, the ground truth's OPC UA server).
    int toChild[2];
    if (::pipe(toChild) != 0) return 1;
    const pid_t pid = ::fork();
    if (pid == 0) {
        ::dup2(toChild[1], STDOUT_FILENO);
        ::close(toChild[0]);
        ::execl(PNP_BENCH_PNP_EXE, PNP_BENCH_PNP_EXE, "sim", "--ephemeral-ports", "--port", "0",
                "--no-register", static_cast<char*>(nullptr));
        ::_exit(127);
    }
    ::close(toChild[1]);
    std::string jsonLine;
    {
        char ch = 0;
        while (::read(toChild[0], &ch, 1) == 1 && ch != '\n' && jsonLine.size() < 65536)
            jsonLine += ch;
    }
    const auto addressAt = jsonLine.find("\"address\":\"");
    if (addressAt == std::string::npos) {
        std::fprintf(stderr, "pnp sim printed no device address: %s\n", jsonLine.c_str());
        ::kill(pid, SIGTERM);
        ::waitpid(pid, nullptr, 0);
        return 1;
    }
    const std::string address =
        jsonLine.substr(addressAt + 11, jsonLine.find('"', addressAt + 11) - (addressAt + 11));
    pnp::device::ur::UrConfig pc2 = uc;
    pc2.port = static_cast<std::uint16_t>(std::stoi(address.substr(address.rfind(':') + 1)));
    pnp::device::ur::UrHardware simHardware(pc2);
    pnp::robot::Controller simController(simHardware, cc);
    if (auto st = simController.start(Clock::now() + 5s); !st) {
        std::fprintf(stderr, "controller on pnp sim: %s\n", st.error().message.c_str());
        ::kill(pid, SIGTERM);
        ::waitpid(pid, nullptr, 0);
        return 1;
    }
    std::this_thread::sleep_for(500ms);
    const double cpu0 = processCpuSeconds(pid);
    const auto w0 = Clock::now();
    std::this_thread::sleep_for(std::chrono::seconds(seconds));
    const double simCpu =
        (processCpuSeconds(pid) - cpu0) / duration<double>(Clock::now() - w0).count();
    const auto stats = simController.stats();
    simController.stop();
    ::kill(pid, SIGTERM);
    ::waitpid(pid, nullptr, 0);
    // Baseline: a plain thread sleeping to absolute 2 ms deadlines, for as long (at most 10 s).
    std::vector<double> baseErr;
    double baseCpu = 0.0;
    {
        std::thread t([&] {
            const auto period = microseconds(2000);
            const int n = std::min(seconds, 10) * 500;
            baseErr.reserve(static_cast<std::size_t>(n));
            auto next = Clock::now() + period;
            auto prev = Clock::now();
            for (int i = 0; i < n; ++i) {
                std::this_thread::sleep_until(next);
                const auto now = Clock::now();
                baseErr.push_back(std::abs(duration<double>(now - prev).count() - 0.002));
                prev = now;
                next += period;
            }
            baseCpu = threadCpuSeconds(pthread_self()) / (n * 0.002);
        });
        t.join();
    }
    std::printf("%-52s %12.4f %12.4f %8.2f\n", "(b) loop period error p99, ms (vs sleep loop)",
                stats.periodErrorP99 * 1e3, quantile(baseErr, 0.99) * 1e3,
                stats.periodErrorP99 / std::max(1e-9, quantile(baseErr, 0.99)));
    std::printf(
        "%-52s %12.4f %12.4f %8.2f\n", "(b) loop period error max, ms", stats.periodErrorMax * 1e3,
        *std::max_element(baseErr.begin(), baseErr.end()) * 1e3,
        stats.periodErrorMax / std::max(1e-9, *std::max_element(baseErr.begin(), baseErr.end())));
    std::printf("%-52s %12s\n", "(b) loop thread real-time (SCHED_FIFO)",
                stats.realtime ? "yes" : "no");
    std::printf("%-52s %12zu\n", "(b) loop periods in the window",
                static_cast<std::size_t>(stats.window));
    std::printf("%-52s %12.2f %12.2f %8.2f\n", "(e) pnp sim process (500 Hz), % of a core",
                simCpu * 100.0, baseCpu * 100.0, simCpu / std::max(1e-9, baseCpu));
    return 0;
}
