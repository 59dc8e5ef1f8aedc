// The simulated IO-Link master's Modbus map, read and written with libmodbus over loopback
// TCP: port status, identity, process data in and out, and the exceptions for addresses
// outside the map. The port's device is a scripted fake here (the ECBPi model has its own
// tests), so every value on the wire is known.
#include <gtest/gtest.h>
#include <modbus.h>

#include <cerrno>
#include <memory>
#include <vector>

#include "modbus/modbus.hpp"
#include "sim/ecbpi/iolink_master.hpp"

namespace pnp::sim::ecbpi {
namespace {

using iolink::PortState;

class FakeDevice : public IoLinkDevice {
  public:
    std::uint16_t vendorId() const override { return 234; }
    std::uint32_t deviceId() const override { return 0x123456; }
    std::size_t pdInBytes() const override { return 3; }
    std::size_t pdOutBytes() const override { return 1; }
    void setProcessDataOut(std::span<const std::uint8_t> pd) override {
        out.assign(pd.begin(), pd.end());
    }
    void step(double) override { ++steps; }
    PortState portState() const override { return state; }
    std::vector<std::uint8_t> processDataIn() const override { return in; }

    PortState state = PortState::kOperate;
    std::vector<std::uint8_t> in = {0xA1, 0xB2, 0xC3};
    std::vector<std::uint8_t> out;
    int steps = 0;
};

class MasterOverModbus : public ::testing::Test {
  protected:
    void SetUp() override {
        device_ = &master_.attach(2, std::make_unique<FakeDevice>());
        modbus::TcpServerConfig config;
        config.port = 0;
        server_ = std::make_unique<modbus::TcpServer>(config, master_);
        server_->start();
        ctx_ = modbus_new_tcp("127.0.0.1", server_->port());
        ASSERT_NE(ctx_, nullptr);
        modbus_set_response_timeout(ctx_, 1, 0);
        ASSERT_EQ(modbus_connect(ctx_), 0) << modbus_strerror(errno);
    }
    void TearDown() override {
        if (ctx_ != nullptr) {
            modbus_close(ctx_);
            modbus_free(ctx_);
        }
        server_->stop();
    }

    std::vector<std::uint16_t> read(int address, int count, bool input = false) {
        std::vector<std::uint16_t> regs(static_cast<std::size_t>(count), 0xDEAD);
        const int n = input ? modbus_read_input_registers(ctx_, address, count, regs.data())
                            : modbus_read_registers(ctx_, address, count, regs.data());
        EXPECT_EQ(n, count) << modbus_strerror(errno);
        return regs;
    }
    // The errno of a request that must fail.
    int readFails(int address, int count) {
        std::vector<std::uint16_t> regs(static_cast<std::size_t>(count));
        EXPECT_EQ(modbus_read_registers(ctx_, address, count, regs.data()), -1);
        return errno;
    }

