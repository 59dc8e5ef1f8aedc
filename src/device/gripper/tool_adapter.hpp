// A tool's adapter and its power (the "tool power = plug in"): the OPC UA server of
// a gripper exists only while the gripper answers.
//
// A thread polls the hardware (connect, then status; every `pollPeriod`, each call with a
// deadline of `pollTimeout`). On the first answer it starts the server with a GripperDevice
// and announces it (the `announce` callback: mDNS + LDS registration); when the device has
// not answered for longer than `graceTime` the announcement is withdrawn (its destruction
// sends the mDNS goodbye and unregisters from the LDS), the device halts its skills and the
// server stops. Power back: a fresh server and device on the same port with the same
// ApplicationUri. The next server and device are built while the tool is unpowered, so a
// power-up only starts the listener and the announcement.
//
//   RobotiqHardware hardware(config);
//   ToolAdapter adapter(hardware, {.server = serverConfig, .device = {.name = "Robotiq"}},
//                       [&](ua::server::Server& s) { return announceSomehow(s); });
//   adapter.onEvent([](const PowerEvent& e) { ... });
//   adapter.start();
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "device/gripper/gripper_device.hpp"
#include "device/gripper/gripper_hardware.hpp"
#include "device/gripper/hardware_access.hpp"
#include "ua/server/server.hpp"

namespace pnp::device::gripper {

// What runs beside a serving server (discovery); released to withdraw it.
using Announcement = std::shared_ptr<void>;
// Called on the adapter's thread right after the server started; may throw (reported as a
// PowerEvent::kError, the server keeps serving unannounced).
using Announce = std::function<Announcement(ua::server::Server& server)>;

struct ToolAdapterOptions {
    // The server's configuration; port 0 takes a free port at the first power-up and keeps
    // it for every later one.
    ua::server::ServerConfig server;
    GripperDeviceOptions device;
    std::chrono::milliseconds pollPeriod{20};
    std::chrono::milliseconds pollTimeout{15};  // each connect / status call
    // The device is gone after this long without an answer.
    std::chrono::milliseconds graceTime{100};
    // Activate (Robotiq rACT, WSG homing) right after the server is up, so that the first
    // skill does not wait for it.
    bool activateOnPowerUp = true;
    // Called on every server built, after the device's nodes (e.g. role permissions and the
    // Part 12 certificate management); may throw like the constructor.
    std::function<void(ua::server::Server&)> prepareServer;
};

struct PowerEvent {
    enum class Kind {
        kUp,     // serving and announced
        kDown,   // withdrawn and stopped (the device stopped answering, or stop())
        kError,  // a server / announcement / activation problem; the adapter goes on
    };
    Kind kind;
    std::string endpointUrl;
    // kUp: the device's first answer -> server listening and announced.
    std::chrono::nanoseconds startLatency{};
    std::string message;
};

class ToolAdapter {
  public:
    // Builds the first server and device (a set-up error throws GripperDeviceError,
    // NodeSetError, ...); start() begins polling.
    ToolAdapter(GripperHardware& hardware, ToolAdapterOptions options, Announce announce = {});
    ~ToolAdapter();  // stop()
    ToolAdapter(const ToolAdapter&) = delete;
    ToolAdapter& operator=(const ToolAdapter&) = delete;

    // Told on the adapter's thread (keep it short). Set before start().
    void onEvent(std::function<void(const PowerEvent&)> callback);
    void start();
    // Stops polling; a serving server is withdrawn and stopped (kDown); disconnects.
    void stop();

    bool serving() const { return serving_.load(); }
    // The endpoint while serving, and the last one after (the same on every power-up).
    std::string endpointUrl() const;
    std::uint64_t powerUps() const { return powerUps_.load(); }
    HardwareAccess& access() { return access_; }

  private:
    struct Impl;
    HardwareAccess access_;
    std::atomic<bool> serving_{false};
    std::atomic<std::uint64_t> powerUps_{0};
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::device::gripper
