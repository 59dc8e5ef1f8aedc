#include "kinematics/kinematics.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

namespace pnp::kinematics {

namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kTwoPi = 2.0 * std::numbers::pi;
// acos/asin arguments up to this far beyond ±1 are rounding of a pose on the workspace
// boundary (stretched arm, shoulder singularity), not an unreachable pose.
constexpr double kReachTolerance = 1e-9;
// Shoulder and elbow: an argument this close to ±1 is a double root (two branches that are
// one) blurred by rounding; snapping it merges them. Harmless: their constraints (wrist centre
// distance, planar reach) depend on the argument, not the angle, and move by ~1e-14 m only.
// Not used for q5: there the flange axis depends on the angle, snapping would tilt it.
constexpr double kDoubleRoot = 1e-14;
// Below this |sin q5| the q6 formula divides noise by noise: treat it as the singularity
// (q6 from the seed then tilts the flange by at most |q5|, far below the accuracy of 1e-9).
constexpr double kWristSingular = 1e-12;
// Two solutions closer than this on every axis (mod 2π) are one.
constexpr double kSameSolution = 1e-9;
// Limit checks accept this much rounding (and clamp), so ±2π limits keep ±2π itself.
constexpr double kLimitSlack = 1e-12;

double wrapPi(double a) {
    a = std::remainder(a, kTwoPi);  // [-π, π]
    return a <= -kPi ? a + kTwoPi : a;
}

// Clamp an acos/asin argument that is within the tolerance; false when beyond it.
bool clampUnit(double& x) {
    if (std::abs(x) > 1.0 + kReachTolerance) return false;
    x = std::clamp(x, -1.0, 1.0);
    return true;
}

struct Trig {
    double c, s;
};

// DH tables are full of alpha = 0, ±π/2: exact values save two libm calls per row (a third
// of the trigonometry of FK) and give exact zeros.
Trig alphaTrig(double alpha) {
    if (alpha == 0.0) return {1.0, 0.0};
    if (alpha == kPi / 2) return {0.0, 1.0};
    if (alpha == -kPi / 2) return {0.0, -1.0};
    return {std::cos(alpha), std::sin(alpha)};
}

// Rz(θ) Tz(d) Tx(a) Rx(α) multiplied out.
Eigen::Isometry3d dhFromTrig(const DhRow& row, double ct, double st, Trig al) {
    Eigen::Isometry3d t;
    t.matrix() << ct, -st * al.c, st * al.s, row.a * ct,  //
        st, ct * al.c, -ct * al.s, row.a * st,            //
        0.0, al.s, al.c, row.d,                           //
        0.0, 0.0, 0.0, 1.0;
    return t;
}

void snapDoubleRoot(double& x) {
    if (std::abs(x) > 1.0 - kDoubleRoot) x = x > 0 ? 1.0 : -1.0;
}

bool finite(const Eigen::Isometry3d& t) { return t.matrix().allFinite(); }

bool finite(const Joints& q) {
    return std::all_of(q.begin(), q.end(), [](double v) { return std::isfinite(v); });
}

// The geometric solutions in joint coordinates (offsets removed), each angle in (-π, π].
// The seed fills the undetermined angles at singularities: q6 at the wrist, q1 at the
// shoulder, so a robot standing still keeps its position.
int solveGeometric(const RobotModel& m, const Eigen::Isometry3d& t, const Joints& seed,
                   std::array<Joints, 8>& out) {
    const auto& dh = m.dh;
    const double d4 = dh[3].d, d6 = dh[5].d, a2 = dh[1].a, a3 = dh[2].a;
    const Eigen::Vector3d p = t.translation();
    const Eigen::Matrix3d r = t.linear();

    // q1: the wrist centre (origin of frame 5) lies d4 off the plane of the arm, along z1.
    const Eigen::Vector3d p05 = p - d6 * r.col(2);
    const double rho = std::hypot(p05.x(), p05.y());
    double theta1[2];
    int n1 = 0;
    if (rho < 1e-12 && std::abs(d4) < 1e-12) {
        // Shoulder singularity (only possible with d4 = 0): q1 is free; the seed's and its flip.
        theta1[n1++] = seed[0] + dh[0].thetaOffset;
        theta1[n1++] = seed[0] + dh[0].thetaOffset + kPi;
    } else {
        if (rho == 0.0) return 0;  // on the base axis, but d4 != 0
        double s = d4 / rho;
        if (!clampUnit(s)) return 0;  // wrist centre inside the cylinder |xy| < d4
        snapDoubleRoot(s);
        const double phi = std::atan2(p05.y(), p05.x());
        const double asinS = std::asin(s);
        theta1[n1++] = phi + asinS;
        theta1[n1++] = phi + kPi - asinS;
    }

    int count = 0;
    auto add = [&](const Joints& theta) {
        Joints q;
        for (int i = 0; i < kAxes; ++i) q[i] = wrapPi(theta[i] - dh[i].thetaOffset);
        for (int k = 0; k < count; ++k) {
            bool same = true;
            for (int i = 0; i < kAxes && same; ++i) {
                same = std::abs(wrapPi(q[i] - out[k][i])) < kSameSolution;
            }
            if (same) return;
        }
        out[count++] = q;
    };

    const Trig al0 = alphaTrig(dh[0].alpha), al4 = alphaTrig(dh[4].alpha),
               al5 = alphaTrig(dh[5].alpha);
    for (int i1 = 0; i1 < n1; ++i1) {
        const double th1 = theta1[i1];
        const double s1 = std::sin(th1), c1 = std::cos(th1);
        const Eigen::Isometry3d t16 = dhFromTrig(dh[0], c1, s1, al0).inverse(Eigen::Isometry) * t;
        // q5, q6: z1 seen from the flange frame is (cos q6 sin q5, -sin q6 sin q5, cos q5).
        // atan2 of both components, not acos(cos q5): acos loses half the digits near the
        // wrist singularity (1e-8 rad instead of 1e-16).
        const Eigen::Vector3d z1(s1, -c1, 0.0);
        const double xz = r.col(0).dot(z1), yz = r.col(1).dot(z1), c5 = r.col(2).dot(z1);
        const double s5abs = std::hypot(xz, yz);
        const double n5 = std::hypot(s5abs, c5);  // 1 up to the rounding of the pose
        for (const double sg : {1.0, -1.0}) {
            const double th5 = std::atan2(sg * s5abs, c5);
            const double s5 = sg * s5abs;
            // Wrist singularity: only q4 + q6 is defined; q6 keeps the seed, q4 takes the rest.
            const double th6 = s5abs < kWristSingular ? seed[5] + dh[5].thetaOffset
                                                      : std::atan2(-sg * yz, sg * xz);
            // q2, q3, q4: a planar 3R arm in frame 1 once joints 1, 5, 6 are known.
            const Eigen::Isometry3d t46 = dhFromTrig(dh[4], c5 / n5, s5 / n5, al4) *
                                          dhFromTrig(dh[5], std::cos(th6), std::sin(th6), al5);
            const Eigen::Isometry3d t14 = t16 * t46.inverse(Eigen::Isometry);
            const double px = t14.translation().x(), py = t14.translation().y();
            double c3 = (px * px + py * py - a2 * a2 - a3 * a3) / (2.0 * a2 * a3);
            if (!clampUnit(c3)) continue;
            snapDoubleRoot(c3);
            const double acos3 = std::acos(c3);
            const double th234 = std::atan2(t14(1, 0), t14(0, 0));
            for (const double th3 : {acos3, -acos3}) {
                const double th2 =
                    std::atan2(py, px) - std::atan2(a3 * std::sin(th3), a2 + a3 * std::cos(th3));
                add({th1, th2, th3, th234 - th2 - th3, th5, th6});
            }
        }
    }
    return count;
}

// The 2π-equivalent of q inside [lo, hi] nearest `seed`; false when there is none.
bool fitInto(double q, double lo, double hi, double seed, double& out) {
    double c = q + kTwoPi * std::round((seed - q) / kTwoPi);
    if (c < lo - kLimitSlack) {
        c += kTwoPi * std::ceil((lo - kLimitSlack - c) / kTwoPi);
    } else if (c > hi + kLimitSlack) {
        c -= kTwoPi * std::ceil((c - hi - kLimitSlack) / kTwoPi);
    }
    if (c < lo - kLimitSlack || c > hi + kLimitSlack) return false;
    out = std::clamp(c, lo, hi);
    return true;
}

bool fitAll(const Joints& q, const Joints& lo, const Joints& hi, const Joints& seed, Joints& out) {
    for (int i = 0; i < kAxes; ++i) {
        if (!fitInto(q[i], lo[i], hi[i], seed[i], out[i])) return false;
    }
    return true;
}

void limitArrays(const RobotModel& m, Joints& lo, Joints& hi) {
    for (int i = 0; i < kAxes; ++i) {
        lo[i] = m.limits[i].minPosition;
        hi[i] = m.limits[i].maxPosition;
    }
}

}  // namespace

