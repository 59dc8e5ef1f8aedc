// The ECBPi model's vacuum physics and flags against the world, stepped by hand at the
// simulator's 2 ms (simulated time, so the timings are exact): sealed on the cube, in the air,
// decay, blow-off, the pump's control range, part detached, power.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>

#include "ecbpi_helpers.hpp"

namespace pnp::ecbpi::test {
namespace {

using sim::ecbpi::Ecbpi;
using sim::ecbpi::EcbpiState;

// Steps world and model until `pred` holds or `limit` seconds pass; the simulated time taken
// (or a negative value when it never held).
double stepUntil(world::World& w, Ecbpi& e, const std::function<bool(const EcbpiState&)>& pred,
                 double limit) {
    for (double t = 0.0; t <= limit; t += kDt) {
        if (pred(e.state())) return t;
        w.step(kDt);
        e.step(kDt);
    }
    return pred(e.state()) ? limit : -1.0;
}

void stepFor(world::World& w, Ecbpi& e, double seconds) {
    for (double t = 0.0; t < seconds - 1e-9; t += kDt) {
        w.step(kDt);
        e.step(kDt);
    }
}

struct Bench {
    explicit Bench(bool onFlange) : world(vacuumCell(onFlange)) {
        tool = toolIndex(world, "vacuum-gripper");
        cube = objectIndex(world, "cube-green");
    }
    world::World world;
    std::size_t tool = 0;
    std::size_t cube = 0;
};

// Powered and past the IO-Link start-up.
void operate(Bench& b, Ecbpi& e) {
    ASSERT_TRUE(b.world.toolPowered(b.tool)) << "a tool locked on the flange has power";
    const double t = stepUntil(
        b.world, e, [](const EcbpiState& s) { return s.port == iolink::PortState::kOperate; }, 1.0);
    ASSERT_GE(t, 0.0);
    EXPECT_NEAR(t, e.config().startupTime, 2 * kDt);
}

TEST(EcbpiVacuum, UnpoweredInTheDockIsNoDevice) {
    Bench b(/*onFlange=*/false);
    Ecbpi e(b.world, b.tool);
    e.setOutputs(true, false);
    stepFor(b.world, e, 0.5);
    EXPECT_FALSE(e.state().powered);
    EXPECT_EQ(e.state().port, iolink::PortState::kNoDevice);
    EXPECT_FALSE(e.state().suction);  // outputs do nothing without power
    EXPECT_EQ(e.state().vacuum, 0.0);
    EXPECT_FALSE(e.state().pumpRunning);
    EXPECT_FALSE(b.world.held(b.tool).has_value());
}

TEST(EcbpiVacuum, OnlyVacuumGrippersAndCompleteTablesAreAccepted) {
    Bench b(false);
    EXPECT_THROW(Ecbpi(b.world, toolIndex(b.world, "parallel-gripper")), std::invalid_argument);
    EXPECT_THROW(Ecbpi(b.world, 99), std::out_of_range);
    auto table = iolink::parseDeviceTable(R"(pnp-iolink-device: 1
vendor: x
vendor-id: 1
device: y
device-id: 0
pd-in-bytes: 2
pd-out-bytes: 1
process-data:
  - {name: vacuum, direction: in, bit-offset: 0, bit-length: 16, type: uint}
)",
                                          "partial.yaml");
    ASSERT_TRUE(table.ok()) << table.error().message;
    sim::ecbpi::EcbpiConfig config;
    config.table = *table;
    try {
        Ecbpi e(b.world, b.tool, config);
        ADD_FAILURE() << "a table without part-present was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("partial.yaml: no process data in field "
                                             "'part-present'"),
                  std::string::npos)
            << e.what();
    }
}

TEST(EcbpiVacuum, StartsUpThroughPreoperate) {
    Bench b(true);
    Ecbpi e(b.world, b.tool);
    e.setOutputs(true, false);
    b.world.step(kDt);
    e.step(kDt);
    EXPECT_EQ(e.state().port, iolink::PortState::kPreoperate);
    EXPECT_FALSE(e.state().suction);  // no cyclic exchange before OPERATE
    operate(b, e);
    stepFor(b.world, e, 0.01);
    EXPECT_TRUE(e.state().suction);
}

