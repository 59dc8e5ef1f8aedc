// Robot motion generation: PTP (synchronised joint-space) and LIN (straight Cartesian line)
// trajectories, time-parametrised so that no velocity / acceleration limit is exceeded.
// A trajectory is a geometric path q(s), s in [0, 1], plus a timing law s(t); stop() and
// resume() only swap the timing law, so both stay on the same path. Kinematics come in as
// callbacks (no dependency on a kinematics module). No exceptions cross this API.
#pragma once

#include <Eigen/Geometry>
#include <array>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <variant>

#include "base/result.hpp"
#include "motion/timing_law.hpp"

namespace pnp::motion {

using Joints = std::array<double, 6>;

struct Kinematics {
    std::function<Eigen::Isometry3d(const Joints&)> forward;
    // The solution nearest `seed` within the joint limits, or nullopt (out of reach).
    std::function<std::optional<Joints>(const Eigen::Isometry3d&, const Joints& seed)> inverse;
};

struct JointLimits {
    Joints maxVelocity{};      // rad/s, > 0
    Joints maxAcceleration{};  // rad/s^2, > 0
};

struct CartesianLimits {
    double maxLinearVelocity = 0.25;      // m/s
    double maxLinearAcceleration = 1.0;   // m/s^2
    double maxAngularVelocity = 1.0;      // rad/s
    double maxAngularAcceleration = 4.0;  // rad/s^2
};

struct Limits {
    JointLimits joint;
    CartesianLimits cartesian;
};

struct LinOptions {
    double linearStep = 1e-3;   // m between IK samples along the line
    double angularStep = 5e-3;  // rad of rotation between IK samples
    std::size_t maxSamples = 200000;
    // "Even at a very low speed": a path whose joint limits would force the TCP below both
    // of these speeds somewhere is refused as singular.
    double minLinearSpeed = 1e-3;   // m/s
    double minAngularSpeed = 1e-2;  // rad/s
    double checkStep = 2e-3;        // s: the final time-sampled limit check
    int maxRetimeIterations = 8;
};

struct Error {
    std::string message;
    std::optional<double> fraction;           // path fraction where it happens (LIN)
    std::optional<Eigen::Vector3d> position;  // Cartesian position there (LIN)
};

// A value or an Error: nothing in this module throws past its API.
template <class T>
using Result = base::Result<T, Error>;

struct JointSample {
    Joints position{};
    Joints velocity{};
    Joints acceleration{};
};

namespace detail {
class Path;
}

class Trajectory {
  public:
    enum class Kind { Ptp, Lin };

    Kind kind() const { return kind_; }
    double duration() const { return law_.duration(); }
    JointSample sample(double t) const;  // t clamped to [0, duration]
    // LIN: the Cartesian pose on the line at t (exact, not through the kinematics).
    std::optional<Eigen::Isometry3d> pose(double t) const;
    PathState pathState(double t) const { return law_.at(t); }
    double startParameter() const { return law_.startParameter(); }
    double endParameter() const { return law_.endParameter(); }  // 1 = the goal
    // Path speed / acceleration bounds that keep every limit (for any timing law within them).
    double pathVelocityLimit() const { return vs_; }
    double pathAccelerationLimit() const { return as_; }

    // From the state at time t of this trajectory: brake along the same path with the
    // maximum allowed deceleration; the result starts at that state (its t = 0) and ends at
    // rest at endParameter().
    Trajectory stop(double t) const;
    // From rest at s (e.g. stop(t).endParameter()) along the same path to the goal.
    Trajectory resume(double s) const;

  private:
    friend Result<Trajectory> planPtp(const Joints&, const Joints&, const JointLimits&);
    friend Result<Trajectory> planLin(const Joints&, const Eigen::Isometry3d&, const Kinematics&,
                                      const Limits&, const LinOptions&);
    Trajectory(Kind kind, std::shared_ptr<const detail::Path> path, TimingLaw law, double vs,
               double as)
        : kind_(kind), path_(std::move(path)), law_(law), vs_(vs), as_(as) {}

    Kind kind_;
    std::shared_ptr<const detail::Path> path_;
    TimingLaw law_;
    double vs_;
    double as_;
};

// Path speed and acceleration bounds (ds/dt, d²s/dt² for s in [0, 1]) that a straight line of
// `length` m turning by `angle` rad keeps within the Cartesian limits (infinite for a null
// move): the line is linear in s and the rotation's angular speed is constant.
struct PathBounds {
    double velocity;
    double acceleration;
};
PathBounds cartesianPathBounds(double length, double angle, const CartesianLimits& limits);

// Joint-space move; all axes start and stop together, the slowest axis sets the duration.
Result<Trajectory> planPtp(const Joints& start, const Joints& goal, const JointLimits& limits);

// Straight line of the TCP from forward(start) to goal, orientation by the shortest
// rotation. Refused (with fraction and position) when out of reach or singular.
Result<Trajectory> planLin(const Joints& start, const Eigen::Isometry3d& goal,
                           const Kinematics& kinematics, const Limits& limits,
                           const LinOptions& options = {});

}  // namespace pnp::motion
