// The move skills: read the parameters, plan (nothing moves on a refused request), hand the
// trajectory to the controller and follow it in slices (progress, Halt, a running-time
// budget). Suspend / Resume / Halt act on the motion directly (MotionSkill).
#include "device/robot/move_skills.hpp"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "skill/model/model.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::device::robot::detail {

using skill::server::Execution;
using skill::server::Outcome;
using skill::server::Param;
using Clock = std::chrono::steady_clock;

// ---- MotionSkill --------------------------------------------------------------------------
ua::StatusCode MotionSkill::onSuspend() {
    std::lock_guard l(mutex_);
    suspended_ = true;
    if (motion_) motion_->suspend();
    return {};
}

ua::StatusCode MotionSkill::onResume() {
    std::lock_guard l(mutex_);
    suspended_ = false;
    if (motion_) motion_->resume();
    return {};
}

void MotionSkill::onHalt() {
    std::lock_guard l(mutex_);
    if (motion_) motion_->halt();
}

void MotionSkill::beginRun() {
    std::lock_guard l(mutex_);
    // A Suspend before this run started is still seen: the runtime's checkpoint() waits for
    // the Resume before the motion is attached.
    suspended_ = false;
    motion_.reset();
}

void MotionSkill::endRun() {
    std::lock_guard l(mutex_);
    motion_.reset();
    suspended_ = false;
}

void MotionSkill::attach(const std::shared_ptr<rb::Motion>& motion) {
    std::lock_guard l(mutex_);
    motion_ = motion;
    if (suspended_) motion->suspend();
}

namespace {

// How a followed motion ended.
struct Followed {
    rb::MotionResult result;
    bool halted = false;  // Halt of the skill (or shutdown): the run is aborted
    std::string problem;  // not empty: the run fails with this (budget, no rest)
};

std::string seconds(std::chrono::nanoseconds d) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.1f s", std::chrono::duration<double>(d).count());
    return buf;
}

// Brakes and waits until the arm is at rest (bounded).
std::optional<rb::MotionResult> haltAndWait(rb::Motion& motion, const Timing& timing) {
    motion.halt();
    return motion.wait(Clock::now() + timing.restTimeout);
}

// Waits for the motion in slices: reports progress, turns Halt into a braked stop and gives
// up (braking) when the motion runs longer than `budget` of Running time.
Followed follow(Execution& run, rb::Motion& motion, const Timing& timing,
                std::chrono::nanoseconds budget, bool reportProgress) {
    double reported = -1.0;
    auto last = Clock::now();
    for (;;) {
        if (auto r = motion.wait(Clock::now() + timing.waitSlice, run.stopToken()))
            return {*r, run.stopRequested(), {}};
        if (run.stopRequested()) {
            auto rest = haltAndWait(motion, timing);
            if (!rest)
                return {
                    {}, true, "the arm did not come to rest within " + seconds(timing.restTimeout)};
            return {*rest, true, {}};
        }
        const auto now = Clock::now();
        if (!motion.suspended()) budget -= now - last;  // suspended time does not count
        last = now;
        if (budget < std::chrono::nanoseconds::zero()) {
            auto rest = haltAndWait(motion, timing);
            return {rest.value_or(rb::MotionResult{}), false,
                    "the motion did not end in time (controller not following?)"};
        }
        if (reportProgress) {
            const double p = motion.progress();
            if (std::abs(p - reported) >= 0.005) {
                run.progress(ua::Variant(p));
                reported = p;
            }
        }
    }
}

// The running-time budget of a trajectory: its duration plus a generous margin.
std::chrono::nanoseconds budgetOf(double duration) {
    const double s = duration + std::max(5.0, 0.5 * duration);
    return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::duration<double>(s));
}

Outcome outcomeOf(const Followed& f) {
    if (f.halted) return Outcome::aborted("halted by a client");
    if (!f.problem.empty()) return Outcome::failed(f.problem);
    switch (f.result.end) {
        case rb::MotionEnd::kCompleted:
            return Outcome::completed();
        case rb::MotionEnd::kHalted:
            return Outcome::failed("the motion was halted" +
                                   (f.result.message.empty() ? "" : ": " + f.result.message));
        case rb::MotionEnd::kForceExceeded:
            return Outcome::failed("the force limit was exceeded" +
                                   (f.result.message.empty() ? "" : ": " + f.result.message));
        case rb::MotionEnd::kFailed:
            break;
    }
    return Outcome::failed(f.result.message.empty() ? "the motion failed" : f.result.message);
}

// The current joints, or why there are none.
std::optional<rb::Joints> currentJoints(const MotionContext& context, std::string& error) {
    if (!context.controller().connected()) {
        error = "the robot controller is not connected";
        return std::nullopt;
    }
    auto s = context.controller().state();
    if (!s) {
        error = "no state from the robot controller yet";
        return std::nullopt;
    }
    return s->q;
}

