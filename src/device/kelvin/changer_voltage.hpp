// What the Kelvin tool changer's state voltage says (cell.md §2; 24 V scale): open ("ready")
// 0 V, turning ("intermediate") 2.1 V, locked without a tool 4.9 V, locked with tool 1…10 at
// 5.7, 6.7, 7.4, 8.4, 9.5, 10.8, 11.7, 12.4, 13.2, 14.1 V. A reading belongs to the level
// nearest to it: the thresholds lie at the midpoints between neighbouring levels, and a
// reading more than half the last gap beyond the end levels (below −0.5 V, above 14.55 V) or
// not finite is Unknown (a broken wire, a short to 24 V).
#pragma once

#include <array>
#include <string>
#include <string_view>

namespace pnp::device::kelvin {

// The values of the model's KelvinChangerState enumeration (models/Pnp.Kelvin.NodeSet2.xml).
enum class ChangerState : int {
    kReady = 0,
    kIntermediate = 1,
    kNoTool = 2,
    kTool = 3,
    kUnknown = 4
};
std::string_view toString(ChangerState s);  // "Ready", "Intermediate", "NoTool", "Tool", "Unknown"
// From an enumeration value on the wire (anything else: kUnknown).
ChangerState changerStateFromValue(int value);

inline constexpr double kReadyVoltage = 0.0;
inline constexpr double kIntermediateVoltage = 2.1;
inline constexpr double kNoToolVoltage = 4.9;
inline constexpr std::array<double, 10> kToolVoltages = {5.7,  6.7,  7.4,  8.4,  9.5,
                                                         10.8, 11.7, 12.4, 13.2, 14.1};
inline constexpr double kLowestValid = -0.5;    // V: below it the reading is Unknown
inline constexpr double kHighestValid = 14.55;  // V: above it the reading is Unknown

struct ChangerReading {
    ChangerState state = ChangerState::kUnknown;
    int toolId = 0;  // 1..10 with kTool, else 0
    bool operator==(const ChangerReading&) const = default;
};

// The reading of a voltage (V, 24 V scale).
ChangerReading classify(double volts);
// The nominal voltage of a reading (kUnknown: NaN), e.g. for messages and tests.
double nominalVoltage(ChangerReading reading);
// "ready", "intermediate", "no tool", "tool 3", "unknown" (messages for people).
std::string describe(ChangerReading reading);

}  // namespace pnp::device::kelvin
