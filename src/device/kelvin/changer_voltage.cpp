#include "device/kelvin/changer_voltage.hpp"

#include <cmath>
#include <limits>

namespace pnp::device::kelvin {

std::string_view toString(ChangerState s) {
    switch (s) {
        case ChangerState::kReady:
            return "Ready";
        case ChangerState::kIntermediate:
            return "Intermediate";
        case ChangerState::kNoTool:
            return "NoTool";
        case ChangerState::kTool:
            return "Tool";
        case ChangerState::kUnknown:
            break;
    }
    return "Unknown";
}

ChangerState changerStateFromValue(int value) {
    if (value < 0 || value > static_cast<int>(ChangerState::kUnknown))
        return ChangerState::kUnknown;
    return static_cast<ChangerState>(value);
}

namespace {
// Every level in ascending order with its reading.
struct Level {
    double volts;
    ChangerReading reading;
};
constexpr std::array<Level, 13> kLevels = {{
    {kReadyVoltage, {ChangerState::kReady, 0}},
    {kIntermediateVoltage, {ChangerState::kIntermediate, 0}},
    {kNoToolVoltage, {ChangerState::kNoTool, 0}},
    {kToolVoltages[0], {ChangerState::kTool, 1}},
    {kToolVoltages[1], {ChangerState::kTool, 2}},
    {kToolVoltages[2], {ChangerState::kTool, 3}},
    {kToolVoltages[3], {ChangerState::kTool, 4}},
    {kToolVoltages[4], {ChangerState::kTool, 5}},
    {kToolVoltages[5], {ChangerState::kTool, 6}},
    {kToolVoltages[6], {ChangerState::kTool, 7}},
    {kToolVoltages[7], {ChangerState::kTool, 8}},
    {kToolVoltages[8], {ChangerState::kTool, 9}},
    {kToolVoltages[9], {ChangerState::kTool, 10}},
}};
}  // namespace

ChangerReading classify(double volts) {
    if (!std::isfinite(volts) || volts < kLowestValid || volts > kHighestValid) return {};
    // Below the midpoint to the next level: this level (a reading exactly on a midpoint
    // belongs to the upper one).
    for (std::size_t i = 0; i + 1 < kLevels.size(); ++i) {
        const double threshold = (kLevels[i].volts + kLevels[i + 1].volts) / 2.0;
        if (volts < threshold) return kLevels[i].reading;
    }
    return kLevels.back().reading;
}

double nominalVoltage(ChangerReading reading) {
    for (const Level& l : kLevels)
        if (l.reading == reading) return l.volts;
    return std::numeric_limits<double>::quiet_NaN();
}

std::string describe(ChangerReading reading) {
    switch (reading.state) {
        case ChangerState::kReady:
            return "ready";
        case ChangerState::kIntermediate:
            return "intermediate";
        case ChangerState::kNoTool:
            return "no tool";
        case ChangerState::kTool:
            return "tool " + std::to_string(reading.toolId);
        case ChangerState::kUnknown:
            break;
    }
    return "unknown";
}

}  // namespace pnp::device::kelvin
