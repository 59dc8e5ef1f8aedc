#include "robot/planner.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>

#include "kinematics/kinematics.hpp"

namespace pnp::robot {
namespace {

constexpr double kConfigurationTolerance = 1e-6;  // rad: "the same configuration"

std::string num(double x) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.4g", x);
    return buf;
}

std::string point(const Eigen::Vector3d& p) {
    return "(" + num(p.x()) + ", " + num(p.y()) + ", " + num(p.z()) + ")";
}

bool finiteJoints(const Joints& q) {
    return std::all_of(q.begin(), q.end(), [](double x) { return std::isfinite(x); });
}

// A rigid transform: finite, a proper rotation (not scaled, sheared or mirrored).
std::string checkPose(const Eigen::Isometry3d& pose, const std::string& name) {
    if (!pose.matrix().allFinite()) return name + " contains a value that is not finite";
    const Eigen::Matrix3d r = pose.linear();
    if ((r.transpose() * r - Eigen::Matrix3d::Identity()).norm() > 1e-6 || r.determinant() <= 0.0)
        return name + ": the orientation is not a rotation (scaled, sheared or mirrored)";
    return {};
}

std::string checkCurrent(const Joints& current) {
    if (!finiteJoints(current)) return "the robot's current joint position is not finite";
    return {};
}

// 0 = the defaults, 1 = every axis, 6 = one per axis; each finite, > 0, <= the maximum.
Result<Joints> axisValues(const std::vector<double>& values, const Joints& maxima,
                          const std::string& name, const char* unit) {
    Joints out = maxima;
    if (values.empty()) return out;
    if (values.size() != 1 && values.size() != out.size())
        return Error{name + " has " + std::to_string(values.size()) +
                     " values: give none (the defaults), 1 (every axis) or 6 (one per axis)"};
    for (std::size_t i = 0; i < out.size(); ++i) {
        const std::size_t k = values.size() == 1 ? 0 : i;
        const double v = values[k];
        const std::string what = name + "[" + std::to_string(k) + "] = " + num(v) + " " + unit;
        if (!std::isfinite(v)) return Error{what + " is not a finite number"};
        if (v <= 0.0) return Error{what + " must be greater than 0"};
        if (v > maxima[i])
            return Error{what + " is above the robot's maximum " + num(maxima[i]) + " " + unit +
                         (values.size() == 1 ? " (axis " + std::to_string(i) + ")" : "")};
        out[i] = v;
    }
    return out;
}

// LIN: 0, 1 (linear), 2 (linear, angular) or 4 (x, y, z, angular; linear = min of x, y, z).
Result<std::pair<double, double>> linValues(const std::vector<double>& values, double maxLinear,
                                            double maxAngular, const std::string& name,
                                            const char* linearUnit, const char* angularUnit) {
    const std::size_t n = values.size();
    if (n != 0 && n != 1 && n != 2 && n != 4)
        return Error{name + " has " + std::to_string(n) +
                     " values: give none (the defaults), 1 (linear), 2 (linear, angular) or 4 "
                     "(x, y, z, angular)"};
    for (std::size_t k = 0; k < n; ++k) {
        const bool angular = (n == 2 && k == 1) || (n == 4 && k == 3);
        const double v = values[k];
        const double max = angular ? maxAngular : maxLinear;
        const char* unit = angular ? angularUnit : linearUnit;
        const std::string what = name + "[" + std::to_string(k) + "] = " + num(v) + " " + unit;
        if (!std::isfinite(v)) return Error{what + " is not a finite number"};
        if (v <= 0.0) return Error{what + " must be greater than 0"};
        if (v > max) return Error{what + " is above the robot's maximum " + num(max) + " " + unit};
    }
    double linear = maxLinear;
    double angular = maxAngular;
    if (n == 1 || n == 2) linear = values[0];
    if (n == 2) angular = values[1];
    if (n == 4) {
        linear = std::min({values[0], values[1], values[2]});
        angular = values[3];
    }
    return std::pair{linear, angular};
}

std::string checkBounds(const std::optional<kinematics::AxisBounds>& bounds,
                        const kinematics::RobotModel& model, const Joints& current) {
    if (!bounds) return {};
    for (std::size_t i = 0; i < current.size(); ++i) {
        const double lo = bounds->min[i], hi = bounds->max[i];
        const std::string axis = "AxisBounds[" + std::to_string(i) + "]";
        if (!std::isfinite(lo) || !std::isfinite(hi))
            return axis + " = [" + num(lo) + ", " + num(hi) + "] is not finite";
        if (lo > hi) return axis + ": the minimum " + num(lo) + " is above the maximum " + num(hi);
        if (hi < model.limits[i].minPosition || lo > model.limits[i].maxPosition)
            return axis + " = [" + num(lo) + ", " + num(hi) + "] lies outside the joint limits [" +
                   num(model.limits[i].minPosition) + ", " + num(model.limits[i].maxPosition) + "]";
        // The motion starts at the current position: a robot outside the bounds would leave
        // them (or travel outside them) on its way.
        if (current[i] < lo || current[i] > hi)
            return axis + " = [" + num(lo) + ", " + num(hi) + "] rad: the robot's axis " +
                   std::to_string(i) + " is at " + num(current[i]) + " rad, outside the bounds";
    }
    return {};
}

Eigen::Isometry3d interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double s) {
    Eigen::Quaterniond qa(a.rotation()), qb(b.rotation());
    if (qa.dot(qb) < 0.0) qb.coeffs() = -qb.coeffs();
    Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
    out.linear() = qa.slerp(s, qb).normalized().toRotationMatrix();
    out.translation() = (1.0 - s) * a.translation() + s * b.translation();
    return out;
}

}  // namespace

