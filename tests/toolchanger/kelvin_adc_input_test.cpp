// The simulated ADC board's analog input (sim/kelvin) served by pnp_modbus' TcpServer and
// read with libmodbus, an independent Modbus master, over 127.0.0.1.
#include "sim/kelvin/kelvin_adc_input.hpp"

#include <gtest/gtest.h>
#include <modbus.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <string>

#include "toolchanger/modbus_loopback.hpp"
#include "world/cell_file.hpp"
#include "world/world.hpp"

using namespace pnp;
using sim::kelvin::KelvinAdcInput;

namespace {

struct ModbusClient {
    modbus_t* ctx = nullptr;
    explicit ModbusClient(std::uint16_t port) {
        ctx = modbus_new_tcp("127.0.0.1", port);
        modbus_set_response_timeout(ctx, 0, 500000);
        if (modbus_connect(ctx) == -1) {
            modbus_free(ctx);
            ctx = nullptr;
        }
    }
    ~ModbusClient() {
        if (ctx) {
            modbus_close(ctx);
            modbus_free(ctx);
        }
    }
};

}  // namespace

TEST(KelvinAdcInput, PinVoltageAndCountOfEveryLevel) {
    std::atomic<double> volts{0.0};
    KelvinAdcInput adc([&] { return volts.load(); }, {.noise = 0.0});
    modbus::TcpServer server(pnp::testing::modbusLoopback(), adc);
    server.start();
    ModbusClient c(server.port());
    ASSERT_NE(c.ctx, nullptr);
    for (double v : {0.0, 2.1, 4.9, 5.7, 6.7, 7.4, 8.4, 9.5, 10.8, 11.7, 12.4, 13.2, 14.1}) {
        volts = v;
        adc.step(0.002);
        std::uint16_t regs[2] = {0, 0};
        ASSERT_EQ(modbus_read_input_registers(c.ctx, 0, 2, regs), 2) << modbus_strerror(errno);
        const double pin = v * 1.5 / 11.5;
        EXPECT_NEAR(regs[0], pin * 1000.0, 0.5) << v << " V";
        EXPECT_NEAR(regs[1], pin / 3.3 * 4095.0, 0.5) << v << " V";
        // Back on the 24 V scale within a millivolt's rounding.
        EXPECT_NEAR(regs[0] / 1000.0 * 11.5 / 1.5, v, 0.004);
    }
}

TEST(KelvinAdcInput, NoiseIsBoundedAndDeterministic) {
    KelvinAdcInput a([] { return 9.5; }, {.noise = 0.010, .seed = 7});
    KelvinAdcInput b([] { return 9.5; }, {.noise = 0.010, .seed = 7});
    const double pin = 9.5 * 1.5 / 11.5 * 1000.0;
    bool varied = false;
    std::uint16_t first = 0;
    for (int i = 0; i < 200; ++i) {
        a.step(0.002);
        b.step(0.002);
        EXPECT_EQ(a.pinMillivolts(), b.pinMillivolts());
        EXPECT_LE(std::abs(a.pinMillivolts() - pin), 10.5);
        if (i == 0) first = a.pinMillivolts();
        varied = varied || a.pinMillivolts() != first;
    }
    EXPECT_TRUE(varied);
}

TEST(KelvinAdcInput, IllegalAddressesAndWritesAreRefused) {
    KelvinAdcInput adc([] { return 5.7; });
    modbus::TcpServer server(pnp::testing::modbusLoopback(), adc);
    server.start();
    ModbusClient c(server.port());
    ASSERT_NE(c.ctx, nullptr);
    std::uint16_t regs[4] = {};
    EXPECT_EQ(modbus_read_input_registers(c.ctx, 2, 1, regs), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_read_input_registers(c.ctx, 1, 2, regs), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_read_registers(c.ctx, 0, 1, regs), -1);
    EXPECT_EQ(errno, EMBXILADD);
    EXPECT_EQ(modbus_write_register(c.ctx, 0, 1), -1);
    EXPECT_EQ(errno, EMBXILADD);
    // The link still works.
    EXPECT_EQ(modbus_read_input_registers(c.ctx, 1, 1, regs), 1);
}

TEST(KelvinAdcInput, ReadsTheWorldsChangerVoltage) {
    auto cell = world::loadCellFile(PNP_CELLS_DIR "/thesis.yaml");
    ASSERT_TRUE(cell) << cell.error().message;
    world::World w(*cell);
    w.step(0.0);
    KelvinAdcInput adc(w, 0, {.noise = 0.0});
    adc.step(0.002);
    // At home the flange is in no dock: the changer is open ("ready", 0 V).
    EXPECT_EQ(adc.pinMillivolts(), static_cast<std::uint16_t>(
                                       std::lround(w.robot(0).changerVoltage * 1.5 / 11.5 * 1000)));
    EXPECT_THROW(KelvinAdcInput(w, 5), std::out_of_range);
}
