// pnp_bench_motion: median time to plan a PTP and a LIN and time per sample, next to a
// baseline measured in the same run (plain linear interpolation with the same number of
// samples: what planning costs beyond producing the points at all).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <vector>

#include "gantry.hpp"
#include "motion/motion.hpp"

namespace {

using namespace pnp::motion;
using Clock = std::chrono::steady_clock;

volatile double gSink = 0.0;  // keeps the optimiser from dropping the measured work

double medianNs(int reps, const std::function<void()>& f) {
    std::vector<double> t(static_cast<std::size_t>(reps));
    for (int i = 0; i < reps; ++i) {
        const auto a = Clock::now();
        f();
        t[static_cast<std::size_t>(i)] =
            std::chrono::duration<double, std::nano>(Clock::now() - a).count();
    }
    std::nth_element(t.begin(), t.begin() + reps / 2, t.end());
    return t[static_cast<std::size_t>(reps / 2)];
}

void row(const char* what, double ns, double baseNs, double unit) {
    std::printf("%-36s %12.2f %12.2f %8.2f\n", what, ns / unit, baseNs / unit, ns / baseNs);
}

}  // namespace

int main() {
    Limits l;
    l.joint.maxVelocity = {1.0, 1.0, 1.0, 2.0, 2.0, 2.0};
    l.joint.maxAcceleration = {2.0, 2.0, 2.0, 4.0, 4.0, 4.0};
    const Kinematics kin = bench::gantry();
    const Joints start{0.1, -0.2, 0.3, 0.1, 0.2, -0.3};
    const Joints goalJ{0.7, 0.3, -0.2, 0.8, -0.4, 0.6};
    const Eigen::Isometry3d goal = bench::gantryForward(goalJ);
    constexpr double kDt = 2e-3;

    // PTP planning vs filling the same number of 2 ms samples by linear interpolation.
    const Trajectory ptp = planPtp(start, goalJ, l.joint).value();
    const auto ptpSamples = static_cast<std::size_t>(std::ceil(ptp.duration() / kDt)) + 1;
    const double ptpPlan =
        medianNs(2001, [&] { gSink = gSink + planPtp(start, goalJ, l.joint).value().duration(); });
    std::vector<Joints> buf(ptpSamples);
    auto lerp = [&](std::size_t n) {
        for (std::size_t k = 0; k < n; ++k) {
            const double s = static_cast<double>(k) / static_cast<double>(n - 1);
            for (std::size_t i = 0; i < 6; ++i) buf[k][i] = start[i] + s * (goalJ[i] - start[i]);
        }
        gSink = gSink + buf[n / 2][0];
    };
    const double ptpBase = medianNs(2001, [&] { lerp(ptpSamples); });

    // LIN planning vs interpolating the poses and solving IK at the same grid (1 mm / 5 mrad).
    auto linRes = planLin(start, goal, kin, l);
    if (!linRes.ok()) {
        std::fprintf(stderr, "LIN failed: %s\n", linRes.error().message.c_str());
        return 1;
    }
    const Trajectory lin = linRes.value();
    const Eigen::Isometry3d s0 = bench::gantryForward(start);
    const Eigen::Quaterniond r0(s0.rotation()), r1(goal.rotation());
    const double len = (goal.translation() - s0.translation()).norm();
    const auto grid = static_cast<std::size_t>(
        std::max({1.0, std::ceil(len / 1e-3), std::ceil(r0.angularDistance(r1) / 5e-3)}));
    const double linPlan =
        medianNs(101, [&] { gSink = gSink + planLin(start, goal, kin, l).value().duration(); });
    std::vector<Joints> ik(grid + 1);
    const double linBase = medianNs(101, [&] {
        ik[0] = start;
        for (std::size_t k = 1; k <= grid; ++k) {
            const double s = static_cast<double>(k) / static_cast<double>(grid);
            Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
            x.linear() = r0.slerp(s, r1).toRotationMatrix();
            x.translation() = s0.translation() + s * (goal.translation() - s0.translation());
            ik[k] = *kin.inverse(x, ik[k - 1]);
        }
        gSink = gSink + ik[grid][0];
    });

    // Sampling cost per sample (2 ms grid over the whole motion) vs lerp per sample.
    auto perSample = [&](const Trajectory& t) {
        const auto n = static_cast<std::size_t>(std::ceil(t.duration() / kDt)) + 1;
        return medianNs(201,
                        [&] {
                            double acc = 0.0;
                            for (std::size_t k = 0; k < n; ++k)
                                acc += t.sample(static_cast<double>(k) * kDt).velocity[0];
                            gSink = gSink + acc;
                        }) /
               static_cast<double>(n);
    };
    const double ptpSample = perSample(ptp);
    const double linSample = perSample(lin);
    const double lerpSample =
        medianNs(201, [&] { lerp(ptpSamples); }) / static_cast<double>(ptpSamples);

    std::printf("pnp_motion benchmark (gantry kinematics, medians)\n");
    std::printf("PTP: %.3f s, %zu samples at 2 ms; LIN: %.3f s, %zu IK grid points\n\n",
                ptp.duration(), ptpSamples, lin.duration(), grid + 1);
    std::printf("%-36s %12s %12s %8s\n", "operation", "pnp_motion", "baseline", "ratio");
    row("plan PTP, us (baseline: lerp)", ptpPlan, ptpBase, 1e3);
    row("plan LIN, us (baseline: lerp + IK)", linPlan, linBase, 1e3);
    row("sample PTP, ns/sample (b.: lerp)", ptpSample, lerpSample, 1.0);
    row("sample LIN, ns/sample (b.: lerp)", linSample, lerpSample, 1.0);
    return 0;
}
