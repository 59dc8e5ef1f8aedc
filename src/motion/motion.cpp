#include "motion/motion.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

namespace pnp::motion {

namespace detail {

// Geometric path q(s), s in [0, 1], with its first and second derivative in s.
class Path {
  public:
    virtual ~Path() = default;
    virtual void evaluate(double s, Joints& q, Joints& dq, Joints& ddq) const = 0;
    virtual std::optional<Eigen::Isometry3d> pose(double) const { return std::nullopt; }
};

}  // namespace detail

namespace {

constexpr std::size_t kAxes = 6;

class PtpPath final : public detail::Path {
  public:
    PtpPath(const Joints& q0, const Joints& q1) : q0_(q0), q1_(q1) {
        for (std::size_t i = 0; i < kAxes; ++i) d_[i] = q1[i] - q0[i];
    }
    void evaluate(double s, Joints& q, Joints& dq, Joints& ddq) const override {
        s = std::clamp(s, 0.0, 1.0);
        for (std::size_t i = 0; i < kAxes; ++i) {
            // Interpolate from the nearer end so that both ends are hit bit-exactly.
            q[i] = s < 0.5 ? q0_[i] + s * d_[i] : q1_[i] - (1.0 - s) * d_[i];
            dq[i] = d_[i];
            ddq[i] = 0.0;
        }
    }

  private:
    Joints q0_, q1_, d_{};
};

// The Cartesian straight line with slerp on the short way.
struct Line {
    Eigen::Vector3d p0, p1;
    Eigen::Quaterniond r0, r1;
    Eigen::Isometry3d goal;

    Eigen::Isometry3d at(double s) const {
        if (s >= 1.0) return goal;
        s = std::max(s, 0.0);
        Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
        x.linear() = r0.slerp(s, r1).toRotationMatrix();
        x.translation() = p0 + s * (p1 - p0);
        return x;
    }
};

// LIN path: IK samples on a uniform s grid joined by cubic Hermite segments (C1 in s), so
// joint velocity is continuous and the derivatives are analytic between the samples.
class LinPath final : public detail::Path {
  public:
    LinPath(Line line, std::vector<Joints> knots)
        : line_(std::move(line)), knots_(std::move(knots)), n_(knots_.size() - 1) {}

    std::size_t segments() const { return n_; }
    // Cubic of segment k, axis i: q(u) = c0 + c1 u + c2 u^2 + c3 u^3, u in [0, 1]. Computed
    // on the fly from the knots (tangents by central differences, one-sided at the ends):
    // storing it would quadruple the memory, and planning time is dominated by memory.
    std::array<double, 4> coeff(std::size_t k, std::size_t i) const {
        auto tangent = [&](std::size_t j) {
            const std::size_t a = j == 0 ? 0 : j - 1;
            const std::size_t b = j == n_ ? n_ : j + 1;
            return (knots_[b][i] - knots_[a][i]) / static_cast<double>(b - a);
        };
        const double p0 = knots_[k][i], p1 = knots_[k + 1][i];
        const double m0 = tangent(k), m1 = tangent(k + 1);
        return {p0, m0, 3.0 * (p1 - p0) - 2.0 * m0 - m1, 2.0 * (p0 - p1) + m0 + m1};
    }

    void evaluate(double s, Joints& q, Joints& dq, Joints& ddq) const override {
        s = std::clamp(s, 0.0, 1.0);
        const double n = static_cast<double>(n_);
        const std::size_t k = std::min(static_cast<std::size_t>(s * n), n_ - 1);
        const double u = s >= 1.0 ? 1.0 : s * n - static_cast<double>(k);
        for (std::size_t i = 0; i < kAxes; ++i) {
            const auto c = coeff(k, i);
            q[i] = s >= 1.0 ? knots_[n_][i] : c[0] + u * (c[1] + u * (c[2] + u * c[3]));
            dq[i] = n * (c[1] + u * (2.0 * c[2] + 3.0 * u * c[3]));
            ddq[i] = n * n * (2.0 * c[2] + 6.0 * u * c[3]);
        }
    }
    std::optional<Eigen::Isometry3d> pose(double s) const override { return line_.at(s); }

