// The move skills of urn:pnp:ua:skills:robotics over a robot::Controller (private to
// pnp_device_robot; semantics in README.md).
#pragma once

#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include "device/robot/motion_context.hpp"
#include "skill/server/skill.hpp"

namespace pnp::device::robot::detail {

// Cartesian (PTP, linear, linear with a force limit) and joint (PTP, linear) moves.
enum class MoveKind { CartesianPtp, CartesianLinear, CartesianLinearForce, JointPtp, JointLinear };
std::shared_ptr<skill::server::Skill> makeMoveSkill(MoveKind kind, MotionContext& context);

// A skill whose run owns one controller motion: Suspend, Resume and Halt reach the motion
// from the network thread at once (Motion is thread-safe and its calls are quick), not only
// at the run's next checkpoint.
class MotionSkill : public skill::server::Skill {
  public:
    MotionSkill(skill::ModelNode type, MotionContext& context) : Skill(type), context_(context) {}
    ua::StatusCode onSuspend() override;
    ua::StatusCode onResume() override;
    void onHalt() override;

  protected:
    // At the start and end of execute(): no motion, not suspended.
    void beginRun();
    void endRun();
    // From now on Suspend / Resume / Halt act on `motion` (a Suspend that came before is
    // applied at once).
    void attach(const std::shared_ptr<rb::Motion>& motion);

    MotionContext& context_;
    mutable std::mutex mutex_;  // after the skill runtime's lock (onSuspend runs under it)
    std::shared_ptr<rb::Motion> motion_;
    bool suspended_ = false;
};

// PositionStreamSkillType: while Running, the arm follows TargetJointPosition as clients
// write it (offer()), speed- and acceleration-limited by the controller; ends on Halt.
class PositionStreamSkill : public MotionSkill {
  public:
    explicit PositionStreamSkill(MotionContext& context);
    skill::server::Outcome execute(skill::server::Execution& run) override;
    // A Write of TargetJointPosition (network thread): while a stream runs the target is
    // checked (Bad_TypeMismatch / Bad_OutOfRange refuse the Write and nothing moves) and
    // handed to it; otherwise accepted as is (Start checks it).
    ua::StatusCode offer(const ua::Variant& value);

  private:
    skill::server::Param<std::vector<double>> target_;
    std::shared_ptr<rb::Stream> stream_;         // guarded by mutex_
    std::optional<std::vector<double>> latest_;  // the last Write while no stream ran
};

}  // namespace pnp::device::robot::detail
