#include "sim/cell/simulator.hpp"

#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <mutex>
#include <stdexcept>
#include <system_error>
#include <thread>

#include "rtde/server.hpp"
#include "sim/cell/hosted_devices.hpp"
#include "sim/ur/ur_controller.hpp"

namespace pnp::sim::cell {

namespace {

using Clock = std::chrono::steady_clock;

// SCHED_FIFO priority of the stepping and RTDE threads: below the adapter's control loop
// (robot::Controller takes half the maximum, 49), which should win on a shared machine.
constexpr int kRealtimePriority = 40;

// Step costs kept for the statistics: the last ~8 s at 500 Hz.
constexpr std::size_t kCostWindow = 4096;

}  // namespace

std::string DeviceEndpoint::address() const {
    if (!path.empty()) return path;
    return host + ":" + std::to_string(port);
}

DeviceEndpoint DeviceEndpoint::tcp(std::string name, std::string device, std::string protocol,
                                   std::string host, std::uint16_t port) {
    DeviceEndpoint e;
    e.name = std::move(name);
    e.device = std::move(device);
    e.protocol = std::move(protocol);
    e.host = std::move(host);
    e.port = port;
    return e;
}

std::filesystem::path defaultCellFile() {
    if (const char* env = std::getenv("PNP_CELL"); env != nullptr && *env != '\0') return env;
    return std::filesystem::path(PNP_CELLS_DIR) / "thesis.yaml";
}

struct Simulator::Impl {
    Impl(world::CellDescription cell, SimulatorConfig c) : config(c), world(std::move(cell)) {}

    SimulatorConfig config;
    world::World world;
    std::vector<std::unique_ptr<ur::UrController>> controllers;
    std::vector<std::unique_ptr<rtde::Server>> servers;
    std::vector<std::unique_ptr<HostedDevice>> devices;  // tools, tool changers
    std::vector<DeviceEndpoint> endpoints;

    std::thread thread;
    std::atomic<bool> running{false};

    std::mutex postedMutex;
    std::vector<std::function<void(world::World&)>> posted;

    void runPosted() {
        std::vector<std::function<void(world::World&)>> actions;
        {
            std::lock_guard lock(postedMutex);
            actions.swap(posted);
        }
        for (auto& a : actions) a(world);
    }
    std::atomic<bool> realtime{false};

    mutable std::mutex snapshotMutex;
    std::shared_ptr<const world::Snapshot> snapshot;

    mutable std::mutex statsMutex;
    StepStats stats;
    std::vector<double> costs = std::vector<double>(kCostWindow, 0.0);
    std::size_t costCount = 0;

    void publishSnapshot() {
        auto s = std::make_shared<const world::Snapshot>(world.snapshot());
        std::lock_guard lock(snapshotMutex);
        snapshot = std::move(s);
    }

    void loop() {
        // A controller's cycle runs real-time where the system permits it (root, or
        // RLIMIT_RTPRIO); else at normal priority, with steps late under load.
        sched_param param{};
        param.sched_priority = kRealtimePriority;
        realtime = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param) == 0;
        const double dt = 1.0 / config.rate;
        const auto period = std::chrono::nanoseconds(std::llround(1e9 / config.rate));
        const auto snapshotEvery = static_cast<std::uint64_t>(
            std::max(1.0, std::round(config.rate / std::min(config.snapshotRate, config.rate))));
        auto next = Clock::now() + period;
        while (running.load(std::memory_order_relaxed)) {
            std::this_thread::sleep_until(next);
            const auto start = Clock::now();
            const auto late = start - next;
            // Fixed dt whatever the wake-up time: the world's trajectory depends only on its
            // inputs, not on the scheduler. A step that starts late is counted.
            runPosted();
            for (auto& c : controllers) c->step(dt);
            world.step(dt);
            for (auto& d : devices) d->step(dt);
            for (auto& c : controllers) c->publish();
            for (auto& s : servers) s->cycle();
            if (config.onStep) config.onStep(world);
            if (world.steps() % snapshotEvery == 0) publishSnapshot();
            const double cost = std::chrono::duration<double>(Clock::now() - start).count();
            {
                std::lock_guard lock(statsMutex);
                ++stats.steps;
                if (late > period) ++stats.overruns;
                stats.lateMax =
                    std::max(stats.lateMax, std::chrono::duration<double>(late).count());
                costs[costCount % kCostWindow] = cost;
                ++costCount;
            }
            next += period;
            // A step that ran late is not made up by a burst of steps: the adapters answer
            // each published state within its cycle, and a burst would leave them behind.
            // The world's time then runs a little slower than the wall clock, in step.
            if (const auto now = Clock::now(); now > next) next = now + period / 2;
        }
    }
};

