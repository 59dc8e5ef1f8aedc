// Helpers of the ECBPi tests: the thesis cell with the vacuum gripper on the UR5's flange at
// start (so it has power), the arm placed so the cup sits on the cube or in the air, and a rig
// that runs the simulated IO-Link master behind the real Modbus TCP server with a stepping
// thread, as `pnp sim` does. Every wait is bounded.
#pragma once

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstddef>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>

#include "kinematics/kinematics.hpp"
#include "modbus/modbus.hpp"
#include "sim/ecbpi/ecbpi.hpp"
#include "sim/ecbpi/iolink_master.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"

namespace pnp::ecbpi::test {

using namespace std::chrono_literals;

inline constexpr double kDt = 0.002;  // s, the simulator's step

// The thesis cell; `onFlange`: the vacuum gripper starts locked on the UR5 (powered), its
// dock empty. Otherwise it stays parked in dock-1 (no power).
inline world::CellDescription vacuumCell(bool onFlange) {
    auto cell =
        world::loadCellFile(std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml");
    if (!cell.ok()) {
        ADD_FAILURE() << cell.error().message;
        return {};
    }
    world::CellDescription c = *cell;
    if (onFlange) {
        for (world::DockDescription& d : c.docks) {
            if (d.tool == "vacuum-gripper") d.tool.reset();
        }
        c.robots.at(0).tool = "vacuum-gripper";
    }
    return c;
}

inline std::size_t toolIndex(const world::World& w, const std::string& name) {
    for (std::size_t i = 0; i < w.description().tools.size(); ++i) {
        if (w.description().tools[i].name == name) return i;
    }
    ADD_FAILURE() << "no tool " << name;
    return 0;
}

inline std::size_t objectIndex(const world::World& w, const std::string& name) {
    for (std::size_t i = 0; i < w.objects().size(); ++i) {
        if (w.objects()[i].name == name) return i;
    }
    ADD_FAILURE() << "no object " << name;
    return 0;
}

// Puts the arm so the vacuum gripper's grip point (the cup, flange pointing down as at home)
// is at `cup` (world frame).
inline void placeCupAt(world::World& w, const Eigen::Vector3d& cup) {
    const world::RobotDescription& r = w.description().robots.at(0);
    const world::ToolDescription* tool = w.description().findTool("vacuum-gripper");
    Eigen::Isometry3d flange = w.robot(0).flange;
    flange.translation() = cup - flange.linear() * tool->tcp.translation();
    auto q = kinematics::solveNearest(r.model, r.base.inverse() * flange, r.home);
    ASSERT_TRUE(q.ok()) << q.error().message;
    ASSERT_TRUE(w.setJoints(0, *q, world::Joints{}));
    w.step(0.0);
}

// The cup pressed 1 mm onto the green cube's top face (its centre (0.05, 0.10), top z 0.04).
inline void placeCupOnCube(world::World& w) { placeCupAt(w, {0.05, 0.10, 0.039}); }
// Well above the table, over nothing.
inline void placeCupInAir(world::World& w) { placeCupAt(w, {0.05, 0.10, 0.15}); }

// What the stepping thread saw after its last step.
struct Observed {
    sim::ecbpi::EcbpiState gripper;
    std::optional<std::size_t> held;  // world.held(tool)
    double time = 0.0;                // simulated s
};

// World + master (ECBPi on port 1) + Modbus TCP server on 127.0.0.1:<free port> + a thread
// stepping world and master every 2 ms. The world is touched by that thread only; the test
// reads what it observed.
class SimRig {
  public:
    explicit SimRig(bool onFlange, bool cupOnCube = false) : world_(vacuumCell(onFlange)) {
        tool_ = toolIndex(world_, "vacuum-gripper");
        if (onFlange) {
            if (cupOnCube) {
                placeCupOnCube(world_);
            } else {
                placeCupInAir(world_);
            }
        }
        gripper_ = &master_.attach(1, std::make_unique<sim::ecbpi::Ecbpi>(world_, tool_));
        // One cycle before the first client can ask, as the simulator steps before it serves.
        world_.step(kDt);
        master_.step(kDt);
        modbus::TcpServerConfig config;
        config.port = 0;
        server_ = std::make_unique<modbus::TcpServer>(config, master_);
        server_->start();
        thread_ = std::thread([this] { run(); });
    }
    ~SimRig() {
        stop_ = true;
        if (thread_.joinable()) thread_.join();
        server_->stop();
    }

    std::uint16_t port() const { return server_->port(); }
    sim::ecbpi::IoLinkMaster& master() { return master_; }
    Observed observed() const {
        const std::lock_guard lock(mutex_);
        return observed_;
    }
    template <class Pred>
    bool waitFor(Pred pred, std::chrono::milliseconds timeout) const {
        const auto end = std::chrono::steady_clock::now() + timeout;
        while (std::chrono::steady_clock::now() < end) {
            if (pred(observed())) return true;
            std::this_thread::sleep_for(2ms);
        }
        return pred(observed());
    }

  private:
    void run() {
        auto next = std::chrono::steady_clock::now();
        while (!stop_) {
            world_.step(kDt);
            master_.step(kDt);
            {
                const std::lock_guard lock(mutex_);
                observed_.gripper = gripper_->state();
                observed_.held = world_.held(tool_);
                observed_.time = world_.time();
            }
            next += std::chrono::microseconds(2000);
            std::this_thread::sleep_until(next);
        }
    }

    world::World world_;
    std::size_t tool_ = 0;
    sim::ecbpi::IoLinkMaster master_;
    sim::ecbpi::Ecbpi* gripper_ = nullptr;
    std::unique_ptr<modbus::TcpServer> server_;
    std::thread thread_;
    std::atomic<bool> stop_{false};
    mutable std::mutex mutex_;
    Observed observed_;
};

}  // namespace pnp::ecbpi::test
