// EcbpiHardware (the adapter's side, libmodbus) against the simulated master and ECBPi over
// loopback TCP: grasp on the cube and on nothing, release, cancel, an unpowered port, a dead
// master and one that never answers; every call within its deadline.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "device/ecbpi/ecbpi_hardware.hpp"
#include "ecbpi_helpers.hpp"

namespace pnp::ecbpi::test {
namespace {

using device::ecbpi::EcbpiHardware;
using device::ecbpi::EcbpiOptions;
using device::gripper::Clock;
using device::gripper::ErrorKind;

std::unique_ptr<EcbpiHardware> adapter(std::uint16_t tcpPort, std::size_t ioLinkPort = 1) {
    EcbpiOptions options;
    options.host = "127.0.0.1";
    options.tcpPort = tcpPort;
    options.ioLinkPort = ioLinkPort;
    auto hw = EcbpiHardware::create(options);
    if (!hw.ok()) {
        ADD_FAILURE() << hw.error();
        return nullptr;
    }
    return std::move(*hw);
}

long long msSince(Clock::time_point t) {
    return std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - t).count();
}

const std::atomic<bool> kNoCancel{false};

// A loopback port with nothing listening (bound, then closed).
std::uint16_t deadPort() {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    socklen_t len = sizeof addr;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
    ::close(fd);
    return ntohs(addr.sin_port);
}

TEST(EcbpiHardware, OptionsAndTablesAreChecked) {
    auto parsed = device::ecbpi::parseIoLinkAddress("localhost:5020");
    ASSERT_TRUE(parsed.ok()) << parsed.error();
    EXPECT_EQ(parsed->host, "localhost");
    EXPECT_EQ(parsed->tcpPort, 5020);
    EXPECT_EQ(device::ecbpi::parseIoLinkAddress("[::1]:502")->host, "::1");
    EXPECT_FALSE(device::ecbpi::parseIoLinkAddress("localhost").ok());
    EXPECT_FALSE(device::ecbpi::parseIoLinkAddress("localhost:0").ok());
    EXPECT_FALSE(device::ecbpi::parseIoLinkAddress("localhost:99999").ok());
    EXPECT_FALSE(device::ecbpi::parseIoLinkAddress(":502").ok());

    EcbpiOptions options;
    options.ioLinkPort = 5;
    auto wrongPort = EcbpiHardware::create(options);
    ASSERT_FALSE(wrongPort.ok());
    EXPECT_NE(wrongPort.error().find("IO-Link port 5"), std::string::npos) << wrongPort.error();
    options.ioLinkPort = 1;
    options.table = "/nonexistent/ecbpi.yaml";
    auto noTable = EcbpiHardware::create(options);
    ASSERT_FALSE(noTable.ok());
    EXPECT_NE(noTable.error().find("/nonexistent/ecbpi.yaml"), std::string::npos);

    auto hw = adapter(502);
    ASSERT_TRUE(hw);
    const device::gripper::GripPoint g = hw->gripPoint();
    EXPECT_EQ(g.kind, device::gripper::GripKind::kVacuum);
    EXPECT_EQ(g.name, "Vacuum");
    EXPECT_DOUBLE_EQ(g.spanMax, 0.03);
    EXPECT_DOUBLE_EQ(g.offset.translation().z(), 0.1868);
    EXPECT_EQ(hw->manufacturer(), "J. Schmalz GmbH");
    EXPECT_EQ(hw->modelName(), "ECBPi");
    EXPECT_EQ(hw->endpoint(), "modbus-tcp://127.0.0.1:502?iolink-port=1");
}

TEST(EcbpiHardware, ADeadMasterIsNoDeviceWithinTheDeadline) {
    auto hw = adapter(deadPort());
    ASSERT_TRUE(hw);
    const auto start = Clock::now();
    auto r = hw->connect(start + std::chrono::milliseconds(500));
    ASSERT_FALSE(r.ok());
    EXPECT_EQ(r.error().kind, ErrorKind::kNoDevice) << r.error().message;
    EXPECT_NE(r.error().message.find("no IO-Link master at 127.0.0.1:"), std::string::npos)
        << r.error().message;
    EXPECT_LT(msSince(start), 500);
    auto g = hw->grasp({}, Clock::now() + std::chrono::milliseconds(300), kNoCancel);
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.error().kind, ErrorKind::kNoDevice);
}

TEST(EcbpiHardware, AMasterThatNeverAnswersIsNoDeviceWithinTheDeadline) {
    // Listening, but nobody reads: connect succeeds (the backlog), the request gets no answer.
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    ASSERT_EQ(::listen(fd, 4), 0);
    socklen_t len = sizeof addr;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
    auto hw = adapter(ntohs(addr.sin_port));
    ASSERT_TRUE(hw);
    const auto start = Clock::now();
    auto r = hw->status(start + std::chrono::milliseconds(300));
    const long long took = msSince(start);
    ::close(fd);
    ASSERT_FALSE(r.ok());
    EXPECT_TRUE(r.error().kind == ErrorKind::kNoDevice || r.error().kind == ErrorKind::kTimeout)
        << r.error().message;
    EXPECT_GE(took, 250);
    EXPECT_LT(took, 550);
}