Simulator::Simulator(world::CellDescription cell, SimulatorConfig config)
    : impl_(std::make_unique<Impl>(std::move(cell), config)) {
    if (!(config.rate >= 1.0 && config.rate <= 10000.0))
        throw std::invalid_argument("simulator rate must be within 1..10000 Hz");
    if (!(config.snapshotRate > 0.0)) throw std::invalid_argument("snapshot rate must be > 0");
    const auto& robots = impl_->world.description().robots;
    for (std::size_t i = 0; i < robots.size(); ++i) {
        ur::UrControllerConfig uc;
        uc.robot = i;
        uc.log = config.log;
        impl_->controllers.push_back(std::make_unique<ur::UrController>(impl_->world, uc));
        rtde::ServerConfig sc;
        sc.bindAddress = config.bindAddress;
        sc.port = config.ephemeralPorts ? 0 : robots[i].controller.port;
        // The state goes out once per world step, right after it, as a UR publishes its
        // state once per control cycle: an adapter that answers within the cycle gets its
        // target into the next step, every step.
        sc.externalCycle = true;
        sc.maxFrequency = config.rate;
        sc.realtimePriority = kRealtimePriority;
        impl_->servers.push_back(std::make_unique<rtde::Server>(sc, *impl_->controllers.back()));
    }
    impl_->devices = makeHostedDevices(impl_->world, config);
    // Outputs valid before the first step: a client that connects at once reads the home pose.
    impl_->world.step(0.0);
    for (auto& d : impl_->devices) d->step(0.0);
    for (auto& c : impl_->controllers) c->publish();
    impl_->publishSnapshot();
}

Simulator::~Simulator() { stop(); }

void Simulator::start() {
    if (impl_->running) return;
    const auto& robots = impl_->world.description().robots;
    impl_->endpoints.clear();
    for (std::size_t i = 0; i < impl_->servers.size(); ++i) {
        try {
            impl_->servers[i]->start();
        } catch (const std::system_error& e) {
            for (std::size_t k = 0; k < i; ++k) impl_->servers[k]->stop();
            throw std::system_error(e.code(), "robot " + robots[i].name + ": RTDE controller on " +
                                                  impl_->config.bindAddress + ":" +
                                                  std::to_string(robots[i].controller.port));
        }
        impl_->endpoints.push_back(DeviceEndpoint::tcp(robots[i].name, "ur-controller", "rtde",
                                                       impl_->config.bindAddress,
                                                       impl_->servers[i]->port()));
    }
    for (std::size_t i = 0; i < impl_->devices.size(); ++i) {
        try {
            impl_->devices[i]->start();
        } catch (const std::system_error& e) {
            for (std::size_t k = 0; k < i; ++k) impl_->devices[k]->stop();
            for (auto& s : impl_->servers) s->stop();
            const DeviceEndpoint d = impl_->devices[i]->endpoint();
            throw std::system_error(e.code(), d.name + " (" + d.device + ") on " + d.address());
        }
        impl_->endpoints.push_back(impl_->devices[i]->endpoint());
    }
    {
        std::lock_guard lock(impl_->postedMutex);
        impl_->running = true;
    }
    impl_->thread = std::thread([this] { impl_->loop(); });
}

void Simulator::stop() {
    {
        std::lock_guard lock(impl_->postedMutex);
        if (!impl_->running.exchange(false)) return;
    }
    if (impl_->thread.joinable()) impl_->thread.join();
    impl_->runPosted();  // posted just before the last step: still done (their callers wait)
    for (auto& s : impl_->servers) s->stop();
    for (auto& d : impl_->devices) d->stop();
}

std::vector<DeviceEndpoint> Simulator::endpoints() const { return impl_->endpoints; }

std::shared_ptr<const world::Snapshot> Simulator::snapshot() const {
    std::lock_guard lock(impl_->snapshotMutex);
    return impl_->snapshot;
}

const world::CellDescription& Simulator::description() const { return impl_->world.description(); }

double Simulator::rate() const { return impl_->config.rate; }

void Simulator::post(std::function<void(world::World&)> action) {
    {
        std::lock_guard lock(impl_->postedMutex);
        if (impl_->running) {
            impl_->posted.push_back(std::move(action));
            return;
        }
    }
    // Not stepping: the world is ours; the snapshot shows the result at once.
    action(impl_->world);
    impl_->world.step(0.0);
    impl_->publishSnapshot();
}

const sim::ur::UrController& Simulator::urController(std::size_t index) const {
    return *impl_->controllers.at(index);
}

StepStats Simulator::stats() const {
    std::lock_guard lock(impl_->statsMutex);
    StepStats s = impl_->stats;
    s.realtime = impl_->realtime.load();
    const std::size_t n = std::min(impl_->costCount, kCostWindow);
    if (n > 0) {
        std::vector<double> c(impl_->costs.begin(), impl_->costs.begin() + n);
        auto at = [&](double q) {
            const auto k = std::min(n - 1, static_cast<std::size_t>(q * (n - 1) + 0.5));
            std::nth_element(c.begin(), c.begin() + k, c.end());
            return c[k];
        };
        s.stepCostMedian = at(0.5);
        s.stepCostP99 = at(0.99);
    }
    return s;
}

}  // namespace pnp::sim::cell
