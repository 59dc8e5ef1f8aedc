#include "skill/server/skill.hpp"

#include "skill/server/runtime.hpp"

namespace pnp::skill::server {

const ua::Variant& Execution::value(std::size_t index) const {
    static const ua::Variant empty;
    return index < values_.size() ? values_[index] : empty;
}

const ua::Variant* Execution::value(std::string_view name) const {
    const auto& decls = runtime_.skill().parameters();
    for (std::size_t i = 0; i < decls.size() && i < values_.size(); ++i)
        if (decls[i].name == name) return &values_[i];
    return nullptr;
}

std::string Execution::declarationName(std::size_t index) const {
    const auto& decls = runtime_.skill().parameters();
    return index < decls.size() ? decls[index].name : "#" + std::to_string(index);
}

bool Execution::checkpoint() { return runtime_.waitWhileSuspended(stop_); }

bool Execution::sleepFor(std::chrono::nanoseconds d) { return runtime_.sleepRunning(d, stop_); }

void Execution::progress(ua::Variant intermediateResult) {
    runtime_.progress(std::move(intermediateResult));
}

namespace {
class CallbackSkill : public Skill {
  public:
    CallbackSkill(ModelNode type, std::vector<ParameterDeclaration> parameters, SkillCallbacks cb)
        : Skill(type), callbacks_(std::move(cb)) {
        for (auto& p : parameters) declareRaw(std::move(p));
    }
    Outcome execute(Execution& run) override {
        return callbacks_.execute ? callbacks_.execute(run) : Outcome::completed();
    }
    ua::StatusCode onSuspend() override {
        return callbacks_.suspend ? callbacks_.suspend() : ua::StatusCode{};
    }
    ua::StatusCode onResume() override {
        return callbacks_.resume ? callbacks_.resume() : ua::StatusCode{};
    }
    ua::StatusCode onReset() override {
        return callbacks_.reset ? callbacks_.reset() : ua::StatusCode{};
    }
    void onHalt() override {
        if (callbacks_.halt) callbacks_.halt();
    }

  private:
    SkillCallbacks callbacks_;
};
}  // namespace

std::shared_ptr<Skill> makeSkill(ModelNode type, std::vector<ParameterDeclaration> parameters,
                                 SkillCallbacks callbacks) {
    return std::make_shared<CallbackSkill>(type, std::move(parameters), std::move(callbacks));
}

}  // namespace pnp::skill::server