TEST(EcbpiHardware, AnUnpoweredPortIsNoDevice) {
    SimRig rig(/*onFlange=*/false);  // the gripper parked in its dock: no power
    auto hw = adapter(rig.port());
    ASSERT_TRUE(hw);
    const auto deadline = Clock::now() + std::chrono::seconds(2);
    auto c = hw->connect(deadline);
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.error().kind, ErrorKind::kNoDevice);
    EXPECT_NE(c.error().message.find("IO-Link port 1"), std::string::npos) << c.error().message;
    auto a = hw->activate(deadline, kNoCancel);
    ASSERT_FALSE(a.ok());
    EXPECT_EQ(a.error().kind, ErrorKind::kNoDevice);
    auto g = hw->grasp({}, deadline, kNoCancel);
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.error().kind, ErrorKind::kNoDevice);
    auto s = hw->status(deadline);
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.error().kind, ErrorKind::kNoDevice);
    EXPECT_FALSE(rig.observed().gripper.suction);
    // Another port of the same master: nothing plugged in at all.
    auto other = adapter(rig.port(), 3);
    ASSERT_TRUE(other);
    EXPECT_EQ(other->connect(deadline).error().kind, ErrorKind::kNoDevice);
}

TEST(EcbpiHardware, GraspOnNothingFailsWithTheReasonWithinItsTimeout) {
    SimRig rig(/*onFlange=*/true, /*cupOnCube=*/false);
    auto hw = adapter(rig.port());
    ASSERT_TRUE(hw);
    const auto deadline = Clock::now() + std::chrono::seconds(5);
    ASSERT_TRUE(hw->connect(deadline).ok());
    auto a = hw->activate(deadline, kNoCancel);  // waits out PREOPERATE
    ASSERT_TRUE(a.ok()) << a.error().message;
    const auto start = Clock::now();
    auto g = hw->grasp({}, deadline, kNoCancel);
    const long long took = msSince(start);
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.error().kind, ErrorKind::kRefused);
    EXPECT_NE(g.error().message.find("no part present after"), std::string::npos)
        << g.error().message;
    EXPECT_GE(took, 1000);  // the part timeout
    EXPECT_LT(took, 1300);
    // Suction is off again, at the master and at the device.
    EXPECT_EQ(rig.master().port(1).pdOut[0] & 0x01, 0);
    EXPECT_TRUE(rig.waitFor([](const Observed& o) { return !o.gripper.suction; }, 500ms));
    EXPECT_FALSE(rig.observed().held.has_value());
    auto m = hw->move({}, deadline, kNoCancel);
    ASSERT_FALSE(m.ok());
    EXPECT_EQ(m.error().kind, ErrorKind::kRefused);
}

TEST(EcbpiHardware, GraspTheCubeThenReleaseIt) {
    SimRig rig(/*onFlange=*/true, /*cupOnCube=*/true);
    auto hw = adapter(rig.port());
    ASSERT_TRUE(hw);
    const auto deadline = Clock::now() + std::chrono::seconds(5);
    ASSERT_TRUE(hw->activate(deadline, kNoCancel).ok());
    const auto start = Clock::now();
    auto g = hw->grasp({}, deadline, kNoCancel);
    ASSERT_TRUE(g.ok()) << g.error().message;
    EXPECT_LT(msSince(start), 500);  // ~70 ms of simulated evacuation
    EXPECT_TRUE(g->holding);
    EXPECT_TRUE(g->ready);
    EXPECT_GE(g->vacuum, 550.0);
    EXPECT_TRUE(rig.waitFor([](const Observed& o) { return o.held.has_value(); }, 500ms));
    auto s = hw->status(deadline);
    ASSERT_TRUE(s.ok()) << s.error().message;
    EXPECT_TRUE(s->holding);

    auto r = hw->release(deadline, kNoCancel);
    ASSERT_TRUE(r.ok()) << r.error().message;
    EXPECT_FALSE(r->holding);
    EXPECT_LT(r->vacuum, 20.0);
    EXPECT_FALSE(rig.observed().held.has_value());
    EXPECT_EQ(rig.master().port(1).pdOut[0] & 0x03, 0);  // suction and blow-off off
}

TEST(EcbpiHardware, CancelStopsAGraspAndSwitchesSuctionOff) {
    SimRig rig(/*onFlange=*/true, /*cupOnCube=*/false);
    auto hw = adapter(rig.port());
    ASSERT_TRUE(hw);
    const auto deadline = Clock::now() + std::chrono::seconds(5);
    ASSERT_TRUE(hw->activate(deadline, kNoCancel).ok());
    std::atomic<bool> cancel{false};
    std::thread halt([&] {
        std::this_thread::sleep_for(100ms);
        cancel = true;
    });
    const auto start = Clock::now();
    auto g = hw->grasp({}, deadline, cancel);
    halt.join();
    ASSERT_FALSE(g.ok());
    EXPECT_EQ(g.error().kind, ErrorKind::kCancelled);
    EXPECT_LT(msSince(start), 400);
    EXPECT_EQ(rig.master().port(1).pdOut[0] & 0x01, 0);
}

}  // namespace
}  // namespace pnp::ecbpi::test