// AxisBounds: none, or one Range (low <= high, finite) per axis.
std::optional<kinematics::AxisBounds> boundsOf(const std::vector<ua::Range>& ranges,
                                               std::string& error) {
    if (ranges.empty()) return std::nullopt;
    if (ranges.size() != static_cast<std::size_t>(kinematics::kAxes)) {
        error =
            "AxisBounds needs 0 or 6 ranges (one per axis), got " + std::to_string(ranges.size());
        return std::nullopt;
    }
    kinematics::AxisBounds b{};
    for (int i = 0; i < kinematics::kAxes; ++i) {
        const auto& r = ranges[static_cast<std::size_t>(i)];
        if (!std::isfinite(r.low) || !std::isfinite(r.high) || r.low > r.high) {
            error = "AxisBounds[" + std::to_string(i) + "] must be finite with Low <= High";
            return std::nullopt;
        }
        b.min[static_cast<std::size_t>(i)] = r.low;
        b.max[static_cast<std::size_t>(i)] = r.high;
    }
    return b;
}

class MoveSkill : public MotionSkill {
  public:
    MoveSkill(MoveKind kind, MotionContext& context)
        : MotionSkill(typeOf(kind), context), kind_(kind) {}

    Outcome execute(Execution& run) override {
        beginRun();
        Outcome o = move(run);
        endRun();
        return o;
    }

  private:
    static skill::ModelNode typeOf(MoveKind kind) {
        namespace t = skill::types;
        switch (kind) {
            case MoveKind::CartesianPtp:
                return t::CartesianPtpMoveSkillType;
            case MoveKind::CartesianLinear:
                return t::CartesianLinearMoveSkillType;
            case MoveKind::CartesianLinearForce:
                return t::CartesianLinearForceMoveSkillType;
            case MoveKind::JointPtp:
                return t::JointPtpMoveSkillType;
            case MoveKind::JointLinear:
                break;
        }
        return t::JointLinearMoveSkillType;
    }
    bool cartesian() const {
        return kind_ == MoveKind::CartesianPtp || kind_ == MoveKind::CartesianLinear ||
               kind_ == MoveKind::CartesianLinearForce;
    }
    bool ptp() const { return kind_ == MoveKind::CartesianPtp || kind_ == MoveKind::JointPtp; }

    // FinalResultData of the Cartesian types: ForcesExceeded and ForcesMax (world frame,
    // magnitudes per axis), on every outcome.
    Outcome report(Outcome o, bool exceeded, const Eigen::Vector3d& maxBase,
                   const Eigen::Matrix3d& baseToWorld) const {
        if (!cartesian()) return o;
        const Eigen::Vector3d world = (baseToWorld * maxBase).cwiseAbs();
        o.with("ForcesExceeded", ua::Variant(exceeded));
        o.with("ForcesMax", ua::Variant(ua::toExtensionObject(ua::spatial::toThreeDVector(world))));
        return o;
    }

    Outcome move(Execution& run) {
        const Eigen::Matrix3d identity = Eigen::Matrix3d::Identity();
        auto fail = [&](const std::string& why) {
            return report(Outcome::failed(why), false, Eigen::Vector3d::Zero(), identity);
        };
        std::string error;
        auto tool = context_.toolFrame(run.get(toolFrame_), error);
        if (!tool) return fail(error);
        const std::vector<double> vmax = run.get(maxVelocity_);
        const std::vector<double> amax = run.get(maxAcceleration_);

        std::optional<rb::CartesianTarget> target;
        std::vector<double> joints;
        std::optional<Eigen::Vector3d> forceLimitWorld;
        if (cartesian()) {
            const ua::ThreeDFrame frame = run.get(targetPosition_);
            if (!ua::spatial::finite(frame)) return fail("TargetPosition must be finite");
            auto bounds = boundsOf(run.get(axisBounds_), error);
            if (!error.empty()) return fail(error);
            target = rb::CartesianTarget{ua::spatial::toIsometry(frame), *tool, bounds};
            if (kind_ == MoveKind::CartesianLinearForce) {
                const Eigen::Vector3d f = ua::spatial::toVector(run.get(maxForce_));
                if (!f.allFinite() || (f.array() <= 0.0).any())
                    return fail("MaxForce must be finite and > 0 on every axis (N)");
                forceLimitWorld = f;
            }
        } else {
            joints = run.get(targetJointPosition_);
        }

        auto q = currentJoints(context_, error);
        if (!q) return fail(error);
        Eigen::Matrix3d baseToWorld = identity;
        rb::Result<motion::Trajectory> plan = context_.plan([&](const rb::Planner& p) {
            baseToWorld = p.worldToBase().linear();
            switch (kind_) {
                case MoveKind::CartesianPtp:
                    return p.cartesianPtp(*q, *target, rb::PtpLimits{vmax, amax});
                case MoveKind::CartesianLinear:
                case MoveKind::CartesianLinearForce:
                    return p.cartesianLinear(*q, *target, rb::LinLimits{vmax, amax});
                case MoveKind::JointPtp:
                    return p.jointPtp(*q, joints, rb::PtpLimits{vmax, amax});
                case MoveKind::JointLinear:
                    break;
            }
            return p.jointLinear(*q, joints, *tool, rb::LinLimits{vmax, amax});
        });
        if (!plan) return fail(plan.error().message);
        const double duration = plan->duration();

        rb::MotionOptions options;
        if (forceLimitWorld)  // the controller monitors base-frame components
            options.maxForce = (baseToWorld.transpose() * *forceLimitWorld).cwiseAbs();
        if (!run.checkpoint()) return fail("halted before the motion started");
        auto motion = context_.controller().execute(std::move(plan).value(), options);
        if (!motion) return fail(motion.error().message);
        attach(*motion);
        const Followed f = follow(run, **motion, context_.timing(), budgetOf(duration), true);
        if (f.result.end == rb::MotionEnd::kCompleted && !f.halted && f.problem.empty())
            run.progress(ua::Variant(1.0));
        return report(outcomeOf(f), f.result.end == rb::MotionEnd::kForceExceeded,
                      f.result.maxForce, baseToWorld);
    }

