#include "motion/timing_law.hpp"

#include <algorithm>
#include <cmath>

namespace pnp::motion {

TimingLaw TimingLaw::restToRest(double s0, double s1, double vmax, double amax) {
    TimingLaw law;
    law.sStart_ = s0;
    law.sEnd_ = std::max(s0, s1);
    const double d = law.sEnd_ - s0;
    if (!(d > 0.0) || !(vmax > 0.0) || !(amax > 0.0)) {
        law.sEnd_ = law.sStart_ = std::max(s0, s1);
        return law;
    }
    double ta = vmax / amax;
    double tc = 0.0;
    double vpeak = vmax;
    if (vmax * ta >= d) {  // triangle: vmax never reached
        ta = std::sqrt(d / amax);
        vpeak = amax * ta;
    } else {
        tc = (d - vmax * ta) / vmax;
    }
    law.phases_[law.count_++] = {0.0, s0, 0.0, amax};
    const double s1a = s0 + 0.5 * amax * ta * ta;
    if (tc > 0.0) law.phases_[law.count_++] = {ta, s1a, vpeak, 0.0};
    law.phases_[law.count_++] = {ta + tc, s1a + vpeak * tc, vpeak, -amax};
    law.duration_ = 2.0 * ta + tc;
    return law;
}

TimingLaw TimingLaw::brake(double s0, double v0, double amax, double sMax) {
    TimingLaw law;
    law.sStart_ = s0;
    law.sEnd_ = s0;
    if (!(v0 > 0.0) || !(amax > 0.0)) return law;
    double send = std::min(s0 + v0 * v0 / (2.0 * amax), std::max(sMax, s0));
    law.sEnd_ = send;
    // Keep the end exact: duration and deceleration from the (possibly clamped) distance.
    const double t = send > s0 ? 2.0 * (send - s0) / v0 : 0.0;
    law.duration_ = t;
    law.phases_[law.count_++] = {0.0, s0, v0, t > 0.0 ? -v0 / t : -amax};
    return law;
}

PathState TimingLaw::at(double t) const {
    if (count_ == 0 || t >= duration_) return {sEnd_, 0.0, 0.0};
    if (t <= 0.0) return {sStart_, phases_[0].v0, phases_[0].a};
    std::size_t i = count_ - 1;
    while (i > 0 && t < phases_[i].t0) --i;
    const Phase& p = phases_[i];
    if (i == count_ - 1) {
        // Last phase decelerates to rest at sEnd_: evaluate from the end so that it is exact.
        const double r = duration_ - t;
        return {sEnd_ + 0.5 * p.a * r * r, -p.a * r, p.a};
    }
    const double tau = t - p.t0;
    return {p.s0 + p.v0 * tau + 0.5 * p.a * tau * tau, p.v0 + p.a * tau, p.a};
}

}  // namespace pnp::motion
