#include "motion/timing_law.hpp"

#include <gtest/gtest.h>

#include <cmath>

namespace pnp::motion {
namespace {

TEST(TimingLaw, TrapezoidReachesEndAtRest) {
    const auto law = TimingLaw::restToRest(0.0, 1.0, 0.5, 2.0);
    // ta = 0.25 s, 0.0625 per ramp, cruise 0.875 / 0.5 = 1.75 s.
    EXPECT_NEAR(law.duration(), 2.25, 1e-12);
    EXPECT_EQ(law.at(law.duration()).s, 1.0);
    EXPECT_EQ(law.at(0.0).v, 0.0);
    EXPECT_NEAR(law.at(1.0).v, 0.5, 1e-12);
    EXPECT_NEAR(law.at(0.1).a, 2.0, 1e-12);
    EXPECT_NEAR(law.at(2.2).a, -2.0, 1e-12);
}

TEST(TimingLaw, TriangleWhenShort) {
    const auto law = TimingLaw::restToRest(0.2, 0.3, 10.0, 1.0);
    EXPECT_NEAR(law.duration(), 2.0 * std::sqrt(0.1), 1e-12);
    EXPECT_NEAR(law.at(law.duration() / 2).v, std::sqrt(0.1), 1e-12);
    EXPECT_NEAR(law.at(law.duration() / 2).s, 0.25, 1e-12);
}

TEST(TimingLaw, ContinuousPositionAndVelocity) {
    const auto law = TimingLaw::restToRest(0.0, 1.0, 0.7, 3.0);
    const double dt = 1e-6;
    for (double t = dt; t < law.duration(); t += 1e-3) {
        const auto a = law.at(t - dt);
        const auto b = law.at(t);
        EXPECT_LE(std::abs(b.s - a.s), 0.7 * dt * (1 + 1e-6));
        EXPECT_LE(std::abs(b.v - a.v), 3.0 * dt * (1 + 1e-6));
    }
}

TEST(TimingLaw, BrakeFromMotion) {
    const auto law = TimingLaw::brake(0.3, 0.4, 2.0, 1.0);
    EXPECT_NEAR(law.duration(), 0.2, 1e-12);
    EXPECT_NEAR(law.endParameter(), 0.3 + 0.16 / 4.0, 1e-12);
    EXPECT_EQ(law.at(0.0).v, 0.4);
    EXPECT_EQ(law.at(1.0).v, 0.0);
    // Clamped at the path end.
    const auto clamped = TimingLaw::brake(0.99, 1.0, 1.0, 1.0);
    EXPECT_EQ(clamped.endParameter(), 1.0);
}

TEST(TimingLaw, ZeroLength) {
    const auto law = TimingLaw::restToRest(0.5, 0.5, 1.0, 1.0);
    EXPECT_EQ(law.duration(), 0.0);
    EXPECT_EQ(law.at(0.0).s, 0.5);
}

}  // namespace
}  // namespace pnp::motion
