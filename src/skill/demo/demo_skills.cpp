#include "skill/demo/demo_skills.hpp"

#include <atomic>
#include <chrono>
#include <cmath>

namespace pnp::skill::demo {

using namespace std::chrono_literals;
using server::Execution;
using server::Outcome;
using server::Param;

namespace {

class DelaySkill : public server::Skill {
  public:
    DelaySkill() : Skill(types::DelaySkillType) {}
    Param<double> duration = parameter<double>("DurationMs", 0.0);
    Param<ua::String> failWith = optionalParameter<ua::String>("FailWith");

    Outcome execute(Execution& run) override {
        const double ms = run.get(duration);
        if (!std::isfinite(ms) || ms < 0 || ms > 3.6e6)
            return Outcome::failed("DurationMs must be within 0 .. 3600000");
        if (ms > 0 && !run.sleepFor(std::chrono::nanoseconds(static_cast<std::int64_t>(ms * 1e6))))
            return Outcome::aborted("halted");
        if (std::string reason = run.get(failWith); !reason.empty()) return Outcome::failed(reason);
        return Outcome::completed();
    }
};

// The simulated gripper all gripper skills share: jaw width in m.
struct Gripper {
    std::atomic<double> width{0.1};
};

class GraspSkill : public server::Skill {
  public:
    explicit GraspSkill(std::shared_ptr<Gripper> g)
        : Skill(types::GraspGripperSkillType), gripper_(std::move(g)) {}
    Param<double> force = optionalParameter<double>("Force", 20.0);
    Outcome execute(Execution& run) override {
        if (run.get(force) < 0) return Outcome::failed("Force must not be negative");
        if (!run.sleepFor(40ms)) return Outcome::aborted("halted");
        gripper_->width = 0.0;
        return Outcome::completed();
    }

  private:
    std::shared_ptr<Gripper> gripper_;
};

class ReleaseSkill : public server::Skill {
  public:
    explicit ReleaseSkill(std::shared_ptr<Gripper> g)
        : Skill(types::ReleaseGripperSkillType), gripper_(std::move(g)) {}
    Param<double> force = optionalParameter<double>("Force", 20.0);
    Outcome execute(Execution& run) override {
        if (!run.sleepFor(40ms)) return Outcome::aborted("halted");
        gripper_->width = 0.1;
        return Outcome::completed();
    }

  private:
    std::shared_ptr<Gripper> gripper_;
};

class MoveGripperSkill : public server::Skill {
  public:
    explicit MoveGripperSkill(std::shared_ptr<Gripper> g)
        : Skill(types::MoveGripperSkillType), gripper_(std::move(g)) {}
    Param<double> width = parameter<double>("Width", 0.05);
    Param<double> force = parameter<double>("Force", 20.0);
    Outcome execute(Execution& run) override {
        const double target = run.get(width);
        if (!(target >= 0 && target <= 0.1))
            return Outcome::failed("Width must be within 0 .. 0.1 m");
        constexpr double speed = 0.5;  // m/s
        constexpr auto step = 5ms;
        for (int i = 0; i < 1000; ++i) {
            double w = gripper_->width;
            if (std::abs(w - target) < 1e-9) break;
            const double delta = speed * std::chrono::duration<double>(step).count();
            w = w < target ? std::min(target, w + delta) : std::max(target, w - delta);
            if (!run.sleepFor(step)) return Outcome::aborted("halted");
            gripper_->width = w;
            run.progress(ua::Variant(w));
        }
        return Outcome::completed();
    }

  private:
    std::shared_ptr<Gripper> gripper_;
};

}  // namespace

void loadDemoModels(ua::server::Server& server) {
    server::loadSkillModels(server.addressSpace(), {kBaseUri, kDemoUri});
}

std::unique_ptr<server::SkillController> addDemoSkills(ua::server::Server& server,
                                                       const std::string& name) {
    loadDemoModels(server);
    auto controller = std::make_unique<server::SkillController>(
        server, server::SkillControllerOptions{.name = name});
    auto gripper = std::make_shared<Gripper>();
    controller->add("Delay", std::make_shared<DelaySkill>());
    controller->add("Grasp", std::make_shared<GraspSkill>(gripper));
    controller->add("Release", std::make_shared<ReleaseSkill>(gripper));
    controller->add("MoveGripper", std::make_shared<MoveGripperSkill>(gripper));
    return controller;
}

}  // namespace pnp::skill::demo