    MoveKind kind_;
    Param<ua::String> toolFrame_ = parameter<ua::String>("ToolFrame", "");
    Param<std::vector<double>> maxVelocity_ = parameter<std::vector<double>>("MaxVelocity");
    Param<std::vector<double>> maxAcceleration_ = parameter<std::vector<double>>("MaxAcceleration");
    // Declared by the Cartesian types only.
    Param<ua::ThreeDFrame> targetPosition_ =
        cartesian() ? parameter<ua::ThreeDFrame>("TargetPosition") : Param<ua::ThreeDFrame>{};
    Param<std::vector<ua::Range>> axisBounds_ =
        cartesian() ? parameter<std::vector<ua::Range>>("AxisBounds")
                    : Param<std::vector<ua::Range>>{};
    Param<ua::ThreeDVector> maxForce_ = kind_ == MoveKind::CartesianLinearForce
                                            ? parameter<ua::ThreeDVector>("MaxForce")
                                            : Param<ua::ThreeDVector>{};
    // Declared by the joint types only.
    Param<std::vector<double>> targetJointPosition_ =
        !cartesian() ? parameter<std::vector<double>>("TargetJointPosition")
                     : Param<std::vector<double>>{};
};

}  // namespace

std::shared_ptr<skill::server::Skill> makeMoveSkill(MoveKind kind, MotionContext& context) {
    return std::make_shared<MoveSkill>(kind, context);
}

// ---- PositionStreamSkill ---------------------------------------------------------------------
PositionStreamSkill::PositionStreamSkill(MotionContext& context)
    : MotionSkill(skill::types::PositionStreamSkillType, context),
      target_(parameter<std::vector<double>>("TargetJointPosition")) {}

ua::StatusCode PositionStreamSkill::offer(const ua::Variant& value) {
    std::vector<double> values;
    if (!skill::server::ParamTraits<std::vector<double>>::fromVariant(value, values))
        return ua::status::BadTypeMismatch;
    std::lock_guard l(mutex_);
    if (!stream_) {
        latest_ = std::move(values);  // the stream starts from the target written last
        return {};
    }
    auto q = context_.checkJoints(values);
    if (!q) return ua::status::BadOutOfRange;
    stream_->setTarget(*q);
    return {};
}

Outcome PositionStreamSkill::execute(Execution& run) {
    beginRun();
    auto done = [&](Outcome o) {
        {
            std::lock_guard l(mutex_);
            stream_.reset();
        }
        endRun();
        return o;
    };
    auto first = context_.checkJoints(run.get(target_));
    if (!first) return done(Outcome::failed("TargetJointPosition: " + first.error().message));
    std::string error;
    if (!currentJoints(context_, error)) return done(Outcome::failed(error));
    if (!run.checkpoint()) return done(Outcome::aborted("halted"));

    const auto& model = context_.model();
    motion::JointLimits limits{};
    for (int i = 0; i < kinematics::kAxes; ++i) {
        const auto k = static_cast<std::size_t>(i);
        limits.maxVelocity[k] = model.limits[k].maxVelocity;
        limits.maxAcceleration[k] = model.limits[k].maxAcceleration;
    }
    auto stream = context_.controller().stream(limits);
    if (!stream) return done(Outcome::failed(stream.error().message));
    std::shared_ptr<rb::Stream> s = *stream;
    {
        // The target written last wins: one written after Start (not in the run's
        // parameters) was kept by offer(); from here on offer() hands writes to the stream.
        std::lock_guard l(mutex_);
        auto latest = latest_ ? context_.checkJoints(*latest_) : first;
        s->setTarget(latest ? *latest : *first);
        stream_ = s;
    }
    attach(s);
    // Unbounded on purpose: a stream runs until Halt (or the controller ends it); each wait
    // is one slice.
    for (;;) {
        if (auto r = s->wait(Clock::now() + context_.timing().waitSlice, run.stopToken())) {
            if (run.stopRequested()) return done(Outcome::aborted("halted by a client"));
            return done(outcomeOf({*r, false, {}}));
        }
        if (run.stopRequested()) {
            auto rest = haltAndWait(*s, context_.timing());
            if (!rest)
                return done(Outcome::failed("the arm did not come to rest within " +
                                            seconds(context_.timing().restTimeout)));
            return done(Outcome::aborted("halted by a client"));
        }
    }
}

}  // namespace pnp::device::robot::detail