Eigen::Isometry3d dhTransform(const DhRow& row, double q) {
    const double th = q + row.thetaOffset;
    return dhFromTrig(row, std::cos(th), std::sin(th), alphaTrig(row.alpha));
}

Eigen::Isometry3d forward(const RobotModel& model, const Joints& q) {
    Eigen::Isometry3d t = dhTransform(model.dh[0], q[0]);
    for (int i = 1; i < kAxes; ++i) t = t * dhTransform(model.dh[i], q[i]);
    return t;
}

bool hasUrClosedForm(const RobotModel& m) {
    constexpr double eps = 1e-12;
    const auto& dh = m.dh;
    const double alpha[kAxes] = {kPi / 2, 0.0, 0.0, kPi / 2, -kPi / 2, 0.0};
    for (int i = 0; i < kAxes; ++i) {
        if (std::abs(dh[i].alpha - alpha[i]) > eps) return false;
    }
    return std::abs(dh[0].a) < eps && std::abs(dh[1].d) < eps && std::abs(dh[2].d) < eps &&
           std::abs(dh[3].a) < eps && std::abs(dh[4].a) < eps && std::abs(dh[5].a) < eps &&
           std::abs(dh[1].a) > eps && std::abs(dh[2].a) > eps && std::abs(dh[5].d) > eps;
}