    IoLinkMaster master_;
    FakeDevice* device_ = nullptr;
    std::unique_ptr<modbus::TcpServer> server_;
    modbus_t* ctx_ = nullptr;
};

TEST_F(MasterOverModbus, PortStatusFollowsTheDevice) {
    master_.step(0.002);
    // Port 1 and 3: nothing plugged in; port 2 operating.
    EXPECT_EQ(read(1000, 1)[0], 0);
    EXPECT_EQ(read(2000, 1)[0], 2);
    EXPECT_EQ(read(3000, 1)[0], 0);
    device_->state = PortState::kPreoperate;
    master_.step(0.002);
    EXPECT_EQ(read(2000, 1)[0], 1);
    device_->state = PortState::kNoDevice;
    master_.step(0.002);
    EXPECT_EQ(read(2000, 1)[0], 0);
    EXPECT_EQ(device_->steps, 3);
}

TEST_F(MasterOverModbus, IdentityOfTheDeviceOnThePort) {
    master_.step(0.002);
    EXPECT_EQ(read(2001, 5), (std::vector<std::uint16_t>{234, 0x12, 0x3456, 3, 1}));
    EXPECT_EQ(read(1001, 5), (std::vector<std::uint16_t>{0, 0, 0, 0, 0}));  // no device
    device_->state = PortState::kNoDevice;  // unpowered: the master sees nothing there
    master_.step(0.002);
    EXPECT_EQ(read(2001, 5), (std::vector<std::uint16_t>{0, 0, 0, 0, 0}));
}

TEST_F(MasterOverModbus, ProcessDataInIsValidInOperateOnly) {
    master_.step(0.002);
    std::vector<std::uint16_t> pd = read(2010, 16);
    EXPECT_EQ(pd[0], 0xA1B2);
    EXPECT_EQ(pd[1], 0xC300);
    for (std::size_t i = 2; i < pd.size(); ++i) EXPECT_EQ(pd[i], 0) << i;
    EXPECT_EQ(read(2010, 2, /*input=*/true), (std::vector<std::uint16_t>{0xA1B2, 0xC300}));
    device_->state = PortState::kPreoperate;
    master_.step(0.002);
    EXPECT_EQ(read(2010, 2), (std::vector<std::uint16_t>{0, 0}));
}

TEST_F(MasterOverModbus, ProcessDataOutReachesTheDeviceAtTheNextCycle) {
    const std::uint16_t value = 0x0300;  // octet 0 = 0x03: suction and blow-off bits
    ASSERT_EQ(modbus_write_registers(ctx_, 2100, 1, &value), 1) << modbus_strerror(errno);
    EXPECT_TRUE(device_->out.empty());  // not before the cycle
    master_.step(0.002);
    EXPECT_EQ(device_->out, (std::vector<std::uint8_t>{0x03}));  // pdOutBytes() octets only
    EXPECT_EQ(read(2100, 1)[0], 0x0300);                         // read back
    EXPECT_EQ(master_.port(2).pdOut[0], 0x03);
    // FC06 works too, and the master keeps the outputs while the device is away.
    ASSERT_EQ(modbus_write_register(ctx_, 2100, 0x0100), 1) << modbus_strerror(errno);
    device_->state = PortState::kNoDevice;
    master_.step(0.002);
    EXPECT_EQ(device_->out, (std::vector<std::uint8_t>{0x01}));
    // A port without a device keeps what is written as well.
    ASSERT_EQ(modbus_write_register(ctx_, 1100, 0x0200), 1) << modbus_strerror(errno);
    EXPECT_EQ(read(1100, 1)[0], 0x0200);
}

TEST_F(MasterOverModbus, AddressesOutsideTheMapGetExceptions) {
    EXPECT_EQ(readFails(999, 1), EMBXILADD);    // before port 1
    EXPECT_EQ(readFails(2006, 1), EMBXILADD);   // the gap between identity and PD in
    EXPECT_EQ(readFails(2010, 17), EMBXILADD);  // one beyond PD in
    EXPECT_EQ(readFails(5000, 1), EMBXILADD);   // port 5 of 4
    EXPECT_EQ(readFails(65535, 1), EMBXILADD);
    const std::uint16_t value = 1;
    EXPECT_EQ(modbus_write_registers(ctx_, 2000, 1, &value), -1);  // the status is read-only
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_write_registers(ctx_, 2010, 1, &value), -1);  // so is PD in
    EXPECT_EQ(errno, EMBXILADD);
    const std::vector<std::uint16_t> many(17, 1);  // PD out and one beyond: nothing written
    EXPECT_EQ(modbus_write_registers(ctx_, 2100, 17, many.data()), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(read(2100, 1)[0], 0);
    // The connection is still good after all of that.
    master_.step(0.002);
    EXPECT_EQ(read(2000, 1)[0], 2);
}

TEST(IoLinkMaster, PortsOutsideTheMasterAreRefused) {
    IoLinkMaster master;
    EXPECT_THROW(master.attach(0, std::make_unique<FakeDevice>()), std::out_of_range);
    EXPECT_THROW(master.attach(5, std::make_unique<FakeDevice>()), std::out_of_range);
    EXPECT_EQ(master.ports(), 4u);
    master.attach(4, std::make_unique<FakeDevice>());
    master.step(0.002);
    EXPECT_EQ(master.port(4).state, PortState::kOperate);
    master.detach(4);
    EXPECT_EQ(master.port(4).state, PortState::kNoDevice);
    EXPECT_TRUE(master.answering());  // powered by the cell, whatever its ports hold
}

}  // namespace
}  // namespace pnp::sim::ecbpi
