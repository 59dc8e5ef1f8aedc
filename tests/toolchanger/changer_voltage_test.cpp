// The Kelvin state voltage's classification (cell.md §2): every level, every threshold at the
// midpoint between neighbouring levels, and what lies outside the table.
#include "device/kelvin/changer_voltage.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

using namespace pnp::device::kelvin;

namespace {

struct Level {
    double volts;
    ChangerReading reading;
};

std::vector<Level> table() {
    std::vector<Level> t = {{0.0, {ChangerState::kReady, 0}},
                            {2.1, {ChangerState::kIntermediate, 0}},
                            {4.9, {ChangerState::kNoTool, 0}}};
    const double tools[] = {5.7, 6.7, 7.4, 8.4, 9.5, 10.8, 11.7, 12.4, 13.2, 14.1};
    for (int i = 0; i < 10; ++i) t.push_back({tools[i], {ChangerState::kTool, i + 1}});
    return t;
}

}  // namespace

TEST(KelvinVoltage, EveryLevelIsItsReading) {
    for (const Level& l : table()) {
        EXPECT_EQ(classify(l.volts), l.reading) << l.volts << " V";
        EXPECT_DOUBLE_EQ(nominalVoltage(l.reading), l.volts);
    }
}

TEST(KelvinVoltage, ThresholdsLieAtTheMidpoints) {
    const auto t = table();
    for (std::size_t i = 0; i + 1 < t.size(); ++i) {
        const double mid = (t[i].volts + t[i + 1].volts) / 2.0;
        EXPECT_EQ(classify(mid - 0.001), t[i].reading) << "just below " << mid;
        EXPECT_EQ(classify(mid), t[i + 1].reading) << "at " << mid;
        EXPECT_EQ(classify(mid + 0.001), t[i + 1].reading) << "just above " << mid;
    }
}

TEST(KelvinVoltage, NoiseOfTheAdcStaysInTheBand) {
    // ±10 mV at the pin is ±77 mV on the 24 V scale; the narrowest half gap is 0.35 V.
    for (const Level& l : table())
        for (double d : {-0.077, 0.077}) EXPECT_EQ(classify(l.volts + d), l.reading);
}

TEST(KelvinVoltage, OutsideTheTableIsUnknown) {
    EXPECT_EQ(classify(-0.3).state, ChangerState::kReady);  // noise around 0 V
    EXPECT_EQ(classify(-0.6).state, ChangerState::kUnknown);
    EXPECT_EQ(classify(14.5), (ChangerReading{ChangerState::kTool, 10}));
    EXPECT_EQ(classify(14.6).state, ChangerState::kUnknown);
    EXPECT_EQ(classify(24.0).state, ChangerState::kUnknown);  // shorted to the supply
    EXPECT_EQ(classify(std::numeric_limits<double>::quiet_NaN()).state, ChangerState::kUnknown);
    EXPECT_EQ(classify(std::numeric_limits<double>::infinity()).state, ChangerState::kUnknown);
    EXPECT_EQ(classify(24.0).toolId, 0);
}

TEST(KelvinVoltage, NamesAndWireValues) {
    EXPECT_EQ(toString(ChangerState::kReady), "Ready");
    EXPECT_EQ(toString(ChangerState::kNoTool), "NoTool");
    EXPECT_EQ(changerStateFromValue(3), ChangerState::kTool);
    EXPECT_EQ(changerStateFromValue(7), ChangerState::kUnknown);
    EXPECT_EQ(changerStateFromValue(-1), ChangerState::kUnknown);
    EXPECT_EQ(describe({ChangerState::kTool, 3}), "tool 3");
    EXPECT_EQ(describe({ChangerState::kNoTool, 0}), "no tool");
}
