#include "component/pickplace/plan.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace pnp::component::pickplace {

namespace {

using Eigen::AngleAxisd;
using Eigen::Isometry3d;
using Eigen::Vector3d;

constexpr double kPi = 3.14159265358979323846;

std::string metres(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3f m", v);
    return buf;
}

Isometry3d raised(const Isometry3d& p, double h) {
    Isometry3d r = p;
    r.translation().z() += h;
    return r;
}

bool finite(const Isometry3d& p) { return p.matrix().allFinite(); }

}  // namespace

std::string toString(GripKind kind) { return kind == GripKind::Vacuum ? "vacuum" : "parallel"; }

std::optional<Plan> planPickAndPlace(const ObjectInfo& object, const GripPoint& grip,
                                     const Isometry3d& placePosition, const PlanOptions& options,
                                     std::string& error) {
    const Vector3d& size = object.size;
    if (!size.allFinite() || size.minCoeff() <= 0.0) {
        error = object.id + " has no valid size (" + metres(size.x()) + " x " + metres(size.y()) +
                " x " + metres(size.z()) + ")";
        return std::nullopt;
    }
    if (!finite(object.pose) || !finite(placePosition) || !finite(grip.offset)) {
        error = "a pose is not finite (the object's, the place position or the grip point)";
        return std::nullopt;
    }
    if (!std::isfinite(options.approachHeight) || options.approachHeight < 0.0) {
        error = "the approach height must be a finite number >= 0";
        return std::nullopt;
    }
    // Only upright objects are taken from above: their z axis along world z.
    auto tilt = [](const Isometry3d& p) {
        return std::acos(std::clamp(p.linear().col(2).dot(Vector3d::UnitZ()), -1.0, 1.0));
    };
    if (tilt(object.pose) > options.uprightTolerance) {
        error = object.id + " is not upright (tilted " + std::to_string(tilt(object.pose)) +
                " rad): it cannot be taken from above";
        return std::nullopt;
    }
    if (tilt(placePosition) > options.uprightTolerance) {
        error = "PlacePosition is tilted " + std::to_string(tilt(placePosition)) +
                " rad: the object is placed upright only";
        return std::nullopt;
    }
    // The grip frame relative to the object's centre (object frame): tool z down.
    const Isometry3d down(AngleAxisd(kPi, Vector3d::UnitY()));
    Isometry3d objectToGrip = Isometry3d::Identity();
    double width = 0.0;
    if (grip.kind == GripKind::Vacuum) {
        objectToGrip = Eigen::Translation3d(0, 0, size.z() / 2) * down;
    } else {
        const double open = grip.spanHigh - options.fingerClearance;
        if (size.x() <= open) {
            objectToGrip = down;  // the fingers' axis (grip x) along the object's x
            width = size.x();
        } else if (size.y() <= open) {
            objectToGrip = Isometry3d(AngleAxisd(kPi / 2, Vector3d::UnitZ())) * down;
            width = size.y();
        } else {
            error = object.id + " is " + metres(std::min(size.x(), size.y())) +
                    " wide across the fingers, the gripper opens to " + metres(grip.spanHigh) +
                    " at most (Span " + metres(grip.spanLow) + " to " + metres(grip.spanHigh) +
                    ", " + metres(options.fingerClearance) + " clearance)";
            return std::nullopt;
        }
        if (width < grip.spanLow) {
            error = object.id + " is " + metres(width) +
                    " wide, narrower than the gripper closes (" + metres(grip.spanLow) + ")";
            return std::nullopt;
        }
    }
    Plan p;
    p.gripWidth = width;
    p.pick = object.pose * objectToGrip;
    p.objectAtPlace = placePosition * Eigen::Translation3d(0, 0, size.z() / 2);
    p.place = p.objectAtPlace * objectToGrip;
    p.pickApproach = raised(p.pick, options.approachHeight);
    p.placeApproach = raised(p.place, options.approachHeight);
    return p;
}

}  // namespace pnp::component::pickplace