TEST(EcbpiVacuum, SealedOnTheCubePartPresentWithinAHundredMilliseconds) {
    Bench b(true);
    placeCupOnCube(b.world);
    ASSERT_EQ(b.world.objectUnderCup(b.tool), b.cube) << "the cup sits on the cube's top face";
    Ecbpi e(b.world, b.tool);
    operate(b, e);
    e.setOutputs(true, false);
    const double present = stepUntil(
        b.world, e, [](const EcbpiState& s) { return s.partPresent; }, 1.0);
    ASSERT_GE(present, 0.0) << "vacuum " << e.state().vacuum;
    // 0 -> 550 mbar towards 800 with tau 60 ms: 70 ms.
    EXPECT_GT(present, 0.05);
    EXPECT_LT(present, 0.1);
    EXPECT_GE(e.state().vacuum, 550.0);
    EXPECT_EQ(e.state().holding, b.cube);
    EXPECT_EQ(b.world.held(b.tool), b.cube);
    EXPECT_FALSE(e.state().inControlRange);
    const double inRange = stepUntil(
        b.world, e, [](const EcbpiState& s) { return s.inControlRange; }, 1.0);
    ASSERT_GE(inRange, 0.0);
    EXPECT_LT(present + inRange, 0.2);    // H1 (750) at 166 ms
    EXPECT_FALSE(e.state().pumpRunning);  // stopped at H1
    EXPECT_FALSE(e.state().partDetached);
    EXPECT_EQ(e.state().deviceStatus, 0);
}

TEST(EcbpiVacuum, ThePumpKeepsTheVacuumInTheControlRange) {
    Bench b(true);
    placeCupOnCube(b.world);
    Ecbpi e(b.world, b.tool);
    operate(b, e);
    e.setOutputs(true, false);
    ASSERT_GE(stepUntil(
                  b.world, e, [](const EcbpiState& s) { return s.inControlRange; }, 1.0),
              0.0);
    // Over 10 s the sealed cup leaks down to H1 - h1 and the pump brings it back, again and
    // again; the part stays present all the time.
    int restarts = 0;
    bool wasRunning = false;
    double lowest = 1e9;
    double highest = 0.0;
    for (int i = 0; i < 5000; ++i) {
        b.world.step(kDt);
        e.step(kDt);
        const EcbpiState& s = e.state();
        lowest = std::min(lowest, s.vacuum);
        highest = std::max(highest, s.vacuum);
        if (s.pumpRunning && !wasRunning) ++restarts;
        wasRunning = s.pumpRunning;
        ASSERT_TRUE(s.partPresent) << "at " << i * kDt << " s";
    }
    EXPECT_GE(restarts, 2);
    EXPECT_GT(lowest, 600.0 - 5.0);
    EXPECT_LT(highest, 760.0);
    EXPECT_EQ(b.world.held(b.tool), b.cube);
}

TEST(EcbpiVacuum, InTheAirThePartNeverComes) {
    Bench b(true);
    placeCupInAir(b.world);
    ASSERT_FALSE(b.world.objectUnderCup(b.tool).has_value());
    Ecbpi e(b.world, b.tool);
    operate(b, e);
    e.setOutputs(true, false);
    double highest = 0.0;
    for (int i = 0; i < 1000; ++i) {  // 2 s
        b.world.step(kDt);
        e.step(kDt);
        highest = std::max(highest, e.state().vacuum);
        ASSERT_FALSE(e.state().partPresent);
    }
    EXPECT_NEAR(e.state().vacuum, e.config().freeFlowVacuum, 1.0);
    EXPECT_LE(highest, e.config().freeFlowVacuum + 1e-9);
    EXPECT_TRUE(e.state().pumpRunning);
    EXPECT_EQ(e.state().deviceStatus, 1);  // warning: sucking for > 1 s without a part
    EXPECT_FALSE(b.world.held(b.tool).has_value());
    // Suction off: the warning goes.
    e.setOutputs(false, false);
    stepFor(b.world, e, 0.01);
    EXPECT_EQ(e.state().deviceStatus, 0);
}