Planner::Planner(PlannerConfig config)
    : config_(std::move(config)), worldToBase_(config_.worldToBase) {
    // Unset or impossible defaults become the model's ratings; none may exceed them.
    for (std::size_t i = 0; i < config_.model.limits.size(); ++i) {
        const auto& m = config_.model.limits[i];
        double& v = config_.defaults.joint.maxVelocity[i];
        double& a = config_.defaults.joint.maxAcceleration[i];
        v = std::isfinite(v) && v > 0.0 ? std::min(v, m.maxVelocity) : m.maxVelocity;
        a = std::isfinite(a) && a > 0.0 ? std::min(a, m.maxAcceleration) : m.maxAcceleration;
    }
}

void Planner::setWorldToBase(const Eigen::Isometry3d& worldToBase) {
    worldToBase_.set(worldToBase);
}

Eigen::Isometry3d Planner::worldToBase() const { return worldToBase_.get(); }

const kinematics::RobotModel& Planner::model() const { return config_.model; }

Eigen::Isometry3d Planner::toolPose(const Joints& q, const Eigen::Isometry3d& tool) const {
    return worldToBase_.get() * kinematics::forward(config_.model, q) * tool;
}

Result<Joints> Planner::checkJoints(const std::vector<double>& target) const {
    if (target.size() != kinematics::kAxes)
        return Error{"TargetJointPosition has " + std::to_string(target.size()) +
                     " values: the robot has 6 axes"};
    Joints q{};
    for (std::size_t i = 0; i < q.size(); ++i) {
        const double v = target[i];
        const auto& l = config_.model.limits[i];
        const std::string what = "TargetJointPosition[" + std::to_string(i) + "] = " + num(v);
        if (!std::isfinite(v)) return Error{what + " is not a finite number"};
        if (v < l.minPosition || v > l.maxPosition) {
            char buf[64];
            std::snprintf(buf, sizeof buf, "[%.3f, %.3f]", l.minPosition, l.maxPosition);
            return Error{what + " rad is outside the joint limits " + buf};
        }
        q[i] = v;
    }
    return q;
}

Result<motion::JointLimits> Planner::jointLimits(const PtpLimits& limits) const {
    auto v =
        axisValues(limits.maxVelocity, config_.defaults.joint.maxVelocity, "MaxVelocity", "rad/s");
    if (!v) return v.error();
    auto a = axisValues(limits.maxAcceleration, config_.defaults.joint.maxAcceleration,
                        "MaxAcceleration", "rad/s²");
    if (!a) return a.error();
    return motion::JointLimits{*v, *a};
}

Result<motion::CartesianLimits> Planner::cartesianLimits(const LinLimits& limits) const {
    const auto& d = config_.defaults.cartesian;
    auto v = linValues(limits.maxVelocity, d.maxLinearVelocity, d.maxAngularVelocity, "MaxVelocity",
                       "m/s", "rad/s");
    if (!v) return v.error();
    auto a = linValues(limits.maxAcceleration, d.maxLinearAcceleration, d.maxAngularAcceleration,
                       "MaxAcceleration", "m/s²", "rad/s²");
    if (!a) return a.error();
    return motion::CartesianLimits{v->first, a->first, v->second, a->second};
}

