// The vendor-neutral real-time control loop: one thread paced by HardwareInterface::read()
// (500 Hz for a UR e-Series) that streams the running motion's interpolated joint targets,
// brakes along the path on halt / suspend / a lost link / excessive force, and keeps loop
// statistics. Planning (robot/planner.hpp) happens before a motion is handed over; the loop
// only samples trajectories. Long work never runs here.
#pragma once

#include <Eigen/Geometry>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <stop_token>
#include <string>

#include "motion/motion.hpp"
#include "robot/hardware.hpp"

namespace pnp::robot {

struct ControllerConfig {
    // No sample for this long = link lost: the motion fails and the loop reconnects. The
    // robot itself is stopped by the controller's own watchdog when targets stop coming (the
    // servo program's), so this only decides when to give up on the link; 250 ms rides out a
    // loaded machine's scheduling stalls (100 ms did not, in CI runs of the whole cell).
    std::chrono::milliseconds readTimeout{250};
    std::chrono::milliseconds reconnectDelay{500};
    // Used to brake when no trajectory is running (e.g. a position stream): rad/s².
    motion::JointLimits limits;
    // Added: one (re)connect attempt may take this long (start() has its own deadline).
    std::chrono::milliseconds connectTimeout{2000};
    // Told when the link is lost (why) and when it is back; called on the loop thread, must
    // not block. Empty: nobody is told (the statistics still count the losses).
    std::function<void(const std::string&)> log;
};

// How a motion ended.
enum class MotionEnd {
    kCompleted,      // at the goal
    kHalted,         // halt(): braked along the path to rest
    kForceExceeded,  // the force limit was exceeded: braked along the path to rest
    kFailed,         // link lost, protective stop, controller stopped following...
};

struct MotionResult {
    MotionEnd end = MotionEnd::kCompleted;
    std::string message;                                 // why, for anything but kCompleted
    Eigen::Vector3d maxForce = Eigen::Vector3d::Zero();  // largest |force| per axis seen, N
};

struct MotionOptions {
    // Base-frame force limit per axis (N, absolute values): exceeding any component ends
    // the motion with kForceExceeded. nullopt = no force monitoring.
    std::optional<Eigen::Vector3d> maxForce;
};

// One running motion (a trajectory or a position stream). Thread-safe.
class Motion {
  public:
    virtual ~Motion() = default;
    // Blocks until the motion has ended (the robot at rest) or the deadline / stop request.
    virtual std::optional<MotionResult> wait(Deadline deadline, std::stop_token stop = {}) = 0;
    virtual bool finished() const = 0;
    // Brakes along the path; the motion ends kHalted once at rest. The first cycle after the
    // call already decelerates.
    virtual void halt() = 0;
    // Brakes along the path and stays there (not finished); resume() continues the same path.
    virtual void suspend() = 0;
    virtual void resume() = 0;
    virtual bool suspended() const = 0;
    virtual double progress() const = 0;  // path parameter 0..1 (streams: 0)
};

// A position stream: the loop follows the latest target, speed- and acceleration-limited.
class Stream : public Motion {
  public:
    virtual void setTarget(const Joints& q) = 0;  // checked by the caller (limits, finite)
};

struct LoopStats {
    std::uint64_t cycles = 0;
    double periodMedian = 0.0;    // s, between successive samples (recent window)
    double periodErrorP99 = 0.0;  // s, |period - cycleTime| at the 99th percentile
    double periodErrorMax = 0.0;
    std::uint64_t linkLosses = 0;
    // Added: samples in the window behind the figures, and whether the loop thread got
    // SCHED_FIFO (false: normal scheduling, e.g. no CAP_SYS_NICE / rtprio limit).
    std::uint64_t window = 0;
    bool realtime = false;
};

class Controller {
  public:
    Controller(HardwareInterface& hardware, ControllerConfig config);
    ~Controller();  // stop()
    Controller(const Controller&) = delete;
    Controller& operator=(const Controller&) = delete;

    // Connects (until the deadline) and starts the loop thread; it reconnects by itself
    // after a lost link.
    Result<Done> start(Deadline deadline);
    void stop();

    bool connected() const;
    std::optional<State> state() const;  // the latest sample
    // Called on the loop thread after every sample (keep it short: copy and return).
    // Replacing it (e.g. onState({})) returns only once the old one no longer runs, so a
    // callback capturing locals is safe if it is cleared before they go.
    void onState(std::function<void(const State&)> callback);

    // Hands a planned trajectory to the loop; it must start at the current position
    // (within 1e-3 rad), else refused. One motion at a time: refused while another runs.
    Result<std::shared_ptr<Motion>> execute(motion::Trajectory trajectory,
                                            MotionOptions options = {});
    Result<std::shared_ptr<Stream>> stream(const motion::JointLimits& limits);

    LoopStats stats() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::robot
