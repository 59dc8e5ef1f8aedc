// `pnp device kelvin-adc`'s library: the ADC board as an OPC UA device, reading the simulated
// board (KelvinAdcInput behind pnp_modbus' TcpServer) over Modbus TCP on 127.0.0.1, read by
// our OPC UA client; a dead link and its recovery.
#include "device/kelvin/kelvin_adc_device.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <thread>

#include "component/toolchanger/adc_monitor.hpp"
#include "sim/kelvin/kelvin_adc_input.hpp"
#include "support/loopback_server.hpp"
#include "support/wait.hpp"
#include "toolchanger/modbus_loopback.hpp"
#include "ua/client/client.hpp"

using namespace pnp;
using namespace std::chrono_literals;
using device::kelvin::ChangerState;

namespace {

// The simulated board: a voltage the test sets, sampled every 2 ms as the cell's stepping
// thread would, served on Modbus TCP.
struct FakeBoard {
    std::atomic<double> volts{0.0};
    sim::kelvin::KelvinAdcInput input{[this] { return volts.load(); }};
    std::unique_ptr<modbus::TcpServer> modbus;
    std::jthread stepper;
    std::uint16_t port = 0;

    FakeBoard() {
        serve(0);
        stepper = std::jthread([this](std::stop_token st) {
            while (!st.stop_requested()) {
                input.step(0.002);
                std::this_thread::sleep_for(2ms);
            }
        });
    }
    void serve(std::uint16_t p) {
        modbus = std::make_unique<modbus::TcpServer>(pnp::testing::modbusLoopback(p), input);
        modbus->start();
        port = modbus->port();
    }
    void unplug() { modbus.reset(); }
};

struct Rig {
    FakeBoard board;
    std::unique_ptr<ua::server::Server> server;
    std::unique_ptr<device::kelvin::KelvinAdcDevice> device;
    ua::client::Client client;

    Rig() {
        auto cfg = pnp::testing::loopbackConfig();
        cfg.applicationUri = "urn:pnp:test:kelvin-adc";
        server = std::make_unique<ua::server::Server>(cfg);
        device = std::make_unique<device::kelvin::KelvinAdcDevice>(
            *server,
            device::kelvin::KelvinAdcDeviceOptions{.adcHost = "127.0.0.1", .adcPort = board.port});
        server->start();
        device->start();
        client.connect(pnp::testing::url(*server));
    }
    ~Rig() {
        device.reset();
        server->stop();
    }
    ua::DataValue read(const ua::NodeId& n) {
        return client.readAttribute(n, ua::AttributeId::Value);
    }
    // Waits until State reads `state` (Good) and returns ToolId.
    bool waitState(ChangerState state, int toolId, std::chrono::milliseconds t = 2000ms) {
        return pnp::testing::waitUntil(
            [&] {
                auto s = read(device->stateNode());
                auto id = read(device->toolIdNode());
                const auto* sv = s.value ? s.value->scalar<ua::Int32>() : nullptr;
                const auto* iv = id.value ? id.value->scalar<ua::Int32>() : nullptr;
                return sv && iv && *sv == static_cast<int>(state) && *iv == toolId &&
                       !id.statusOrGood().isBad();
            },
            t);
    }
};

}  // namespace

TEST(KelvinAdcDevice, ServesVoltageStateAndToolId) {
    Rig rig;
    rig.board.volts = 8.4;
    ASSERT_TRUE(rig.waitState(ChangerState::kTool, 4));
    const auto v = rig.read(rig.device->voltageNode());
    ASSERT_TRUE(v.value && v.value->scalar<double>());
    EXPECT_NEAR(*v.value->scalar<double>(), 8.4, 0.1);
    EXPECT_FALSE(v.statusOrGood().isBad());

    rig.board.volts = 0.0;
    EXPECT_TRUE(rig.waitState(ChangerState::kReady, 0));
    rig.board.volts = 2.1;
    EXPECT_TRUE(rig.waitState(ChangerState::kIntermediate, 0));
    rig.board.volts = 4.9;
    EXPECT_TRUE(rig.waitState(ChangerState::kNoTool, 0));
    rig.board.volts = 14.1;
    EXPECT_TRUE(rig.waitState(ChangerState::kTool, 10));
    EXPECT_TRUE(rig.device->status().linkUp);
    EXPECT_GT(rig.device->status().reads, 0u);
}