Result<Joints> Planner::solve(const Joints& current, const CartesianTarget& target) const {
    if (auto e = checkCurrent(current); !e.empty()) return Error{e};
    if (auto e = checkPose(target.pose, "TargetPosition"); !e.empty()) return Error{e};
    if (auto e = checkPose(target.tool, "the tool frame"); !e.empty()) return Error{e};
    if (auto e = checkBounds(target.bounds, config_.model, current); !e.empty()) return Error{e};
    const Eigen::Isometry3d flange =
        worldToBase_.get().inverse() * target.pose * target.tool.inverse();
    auto q = kinematics::solveNearest(config_.model, flange, current, target.bounds);
    if (q) return *q;
    const std::string where = "TargetPosition " + point(target.pose.translation());
    switch (q.error().code) {
        case kinematics::ErrorCode::kOutOfReach:
            return Error{where + " is out of reach"};
        case kinematics::ErrorCode::kOutsideJointLimits:
            return Error{where + " can only be reached outside the joint limits"};
        case kinematics::ErrorCode::kOutsideAxisBounds:
            return Error{"AxisBounds: " + where + " can only be reached outside the axis bounds"};
        default:
            break;
    }
    return Error{where + ": " + q.error().message};
}

Result<motion::Trajectory> Planner::cartesianPtp(const Joints& current,
                                                 const CartesianTarget& target,
                                                 const PtpLimits& limits) const {
    auto l = jointLimits(limits);
    if (!l) return l.error();
    auto goal = solve(current, target);
    if (!goal) return goal.error();
    auto t = motion::planPtp(current, *goal, *l);
    if (!t) return Error{"PTP refused: " + t.error().message};
    return std::move(*t);
}

Result<motion::Trajectory> Planner::jointPtp(const Joints& current,
                                             const std::vector<double>& target,
                                             const PtpLimits& limits) const {
    if (auto e = checkCurrent(current); !e.empty()) return Error{e};
    auto l = jointLimits(limits);
    if (!l) return l.error();
    auto goal = checkJoints(target);
    if (!goal) return goal.error();
    auto t = motion::planPtp(current, *goal, *l);
    if (!t) return Error{"PTP refused: " + t.error().message};
    return std::move(*t);
}

namespace {

struct LinRequest {
    const kinematics::RobotModel* model;
    Eigen::Isometry3d worldToBase;
    Eigen::Isometry3d tool;
    std::optional<kinematics::AxisBounds> bounds;
};

motion::Kinematics linKinematics(const LinRequest& r) {
    const Eigen::Isometry3d toolInv = r.tool.inverse();
    return motion::Kinematics{
        [model = r.model, tool = r.tool](const Joints& q) {
            return kinematics::forward(*model, q) * tool;
        },
        [model = r.model, toolInv, bounds = r.bounds](const Eigen::Isometry3d& pose,
                                                      const Joints& seed) -> std::optional<Joints> {
            auto q = kinematics::solveNearest(*model, pose * toolInv, seed, bounds);
            if (!q) return std::nullopt;
            return *q;
        }};
}

// The planner's refusal in the operator's words: where on the line and why there.
Error linRefusal(const motion::Error& e, const LinRequest& r, const Eigen::Isometry3d& startTool,
                 const Eigen::Isometry3d& goalTool, const Joints& current) {
    if (!e.fraction || !e.position) return Error{"LIN refused: " + e.message};
    const double s = std::clamp(*e.fraction, 0.0, 1.0);
    char pct[16];
    std::snprintf(pct, sizeof pct, "%.0f %%", s * 100.0);
    const std::string where = std::string(pct) + " " + point(r.worldToBase * *e.position);
    if (e.message.find("singular") != std::string::npos)
        return Error{"the line passes a singularity at " + where};
    // Which constraint ends the line there: ask the IK without and with the bounds.
    const Eigen::Isometry3d flange = interpolate(startTool, goalTool, s) * r.tool.inverse();
    auto free = kinematics::solveNearest(*r.model, flange, current);
    if (!free && free.error().code == kinematics::ErrorCode::kOutOfReach)
        return Error{"the line leaves the robot's reach at " + where};
    if (!free) return Error{"the line leaves the joint limits at " + where};
    if (r.bounds) return Error{"AxisBounds: the line leaves the axis bounds at " + where};
    return Error{"the line cannot be followed at " + where + " (" + e.message + ")"};
}

// LinOptions' rule ("refused as singular when the joint limits force the TCP below both
// minimum speeds"), applied to the final timing. motion::planLin checks the velocity bound
// on its sampled steps; near a wrist flip the acceleration bound (|q''| vs²) can still make
// the line crawl: many times slower than the Cartesian limits alone and below both speeds
// on average. The ratio keeps tiny, legitimately slow corrections.
std::optional<Error> crawl(const motion::Trajectory& t, const Eigen::Isometry3d& startTool,
                           const Eigen::Isometry3d& goalTool, const motion::LinOptions& opt,
                           const motion::Limits& limits, const Eigen::Isometry3d& worldToBase) {
    constexpr double kSlowdown = 4.0;
    const double len = (goalTool.translation() - startTool.translation()).norm();
    const double angle =
        Eigen::AngleAxisd(startTool.rotation().transpose() * goalTool.rotation()).angle();
    if ((len == 0.0 && angle == 0.0) || !(t.duration() > 0.0)) return std::nullopt;
    const auto bounds = motion::cartesianPathBounds(len, angle, limits.cartesian);
    const double cartesianDuration =
        motion::TimingLaw::restToRest(0.0, 1.0, bounds.velocity, bounds.acceleration).duration();
    const bool linSlow = len / t.duration() < opt.minLinearSpeed;
    const bool angSlow = angle / t.duration() < opt.minAngularSpeed;
    if (!(t.duration() > kSlowdown * cartesianDuration) || !linSlow || !angSlow)
        return std::nullopt;
    const motion::JointLimits& joint = limits.joint;
    // The spot: where the joint speed demand peaks (the path speed is constant at cruise).
    constexpr int kSamples = 2000;
    double worst = -1.0, worstT = 0.0;
    for (int k = 0; k <= kSamples; ++k) {
        const double time = t.duration() * k / kSamples;
        const auto smp = t.sample(time);
        const double v = t.pathState(time).v;
        if (v <= 0.0) continue;
        double r = 0.0;
        for (std::size_t i = 0; i < smp.velocity.size(); ++i)
            r = std::max(r, std::abs(smp.velocity[i]) / (joint.maxVelocity[i] * v));
        if (r > worst) {
            worst = r;
            worstT = time;
        }
    }
    const double s = t.pathState(worstT).s;
    const auto pose = t.pose(worstT);
    const Eigen::Vector3d p = pose ? Eigen::Vector3d(pose->translation()) : Eigen::Vector3d::Zero();
    char pct[16];
    std::snprintf(pct, sizeof pct, "%.0f %%", s * 100.0);
    return Error{"the line passes a singularity at " + std::string(pct) + " " +
                 point(worldToBase * p)};
}

}  // namespace

