// The gripper tests' set-up: FakeGripper -> HardwareAccess -> GripperDevice on a server at
// 127.0.0.1 (ephemeral port), and a connected client.
#pragma once

#include <chrono>
#include <memory>
#include <stdexcept>
#include <string>

#include "device/gripper/gripper_device.hpp"
#include "fake_gripper.hpp"
#include "support/loopback_server.hpp"
#include "support/wait.hpp"
#include "ua/client/client.hpp"

namespace pnp::testing {

using namespace std::chrono_literals;

struct GripperRig {
    FakeGripper hardware;
    device::gripper::HardwareAccess access{hardware};
    ua::server::Server server{pnp::testing::loopbackConfig()};
    std::unique_ptr<device::gripper::GripperDevice> device;
    std::shared_ptr<ua::client::Client> ua = std::make_shared<ua::client::Client>();

    explicit GripperRig(device::gripper::GripKind kind = device::gripper::GripKind::kParallel,
                        device::gripper::GripperDeviceOptions options = {.name = "Gripper"})
        : hardware(kind) {
        if (!hardware.connect(device::gripper::Clock::now() + 1s))
            throw std::runtime_error("fake gripper: no connection");
        device = std::make_unique<device::gripper::GripperDevice>(server, access, options);
        server.start();
        ua->connect(pnp::testing::url(server));
    }
    ~GripperRig() {
        ua->disconnect();
        device.reset();
        server.stop();
    }

    ua::NodeId skill(const char* name) const { return device->skillNode(name); }
    ua::UInt16 di() { return ua->namespaceIndex("http://opcfoundation.org/UA/DI/", 5s); }
    ua::UInt16 skills() { return ua->namespaceIndex("urn:pnp:ua:skills", 5s); }
};

}  // namespace pnp::testing
