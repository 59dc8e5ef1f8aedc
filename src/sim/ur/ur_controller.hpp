// The simulated Universal Robots controller: the device side of RTDE for one robot of the
// world. It is an rtde::ControllerState (the RTDE server reads outputs and writes inputs on
// its network thread) and is stepped by the simulator's fixed-rate loop, where it runs the
// equivalent of the servo URScript we ship for real robots (docs/ur-real-robot.md): while
// input_int_register_0 = 1 it servos to the joint targets in input_double_register_0..5,
// within the controller's joint speed and acceleration limits; a watchdog stops the robot
// (decelerating) when inputs stop coming, and it then stays still until the register is
// set to 0 and to 1 again. Inputs are latched at the start of a step, so stepping is
// deterministic for a given input sequence.
#pragma once

#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "rtde/server.hpp"
#include "world/world.hpp"

namespace pnp::sim::ur {

struct UrControllerConfig {
    std::size_t robot = 0;         // index in the world
    double watchdogTimeout = 0.1;  // s of simulated time without a new input package
    // Controller limits per joint; 0 = the robot model's (velocity) / 4 × the model's
    // (acceleration: a UR brakes harder than the planner's default).
    double maxVelocity = 0.0;
    double maxAcceleration = 0.0;
    // Protective stop when |TCP force| exceeds this (N), as a UR's safety system does.
    double protectiveStopForce = 250.0;
    // Told (on the stepping thread; rare) when a protective stop starts, with the force and
    // where, and when it is cleared: what an operator reads on a real UR's teach pendant.
    std::function<void(const std::string&)> log;
};

class UrController : public rtde::ControllerState {
  public:
    // Throws std::out_of_range for a robot index the world does not have and
    // std::invalid_argument for a non-finite or non-positive timeout or a negative limit.
    UrController(world::World& world, UrControllerConfig config);

    // rtde::ControllerState (RTDE network thread).
    rtde::Value read(std::string_view name) override;
    void write(std::string_view name, const rtde::Value& value) override;
    void endInputPackage() override;

    // The simulator's stepping thread: latches inputs, servos, writes the world's joints.
    // Call before world.step(dt); publish() after it.
    void step(double dt);
    // Copies the world's state into the RTDE outputs (after world.step()).
    void publish();

    // For tests and the ground truth: the controller's view.
    bool following() const;
    bool watchdogTripped() const;
    bool protectiveStop() const;
    // Input packages whose joint targets were rejected (non-finite or beyond the joint
    // limits) while following; the robot kept its previous target.
    std::uint64_t rejectedTargets() const;
    // Steps in which a followed stream had no target ready (the client was later than the
    // jitter buffer holds): the robot coasted on, then braked.
    std::uint64_t starvedSteps() const;
    // Stamped targets that came after their step (dropped).
    std::uint64_t lateTargets() const;
    // What a URScript program would write (write_output_*_register): sets an output register
    // (output_int_register_N, output_double_register_N, output_bit_register_N,
    // output_bit_registers*); false for any other name or a value of the wrong type.
    bool setOutputRegister(std::string_view name, const rtde::Value& value);
    // The last value a client wrote to an input variable (zero before); nullopt if unknown.
    std::optional<rtde::Value> input(std::string_view name) const;

  private:
    // What step() latches from the RTDE inputs, under the mutex.
    struct Inputs {
        std::int32_t mode = 0;     // input_int_register_0
        world::Joints targets{};   // input_double_register_0..5
        std::uint64_t writes = 0;  // input values written so far (the watchdog's feed)
        bool zeroSeen = false;     // register 0 written as 0 since the last latch
        bool target = false;       // targets holds a new target for this step
    };
    Inputs latch(double dt);
    void servo(const Inputs& in, double dt);
    void logProtectiveStop(const world::RobotState& robot) const;

    world::World& world_;
    UrControllerConfig config_;
    mutable std::mutex mutex_;

    // Guarded by mutex_ (shared with the RTDE network thread and readers).
    std::map<std::string, rtde::Value, std::less<>> outputs_;
    std::map<std::string, rtde::Value, std::less<>> inputs_;
    std::uint64_t inputWrites_ = 0;
    // Joint targets of whole input packages, oldest first: each step takes one (see
    // endInputPackage()). Empty and unused until the first package boundary is seen.
    struct Package {
        world::Joints targets{};
        // The state it answers (input_double_register_6 = that state's timestamp, in steps):
        // applied kBufferDepth steps after that state, dropped when later. None: in order.
        std::optional<std::uint64_t> answers;
    };
    std::deque<Package> packages_;
    bool stampWritten_ = false;  // input_double_register_6 written in the current package
    std::uint64_t lateTargets_ = 0;
    double dt_ = 0.0;        // of the last step (timestamps -> steps)
    bool packaged_ = false;  // package boundaries are known (a real RTDE server feeds us)
    bool primed_ = false;    // the buffer filled up to its depth since it last ran dry
    bool flush_ = false;     // the servo stopped following: drop what is buffered
    bool zeroSeen_ = false;
    bool followingShared_ = false;
    bool trippedShared_ = false;
    bool protectiveStopShared_ = false;
    std::uint64_t rejectedShared_ = 0;

    // The stepping thread's own (the servo program's state).
    world::Joints maxVelocity_{};
    world::Joints maxAcceleration_{};
    world::Joints target_{};
    world::Joints previousTarget_{};
    int bridged_ = 0;        // steps the stream has been carried on without a new target
    bool tracking_ = false;  // the last step ended on target_ (a stream being followed)
    std::uint64_t starved_ = 0;
    std::uint64_t starvedShared_ = 0;  // guarded by mutex_
    world::Joints commandAcceleration_{};
    bool armed_ = false;       // the register has been 1: the watchdog watches from then on
    bool following_ = false;   // servoing to target_
    bool tripped_ = false;     // the watchdog fired; waits for a re-arm
    bool protective_ = false;  // protective stop; waits for low force and a re-arm
    bool rearmZero_ = false;   // since the stop, register 0 has been seen 0
    std::uint64_t lastWrites_ = 0;
    std::uint64_t silentSteps_ = 0;
    std::uint64_t rejected_ = 0;
    // publish(): the previous TCP pose (base frame) and time, for actual_TCP_speed.
    std::optional<Eigen::Isometry3d> previousTcp_;
    double previousTime_ = 0.0;
};

}  // namespace pnp::sim::ur