TEST(EcbpiVacuum, SuctionOffDecaysAndDropsThePart) {
    Bench b(true);
    placeCupOnCube(b.world);
    Ecbpi e(b.world, b.tool);
    operate(b, e);
    e.setOutputs(true, false);
    ASSERT_GE(stepUntil(
                  b.world, e, [](const EcbpiState& s) { return s.inControlRange; }, 1.0),
              0.0);
    ASSERT_EQ(b.world.held(b.tool), b.cube);
    const double start = e.state().vacuum;
    e.setOutputs(false, false);
    const double gone = stepUntil(
        b.world, e, [](const EcbpiState& s) { return !s.partPresent; }, 2.0);
    ASSERT_GE(gone, 0.0);
    // tau 0.3 s from ~750 to below 540: ~0.1 s.
    EXPECT_NEAR(gone, 0.3 * std::log(start / 540.0), 0.01);
    EXPECT_FALSE(e.state().partDetached);  // suction was switched off: not "detached"
    const double dropped = stepUntil(
        b.world, e, [](const EcbpiState& s) { return !s.holding; }, 2.0);
    ASSERT_GE(dropped, 0.0);
    EXPECT_NEAR(gone + dropped, 0.3 * std::log(start / 200.0), 0.01);  // holding threshold
    EXPECT_FALSE(b.world.held(b.tool).has_value());
}

TEST(EcbpiVacuum, BlowOffEmptiesTheCupInFiftyMillisecondsAndReleases) {
    Bench b(true);
    placeCupOnCube(b.world);
    Ecbpi e(b.world, b.tool);
    operate(b, e);
    e.setOutputs(true, false);
    ASSERT_GE(stepUntil(
                  b.world, e, [](const EcbpiState& s) { return s.inControlRange; }, 1.0),
              0.0);
    e.setOutputs(true, true);  // blow-off has priority over suction
    b.world.step(kDt);
    e.step(kDt);
    EXPECT_FALSE(e.state().holding);  // released at once
    EXPECT_FALSE(b.world.held(b.tool).has_value());
    const double empty = stepUntil(
        b.world, e, [](const EcbpiState& s) { return s.vacuum < 5.0; }, 1.0);
    ASSERT_GE(empty, 0.0);
    EXPECT_LT(empty + kDt, 0.07);
    EXPECT_FALSE(e.state().partPresent);
    EXPECT_FALSE(e.state().partDetached);
    EXPECT_FALSE(e.state().pumpRunning);
}

TEST(EcbpiVacuum, APartLostWhileSuckingIsDetached) {
    Bench b(true);
    placeCupOnCube(b.world);
    Ecbpi e(b.world, b.tool);
    operate(b, e);
    e.setOutputs(true, false);
    ASSERT_GE(stepUntil(
                  b.world, e, [](const EcbpiState& s) { return s.partPresent; }, 1.0),
              0.0);
    // An operator takes the cube out of the cell while the gripper holds it: the seal is gone.
    ASSERT_EQ(b.world.removeObject("cube-green"), "");
    const double lost = stepUntil(
        b.world, e, [](const EcbpiState& s) { return s.partDetached; }, 1.0);
    ASSERT_GE(lost, 0.0);
    EXPECT_LT(lost, 0.1);
    EXPECT_FALSE(e.state().partPresent);
    EXPECT_TRUE(e.state().suction);
    // A new suction cycle clears it.
    e.setOutputs(false, false);
    stepFor(b.world, e, 0.01);
    EXPECT_TRUE(e.state().partDetached);  // still readable after suction off
    e.setOutputs(true, false);
    stepFor(b.world, e, 0.01);
    EXPECT_FALSE(e.state().partDetached);
}

TEST(EcbpiVacuum, ProcessDataCarriesTheStateByTheTable) {
    Bench b(true);
    placeCupOnCube(b.world);
    Ecbpi e(b.world, b.tool);
    operate(b, e);
    std::vector<std::uint8_t> out = {0x01};  // suction (bit 0)
    e.setProcessDataOut(out);
    ASSERT_GE(stepUntil(
                  b.world, e, [](const EcbpiState& s) { return s.partPresent; }, 1.0),
              0.0);
    const std::vector<std::uint8_t> in = e.processDataIn();
    ASSERT_EQ(in.size(), 4u);
    EXPECT_EQ(in[0] & 0x01, 0x01);  // part present
    EXPECT_EQ(in[0] & 0x02, 0x00);  // not yet in the control range
    EXPECT_EQ(in[1], 100);          // pump power %
    const int vacuum = (in[2] << 8) | in[3];
    EXPECT_NEAR(vacuum, e.state().vacuum, 0.5);
}

}  // namespace
}  // namespace pnp::ecbpi::test