  private:
    Line line_;
    std::vector<Joints> knots_;
    std::size_t n_;
};

bool positive(double x) { return std::isfinite(x) && x > 0.0; }

std::optional<Error> checkJointLimits(const JointLimits& l) {
    for (std::size_t i = 0; i < kAxes; ++i) {
        if (!positive(l.maxVelocity[i]) || !positive(l.maxAcceleration[i]))
            return Error{"joint limits must be finite and > 0 (axis " + std::to_string(i) + ")",
                         std::nullopt, std::nullopt};
    }
    return std::nullopt;
}

bool finite(const Joints& q) {
    return std::all_of(q.begin(), q.end(), [](double x) { return std::isfinite(x); });
}

Error linError(const char* what, double s, const Eigen::Vector3d& p) {
    char buf[256];
    std::snprintf(buf, sizeof buf, "LIN refused: %s at path fraction %.4f (x=%.6f y=%.6f z=%.6f m)",
                  what, s, p.x(), p.y(), p.z());
    return Error{buf, s, p};
}

// max_i |a_i - b_i| / (ds * vmax_i): the inverse of the largest path speed ds/dt the joint
// velocity limits allow over this step.
double stepRate(const Joints& a, const Joints& b, double ds, const Joints& vmax) {
    double r = 0.0;
    for (std::size_t i = 0; i < kAxes; ++i) r = std::max(r, std::abs(b[i] - a[i]) / (ds * vmax[i]));
    return r;
}

}  // namespace

JointSample Trajectory::sample(double t) const {
    const PathState st = law_.at(t);
    Joints dq{}, ddq{};
    JointSample out;
    path_->evaluate(st.s, out.position, dq, ddq);
    for (std::size_t i = 0; i < kAxes; ++i) {
        out.velocity[i] = dq[i] * st.v;
        out.acceleration[i] = ddq[i] * st.v * st.v + dq[i] * st.a;
    }
    return out;
}

std::optional<Eigen::Isometry3d> Trajectory::pose(double t) const {
    return path_->pose(law_.at(t).s);
}

Trajectory Trajectory::stop(double t) const {
    const PathState st = law_.at(t);
    return Trajectory(kind_, path_, TimingLaw::brake(st.s, st.v, as_, 1.0), vs_, as_);
}

Trajectory Trajectory::resume(double s) const {
    return Trajectory(kind_, path_, TimingLaw::restToRest(std::clamp(s, 0.0, 1.0), 1.0, vs_, as_),
                      vs_, as_);
}

PathBounds cartesianPathBounds(double length, double angle, const CartesianLimits& limits) {
    PathBounds b{std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
    if (length > 0.0) {
        b.velocity = std::min(b.velocity, limits.maxLinearVelocity / length);
        b.acceleration = std::min(b.acceleration, limits.maxLinearAcceleration / length);
    }
    if (angle > 0.0) {
        b.velocity = std::min(b.velocity, limits.maxAngularVelocity / angle);
        b.acceleration = std::min(b.acceleration, limits.maxAngularAcceleration / angle);
    }
    return b;
}

Result<Trajectory> planPtp(const Joints& start, const Joints& goal, const JointLimits& limits) {
    if (auto e = checkJointLimits(limits)) return *e;
    if (!finite(start) || !finite(goal)) return Error{"PTP: non-finite joint values", {}, {}};
    // Path q(s) = start + s (goal - start): axis i moves at |dq_i| ds/dt, so the common path
    // bounds are the tightest per-axis ratios (the slowest axis sets the duration).
    double vs = std::numeric_limits<double>::infinity();
    double as = vs;
    for (std::size_t i = 0; i < kAxes; ++i) {
        const double d = std::abs(goal[i] - start[i]);
        if (d > 0.0) {
            vs = std::min(vs, limits.maxVelocity[i] / d);
            as = std::min(as, limits.maxAcceleration[i] / d);
        }
    }
    auto path = std::make_shared<PtpPath>(start, goal);
    if (!std::isfinite(vs)) {  // zero-length move: already at the goal
        return Trajectory(Trajectory::Kind::Ptp, path, TimingLaw::restToRest(1.0, 1.0, 1.0, 1.0),
                          1.0, 1.0);
    }
    return Trajectory(Trajectory::Kind::Ptp, path, TimingLaw::restToRest(0.0, 1.0, vs, as), vs, as);
}

Result<Trajectory> planLin(const Joints& start, const Eigen::Isometry3d& goal,
                           const Kinematics& kin, const Limits& limits, const LinOptions& opt) {
    if (auto e = checkJointLimits(limits.joint)) return *e;
    const CartesianLimits& cl = limits.cartesian;
    if (!positive(cl.maxLinearVelocity) || !positive(cl.maxLinearAcceleration) ||
        !positive(cl.maxAngularVelocity) || !positive(cl.maxAngularAcceleration))
        return Error{"Cartesian limits must be finite and > 0", {}, {}};
    if (!kin.forward || !kin.inverse) return Error{"LIN: kinematics callbacks missing", {}, {}};
    if (!finite(start)) return Error{"LIN: non-finite joint values", {}, {}};
    if (!(opt.linearStep > 0.0) || !(opt.angularStep > 0.0) || opt.maxSamples < 1 ||
        !(opt.checkStep > 0.0))
        return Error{"LIN: invalid options", {}, {}};

    const Eigen::Isometry3d startPose = kin.forward(start);
    Line line;
    line.p0 = startPose.translation();
    line.p1 = goal.translation();
    line.r0 = Eigen::Quaterniond(startPose.rotation()).normalized();
    line.r1 = Eigen::Quaterniond(goal.rotation()).normalized();
    // q and -q are the same rotation; pick the sign that makes slerp take the short way.
    if (line.r0.dot(line.r1) < 0.0) line.r1.coeffs() = -line.r1.coeffs();
    line.goal = goal;
    const double len = (line.p1 - line.p0).norm();
    const double angle = line.r0.angularDistance(line.r1);
    if (!std::isfinite(len) || !std::isfinite(angle)) return Error{"LIN: non-finite goal", {}, {}};

    const double nd =
        std::max({1.0, std::ceil(len / opt.linearStep), std::ceil(angle / opt.angularStep)});
    const std::size_t n = std::min(static_cast<std::size_t>(nd), opt.maxSamples);
    const double h = 1.0 / static_cast<double>(n);
    auto sAt = [&](std::size_t k) { return k == n ? 1.0 : static_cast<double>(k) * h; };

    if (len == 0.0 && angle == 0.0) {
        auto path = std::make_shared<LinPath>(line, std::vector<Joints>{start, start});
        return Trajectory(Trajectory::Kind::Lin, path, TimingLaw::restToRest(1.0, 1.0, 1.0, 1.0),
                          1.0, 1.0);
    }

    // 1. IK along the path, each sample seeded with the previous one.
    std::vector<Joints> knots;
    knots.reserve(n + 1);
    knots.push_back(start);
    for (std::size_t k = 1; k <= n; ++k) {
        auto q = kin.inverse(line.at(sAt(k)), knots[k - 1]);
        if (!q || !finite(*q)) {
            // Bisect for the edge of the workspace so that the report says where it is.
            double lo = sAt(k - 1), hi = sAt(k);
            Joints qlo = knots[k - 1];
            for (int it = 0; it < 40; ++it) {
                const double mid = 0.5 * (lo + hi);
                auto qm = kin.inverse(line.at(mid), qlo);
                if (qm && finite(*qm)) {
                    lo = mid;
                    qlo = *qm;
                } else {
                    hi = mid;
                }
            }
            return linError("out of reach", hi, line.at(hi).translation());
        }
        knots.push_back(*q);
    }

    // 2. Singularities / configuration jumps. A smooth path's step rate converges when the
    // step is halved; near a singularity it grows without bound and at a jump it doubles
    // with every halving. Refine the worst steps (and every large one) down to a tiny step
    // and refuse when the joint velocity limits would then force the TCP below the minimum
    // speeds.
    const Joints& vmax = limits.joint.maxVelocity;
    std::vector<std::pair<double, std::size_t>> rates(n);
    for (std::size_t k = 0; k < n; ++k)
        rates[k] = {stepRate(knots[k], knots[k + 1], sAt(k + 1) - sAt(k), vmax), k};
    std::vector<std::size_t> suspects;
    {
        auto sorted = rates;
        const std::size_t top = std::min<std::size_t>(3, sorted.size());
        std::partial_sort(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(top),
                          sorted.end(), [](const auto& a, const auto& b) {
                              return a.first > b.first ||
                                     (a.first == b.first && a.second < b.second);
                          });
        for (std::size_t j = 0; j < top; ++j) suspects.push_back(sorted[j].second);
        // Also every large step and every local spike of the rate (a smooth path's rate
        // varies smoothly from step to step; a jump or a singularity stands out).
        for (std::size_t k = 0; k < n && suspects.size() < 64; ++k) {
            const double left = k > 0 ? rates[k - 1].first : 0.0;
            const double right = k + 1 < n ? rates[k + 1].first : 0.0;
            bool suspect = n > 2 && rates[k].first > 1.5 * std::max(left, right);
            for (std::size_t i = 0; i < kAxes; ++i)
                suspect = suspect || std::abs(knots[k + 1][i] - knots[k][i]) > 0.1;
            if (suspect) suspects.push_back(k);
        }
        std::sort(suspects.begin(), suspects.end());
        suspects.erase(std::unique(suspects.begin(), suspects.end()), suspects.end());
    }
    auto tooSlow = [&](double rate) {
        // rate = 1 / (allowed ds/dt); the TCP would move at len/rate and angle/rate.
        const bool linSlow = len == 0.0 || len < opt.minLinearSpeed * rate;
        const bool angSlow = angle == 0.0 || angle < opt.minAngularSpeed * rate;
        return linSlow && angSlow;
    };
    for (std::size_t k : suspects) {
        double a = sAt(k), b = sAt(k + 1);
        Joints qa = knots[k], qb = knots[k + 1];
        double rate = stepRate(qa, qb, b - a, vmax);
        // Always refine fully: it also locates the spot for the report.
        for (int it = 0; it < 24; ++it) {
            const double mid = 0.5 * (a + b);
            auto qm = kin.inverse(line.at(mid), qa);
            if (!qm || !finite(*qm))
                return linError("out of reach", mid, line.at(mid).translation());
            const double r1 = stepRate(qa, *qm, mid - a, vmax);
            const double r2 = stepRate(*qm, qb, b - mid, vmax);
            if (r1 >= r2) {
                b = mid;
                qb = *qm;
                rate = r1;
            } else {
                a = mid;
                qa = *qm;
                rate = r2;
            }
        }
        if (tooSlow(rate)) {
            const double s = 0.5 * (a + b);
            return linError("singularity (joint velocity demand unbounded or IK jump)", s,
                            line.at(s).translation());
        }
    }

    auto path = std::make_shared<LinPath>(line, std::move(knots));

    // 3. Path bounds from the Cartesian limits (the line is linear in s, slerp has constant
    // angular speed: both are exact).
    const PathBounds cartesian = cartesianPathBounds(len, angle, cl);
    double vs = cartesian.velocity;
    double as = cartesian.acceleration;

    // 4. Joint limits for ANY timing law with |ds/dt| <= vs, |d2s/dt2| <= as (so stop and
    // resume stay within them too): |qd| <= |q'| vs, |qdd| <= |q''| vs^2 + |q'| as, with the
    // exact maxima of the Hermite segments.
    const Joints& amax = limits.joint.maxAcceleration;
    const double nn = static_cast<double>(path->segments());
    auto bounds = [&](std::size_t j) {  // max |q'|, max |q''| of segment j / 6, axis j % 6
        const auto c = path->coeff(j / kAxes, j % kAxes);
        auto d1 = [&](double u) { return std::abs(c[1] + u * (2.0 * c[2] + 3.0 * u * c[3])); };
        double m1 = std::max(d1(0.0), d1(1.0));
        if (c[3] != 0.0) {
            const double u = -c[2] / (3.0 * c[3]);
            if (u > 0.0 && u < 1.0) m1 = std::max(m1, d1(u));
        }
        return std::array<double, 2>{
            m1 * nn, nn * nn * std::max(std::abs(2.0 * c[2]), std::abs(2.0 * c[2] + 6.0 * c[3]))};
    };
    const std::size_t nb = path->segments() * kAxes;
    // Two ways to get within them; the faster one wins. (a) Scale time by k: vs / k, as / k^2.
    // (b) Cap vs by the velocity limits alone, then give as whatever acceleration is left.
    double need = 0.0, vsB = vs;
    for (std::size_t j = 0; j < nb; ++j) {
        const auto [m1, m2] = bounds(j);
        const std::size_t i = j % kAxes;
        need = std::max(need, m1 * vs / vmax[i]);
        need = std::max(need, std::sqrt((m2 * vs * vs + m1 * as) / amax[i]));
        if (m1 > 0.0) vsB = std::min(vsB, vmax[i] / m1);
    }
    double asB = as;
    for (std::size_t j = 0; j < nb; ++j) {
        const auto [m1, m2] = bounds(j);
        const double left = amax[j % kAxes] - m2 * vsB * vsB;
        if (m1 > 0.0) asB = std::min(asB, left / m1);
        if (left < 0.0) asB = -1.0;
    }
    if (need > 1.0) {
        const double vsA = vs / need, asA = as / (need * need);
        if (asB > 0.0 && TimingLaw::restToRest(0.0, 1.0, vsB, asB).duration() <
                             TimingLaw::restToRest(0.0, 1.0, vsA, asA).duration()) {
            vs = vsB;
            as = asB;
        } else {
            vs = vsA;
            as = asA;
        }
    }

    // 5. Re-check the actual trajectory sampled in time; slow down further if needed.
    for (int it = 0;; ++it) {
        Trajectory traj(Trajectory::Kind::Lin, path, TimingLaw::restToRest(0.0, 1.0, vs, as), vs,
                        as);
        double worstV = 0.0, worstA = 0.0;
        const double T = traj.duration();
        // At most 100k checks: a very slow motion is checked more coarsely (the envelope of
        // step 4 is the actual guarantee; this catches what lies between the bounds' points).
        const double dt = std::max(opt.checkStep, T / 1e5);
        const auto steps = static_cast<std::size_t>(std::ceil(T / dt));
        for (std::size_t j = 0; j <= steps; ++j) {
            const JointSample q = traj.sample(std::min(T, static_cast<double>(j) * dt));
            for (std::size_t i = 0; i < kAxes; ++i) {
                worstV = std::max(worstV, std::abs(q.velocity[i]) / vmax[i]);
                worstA = std::max(worstA, std::abs(q.acceleration[i]) / amax[i]);
            }
        }
        const double worst = std::max(worstV, std::sqrt(worstA));
        if (worst <= 1.0) return traj;
        if (it + 1 >= opt.maxRetimeIterations)
            return Error{"LIN: could not retime within the joint limits", {}, {}};
        const double k = worst * (1.0 + 1e-9);
        vs /= k;
        as /= k * k;
    }
}

}  // namespace pnp::motion
