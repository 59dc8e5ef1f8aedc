// What the move skills of one robot share (private to pnp_device_robot): the controller, the
// planner, and the tool frames of SetTool.
#pragma once

#include <Eigen/Geometry>
#include <chrono>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "robot/controller.hpp"
#include "robot/planner.hpp"
#include "ua/types/builtin.hpp"

namespace pnp::device::robot::detail {

namespace rb = pnp::robot;

struct Timing {
    std::chrono::milliseconds waitSlice{10};
    std::chrono::milliseconds restTimeout{10000};
};

class MotionContext {
  public:
    static constexpr std::size_t kMaxTools = 64;
    static constexpr std::size_t kMaxToolNameLength = 256;

    MotionContext(rb::Controller& controller, rb::Planner& planner, Timing timing)
        : controller_(controller), planner_(planner), timing_(timing) {}

    rb::Controller& controller() const { return controller_; }
    const Timing& timing() const { return timing_; }

    // Runs f(planner): planning happens on the skills' workers only (the planner is
    // thread-safe; its world -> base pose may change meanwhile from the network thread).
    template <class F>
    auto plan(F&& f) const {
        return std::forward<F>(f)(static_cast<const rb::Planner&>(planner_));
    }
    rb::Result<rb::Joints> checkJoints(const std::vector<double>& q) const {
        return planner_.checkJoints(q);
    }
    const kinematics::RobotModel& model() const { return planner_.model(); }

    // WorldToRobotBase (any thread; quick): used from the next plan on.
    void setWorldToBase(const Eigen::Isometry3d& worldToBase) {
        planner_.setWorldToBase(worldToBase);
    }
    Eigen::Isometry3d worldToBase() const { return planner_.worldToBase(); }

    // SetTool: registers (frame given) and activates a named flange -> tool frame.
    // Bad_InvalidArgument for an empty or too long name, an unknown name without a frame, a
    // frame that is not finite, or too many tools; nothing changes then.
    ua::StatusCode setTool(const std::string& name, const std::optional<Eigen::Isometry3d>& frame);
    // ClearTool: "" deactivates the active tool (the flange is used); a name removes that
    // tool (and deactivates it if it was active); an unknown name is Bad_InvalidArgument.
    ua::StatusCode clearTool(const std::string& name);
    std::string activeTool() const {
        std::lock_guard l(frameMutex_);
        return active_;
    }
    // The flange -> tool frame a move's ToolFrame names: "" = the active tool (the flange
    // when none); an unknown name = nullopt with the reason in `error`.
    std::optional<Eigen::Isometry3d> toolFrame(const std::string& name, std::string& error) const;

  private:
    rb::Controller& controller_;
    rb::Planner& planner_;
    Timing timing_;
    mutable std::mutex frameMutex_;  // the tools
    std::map<std::string, Eigen::Isometry3d, std::less<>> tools_;
    std::string active_;
};

}  // namespace pnp::device::robot::detail
