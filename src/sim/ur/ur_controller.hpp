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

#include <cstddef>
#include <cstdint>
#include <mutex>
#include <string_view>

#include "rtde/server.hpp"
#include "world/world.hpp"

namespace pnp::sim::ur {

struct UrControllerConfig {
    std::size_t robot = 0;  // index in the world
    double watchdogTimeout = 0.1;  // s of simulated time without a new input package
    // Controller limits per joint; 0 = the robot model's (velocity) / 4 × the model's
    // (acceleration: a UR brakes harder than the planner's default).
    double maxVelocity = 0.0;
    double maxAcceleration = 0.0;
    // Protective stop when |TCP force| exceeds this (N), as a UR's safety system does.
    double protectiveStopForce = 250.0;
};

class UrController : public rtde::ControllerState {
  public:
    UrController(world::World& world, UrControllerConfig config);

    // rtde::ControllerState (RTDE network thread).
    rtde::Value read(std::string_view name) override;
    void write(std::string_view name, const rtde::Value& value) override;

    // The simulator's stepping thread: latches inputs, servos, writes the world's joints.
    // Call before world.step(dt); publish() after it.
    void step(double dt);
    // Copies the world's state into the RTDE outputs (after world.step()).
    void publish();

    // For tests and the ground truth: the controller's view.
    bool following() const;
    bool watchdogTripped() const;
    bool protectiveStop() const;

  private:
    struct Inputs;
    world::World& world_;
    UrControllerConfig config_;
    mutable std::mutex mutex_;
    // ... implementation state (helper's choice)
};

}  // namespace pnp::sim::ur
