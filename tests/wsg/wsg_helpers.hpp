// Helpers of the WSG tests: the thesis cell with the WSG 50 on the UR5's flange (so it is
// powered), optionally a part between its fingers; a stepping thread for the simulator; a raw
// TCP client that speaks frames. Every wait is bounded.
#pragma once

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "sim/wsg/wsg50.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"
#include "wsg/protocol.hpp"

namespace pnp::wsg::test {

using namespace std::chrono_literals;

inline constexpr const char* kTool = "wsg-gripper";

inline std::size_t toolIndex(const world::CellDescription& cell) {
    for (std::size_t i = 0; i < cell.tools.size(); ++i) {
        if (cell.tools[i].name == kTool) return i;
    }
    ADD_FAILURE() << "no " << kTool << " in the cell";
    return 0;
}

// The thesis cell (models/cells/thesis.yaml) with the WSG 50 locked on the UR5's flange, and,
// with `part`, a 40 mm cube between its fingers (its centre 10 mm behind the finger tips).
inline world::CellDescription cellWithWsg(bool onFlange, bool part = false) {
    auto loaded =
        world::loadCellFile(std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml");
    if (!loaded.ok()) {
        ADD_FAILURE() << loaded.error().message;
        return {};
    }
    world::CellDescription cell = *loaded;
    if (onFlange) {
        cell.robots.at(0).tool = kTool;
        for (world::DockDescription& d : cell.docks) {
            if (d.tool == kTool) d.tool.reset();
        }
    }
    if (part) {
        const world::World probe(cell);
        const auto grip = probe.gripPoint(toolIndex(cell));
        if (!grip) {
            ADD_FAILURE() << "the WSG has no grip point";
            return cell;
        }
        world::ObjectDescription o;
        o.name = "part";
        o.size = Eigen::Vector3d(0.04, 0.04, 0.04);
        o.mass = 0.05;
        o.color = "red";
        o.pose = *grip * Eigen::Translation3d(0.0, 0.0, -0.01);
        cell.objects.push_back(o);
    }
    return cell;
}

inline sim::wsg::Wsg50Config anyPort() {
    sim::wsg::Wsg50Config c;
    c.port = 0;
    return c;
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

// Steps the gripper and the world every 2 ms (2 ms of simulated time), as the simulator does.
class Stepper {
  public:
    Stepper(world::World& world, sim::wsg::Wsg50& wsg, std::size_t maxSteps = 30000)
        : world_(world), wsg_(wsg), maxSteps_(maxSteps) {
        thread_ = std::thread([this] { run(); });
    }
    ~Stepper() { stop(); }
    Stepper(const Stepper&) = delete;
    Stepper& operator=(const Stepper&) = delete;
    void stop() {
        stop_ = true;
        if (thread_.joinable()) thread_.join();
    }
    // The world, read on the stepping thread's side (between steps).
    template <class F>
    auto read(F f) {
        std::lock_guard lock(mutex_);
        return f(static_cast<const world::World&>(world_));
    }

  private:
    void run() {
        auto next = std::chrono::steady_clock::now();
        for (std::size_t i = 0; i < maxSteps_ && !stop_; ++i) {
            {
                std::lock_guard lock(mutex_);
                wsg_.step(0.002);
                world_.step(0.002);
            }
            next += 2ms;
            next = std::max(next, std::chrono::steady_clock::now());
            std::this_thread::sleep_until(next);
        }
    }
    world::World& world_;
    sim::wsg::Wsg50& wsg_;
    const std::size_t maxSteps_;
    std::atomic<bool> stop_{false};
    std::mutex mutex_;
    std::thread thread_;
};

// A plain TCP client on loopback that sends bytes and reads frames.
class RawClient {
  public:
    ~RawClient() {
        if (fd_ >= 0) ::close(fd_);
    }
    bool connect(std::uint16_t port) {
        fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(port);
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        return ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    }
    bool sendBytes(const std::vector<std::uint8_t>& bytes) {
        return ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL) ==
               static_cast<ssize_t>(bytes.size());
    }
    bool send(Command c, const std::vector<std::uint8_t>& payload = {}) {
        return sendBytes(encodeCommand(c, payload));
    }
    // The next frame, or nullopt after `timeout` (or when the peer closed).
    std::optional<Frame> next(std::chrono::milliseconds timeout = 2000ms) {
        const auto end = std::chrono::steady_clock::now() + timeout;
        for (int i = 0; i < 10000; ++i) {
            if (!frames_.empty()) {
                Frame f = std::move(frames_.front());
                frames_.pop_front();
                return f;
            }
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                end - std::chrono::steady_clock::now());
            if (left.count() <= 0) return std::nullopt;
            pollfd p{fd_, POLLIN, 0};
            if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) return std::nullopt;
            std::uint8_t buf[1024];
            const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
            if (n <= 0) {
                closed_ = true;
                return std::nullopt;
            }
            for (Frame& f : decoder_.feed(std::span(buf, static_cast<std::size_t>(n)))) {
                frames_.push_back(std::move(f));
            }
        }
        return std::nullopt;
    }
    std::optional<Response> response(std::chrono::milliseconds timeout = 2000ms) {
        auto f = next(timeout);
        if (!f) return std::nullopt;
        return parseResponse(*f);
    }
    // Sends and returns the first answer.
    std::optional<Response> call(Command c, const std::vector<std::uint8_t>& payload = {}) {
        if (!send(c, payload)) return std::nullopt;
        return response();
    }
    // Waits (bounded) until the peer closes the connection.
    bool waitClosed(std::chrono::milliseconds timeout) {
        const auto end = std::chrono::steady_clock::now() + timeout;
        while (!closed_ && std::chrono::steady_clock::now() < end) next(50ms);
        return closed_;
    }

  private:
    int fd_ = -1;
    bool closed_ = false;
    Decoder decoder_;
    std::deque<Frame> frames_;
};

inline std::uint16_t st(Status s) { return static_cast<std::uint16_t>(s); }

}  // namespace pnp::wsg::test