TEST(KelvinAdcDevice, ClientsFindItByType) {
    Rig rig;
    const ua::UInt16 ns = rig.client.namespaceIndex(device::kelvin::kKelvinUri);
    ua::client::BrowseOptions o;
    o.referenceTypeId = ua::NodeId(0, 40);  // HasTypeDefinition
    const auto refs = rig.client.browse(rig.device->deviceNode(), o);
    ASSERT_EQ(refs.size(), 1u);
    EXPECT_EQ(refs[0].nodeId.nodeId, ua::NodeId(ns, device::kelvin::kKelvinToolChangerTypeId));
    EXPECT_TRUE(
        component::toolchanger::AdcMonitor::isKelvinAdc(pnp::testing::url(*rig.server), 2s));
}

TEST(KelvinAdcDevice, DeadLinkIsUnknownAndBadThenRecovers) {
    Rig rig;
    rig.board.volts = 6.7;
    ASSERT_TRUE(rig.waitState(ChangerState::kTool, 2));
    const std::uint16_t port = rig.board.port;
    rig.board.unplug();
    ASSERT_TRUE(pnp::testing::waitUntil(
        [&] {
            auto s = rig.read(rig.device->stateNode());
            auto v = rig.read(rig.device->voltageNode());
            auto id = rig.read(rig.device->toolIdNode());
            const auto* sv = s.value ? s.value->scalar<ua::Int32>() : nullptr;
            return sv && *sv == static_cast<int>(ChangerState::kUnknown) &&
                   v.statusOrGood().isBad() && id.statusOrGood().isBad();
        },
        2000ms));
    EXPECT_FALSE(rig.device->status().linkUp);
    EXPECT_FALSE(rig.device->status().error.empty());

    rig.board.volts = 9.5;
    rig.board.serve(port);  // plugged in again
    EXPECT_TRUE(rig.waitState(ChangerState::kTool, 5, 3000ms));
    EXPECT_FALSE(rig.read(rig.device->voltageNode()).statusOrGood().isBad());
}

TEST(KelvinAdcDevice, TheComponentsMonitorFollowsIt) {
    Rig rig;
    rig.board.volts = 5.7;
    ASSERT_TRUE(rig.waitState(ChangerState::kTool, 1));
    component::toolchanger::AdcMonitor monitor(pnp::testing::url(*rig.server), 2s);
    auto s = monitor.waitFor([](const auto& s) { return s.valid && s.reading.toolId == 1; }, 2s);
    ASSERT_TRUE(s);
    rig.board.volts = 2.1;
    EXPECT_TRUE(monitor.waitFor(
        [](const auto& s) { return s.valid && s.reading.state == ChangerState::kIntermediate; },
        2s));
    rig.board.unplug();
    EXPECT_TRUE(monitor.waitFor([](const auto& s) { return !s.valid; }, 2s));
}

TEST(KelvinAdcDevice, BadAddresses) {
    EXPECT_EQ(device::kelvin::parseModbusAddress("10.0.0.5").second, 502);
    EXPECT_EQ(device::kelvin::parseModbusAddress("10.0.0.5:1502").second, 1502);
    EXPECT_EQ(device::kelvin::parseModbusAddress("[::1]:15").first, "::1");
    EXPECT_THROW(device::kelvin::parseModbusAddress(":502"), device::kelvin::KelvinDeviceError);
    EXPECT_THROW(device::kelvin::parseModbusAddress("h:99999"), device::kelvin::KelvinDeviceError);
    EXPECT_THROW(device::kelvin::parseModbusAddress("h:x"), device::kelvin::KelvinDeviceError);
}