Result<motion::Trajectory> Planner::cartesianLinear(const Joints& current,
                                                    const CartesianTarget& target,
                                                    const LinLimits& limits) const {
    auto cl = cartesianLimits(limits);
    if (!cl) return cl.error();
    // The goal's IK first: its refusal names the target (reach, joint limits, bounds).
    auto goalQ = solve(current, target);
    if (!goalQ) return goalQ.error();
    const LinRequest r{&config_.model, worldToBase_.get(), target.tool, target.bounds};
    const Eigen::Isometry3d goal = r.worldToBase.inverse() * target.pose;  // tool in base
    const Eigen::Isometry3d start = kinematics::forward(config_.model, current) * target.tool;
    const motion::Limits ml{config_.defaults.joint, *cl};
    auto t = motion::planLin(current, goal, linKinematics(r), ml, config_.lin);
    if (!t) return linRefusal(t.error(), r, start, goal, current);
    if (auto e = crawl(*t, start, goal, config_.lin, ml, r.worldToBase)) return *e;
    return std::move(*t);
}

Result<motion::Trajectory> Planner::jointLinear(const Joints& current,
                                                const std::vector<double>& target,
                                                const Eigen::Isometry3d& tool,
                                                const LinLimits& limits) const {
    if (auto e = checkCurrent(current); !e.empty()) return Error{e};
    if (auto e = checkPose(tool, "the tool frame"); !e.empty()) return Error{e};
    auto cl = cartesianLimits(limits);
    if (!cl) return cl.error();
    auto goalQ = checkJoints(target);
    if (!goalQ) return goalQ.error();
    const LinRequest r{&config_.model, worldToBase_.get(), tool, std::nullopt};
    const Eigen::Isometry3d goal = kinematics::forward(config_.model, *goalQ) * tool;
    const Eigen::Isometry3d start = kinematics::forward(config_.model, current) * tool;
    const motion::Limits ml{config_.defaults.joint, *cl};
    auto t = motion::planLin(current, goal, linKinematics(r), ml, config_.lin);
    if (!t) return linRefusal(t.error(), r, start, goal, current);
    if (auto e = crawl(*t, start, goal, config_.lin, ml, r.worldToBase)) return *e;
    const Joints end = t->sample(t->duration()).position;
    for (std::size_t i = 0; i < end.size(); ++i) {
        if (!(std::abs(end[i] - (*goalQ)[i]) <= kConfigurationTolerance))
            return Error{
                "a straight line from the current position ends in another "
                "configuration than TargetJointPosition: axis " +
                std::to_string(i) + " would end at " + num(end[i]) + " rad instead of " +
                num((*goalQ)[i]) + " rad (use a PTP move)"};
    }
    return std::move(*t);
}

}  // namespace pnp::robot