std::vector<Joints> solveAll(const RobotModel& model, const Eigen::Isometry3d& flange,
                             const Joints& seed) {
    std::vector<Joints> result;
    if (!hasUrClosedForm(model) || !finite(flange) || !finite(seed)) return result;
    std::array<Joints, 8> raw;
    const int n = solveGeometric(model, flange, seed, raw);
    Joints lo, hi;
    limitArrays(model, lo, hi);
    result.reserve(n);
    for (int k = 0; k < n; ++k) {
        Joints q;
        if (fitAll(raw[k], lo, hi, seed, q)) result.push_back(q);
    }
    return result;
}

double jointDistance(const Joints& a, const Joints& b, const Joints& weights) {
    double sum = 0.0;
    for (int i = 0; i < kAxes; ++i) sum += weights[i] * (a[i] - b[i]) * (a[i] - b[i]);
    return sum;
}

Result<Joints> solveNearest(const RobotModel& model, const Eigen::Isometry3d& flange,
                            const Joints& seed, const std::optional<AxisBounds>& bounds,
                            const Joints& weights) {
    if (!hasUrClosedForm(model)) {
        return Error{ErrorCode::kUnsupportedModel,
                     "model '" + model.name + "' has no UR-type DH table for the closed-form IK"};
    }
    if (!finite(flange) || !finite(seed)) {
        return Error{ErrorCode::kInvalidArgument, "pose or seed is not finite"};
    }
    Joints lo, hi;
    limitArrays(model, lo, hi);
    Joints blo = lo, bhi = hi;
    if (bounds) {
        for (int i = 0; i < kAxes; ++i) {
            if (!(bounds->min[i] <= bounds->max[i])) {
                return Error{ErrorCode::kInvalidArgument,
                             "axis bounds of joint " + std::to_string(i + 1) + " are empty"};
            }
            blo[i] = std::max(lo[i], bounds->min[i]);
            bhi[i] = std::min(hi[i], bounds->max[i]);
        }
    }

    std::array<Joints, 8> raw;
    const int n = solveGeometric(model, flange, seed, raw);
    if (n == 0) return Error{ErrorCode::kOutOfReach, "pose out of reach"};

    bool withinLimits = false;
    bool found = false;
    Joints best{};
    double bestDistance = 0.0;
    for (int k = 0; k < n; ++k) {
        Joints q;
        if (!fitAll(raw[k], lo, hi, seed, q)) continue;
        withinLimits = true;
        // Per axis the nearest equivalent is independent of the others: the weighted sum
        // is minimal when each term is.
        if (bounds && !fitAll(raw[k], blo, bhi, seed, q)) continue;
        const double dist = jointDistance(q, seed, weights);
        if (!found || dist < bestDistance) {
            found = true;
            best = q;
            bestDistance = dist;
        }
    }
    if (!withinLimits) {
        return Error{ErrorCode::kOutsideJointLimits,
                     std::to_string(n) + " solution(s), all outside joint limits"};
    }
    if (!found) {
        return Error{
            ErrorCode::kOutsideAxisBounds,
            std::to_string(n) + " solution(s) within joint limits, all outside axis bounds"};
    }
    return best;
}

}  // namespace pnp::kinematics
