// Timing law s(t) on a path parameter: piecewise constant acceleration (trapezoid / triangle
// from rest to rest, or a single braking phase from a moving state to rest). Every law ends
// at rest, which is what makes stop / resume natural: a stopped trajectory is just another
// law on the same path.
#pragma once

#include <array>
#include <cstddef>

namespace pnp::motion {

struct PathState {
    double s = 0.0;  // path parameter
    double v = 0.0;  // ds/dt
    double a = 0.0;  // d2s/dt2
};

class TimingLaw {
  public:
    // Rest at s0 -> rest at s1 (s1 >= s0) with |ds/dt| <= vmax, |d2s/dt2| <= amax.
    static TimingLaw restToRest(double s0, double s1, double vmax, double amax);
    // From s0 moving at v0 >= 0, decelerating at amax to rest; the end is clamped to sMax
    // (rounding only: a valid law can always stop before its end).
    static TimingLaw brake(double s0, double v0, double amax, double sMax);

    PathState at(double t) const;  // t is clamped to [0, duration]
    double duration() const { return duration_; }
    double startParameter() const { return sStart_; }
    double endParameter() const { return sEnd_; }

  private:
    struct Phase {
        double t0 = 0.0;
        double s0 = 0.0;
        double v0 = 0.0;
        double a = 0.0;
    };
    std::array<Phase, 3> phases_{};
    std::size_t count_ = 0;
    double duration_ = 0.0;
    double sStart_ = 0.0;
    double sEnd_ = 0.0;
};

}  // namespace pnp::motion
