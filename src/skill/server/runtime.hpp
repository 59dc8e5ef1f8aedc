// One skill instance in the address space: its program state machine, DI lock, parameter
// nodes and worker thread (private to pnp_skill_server; see skill.hpp for the semantics).
#pragma once

#include <atomic>
#include <condition_variable>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <thread>
#include <vector>

#include "skill/server/locking.hpp"
#include "skill/server/skill.hpp"
#include "ua/server/server.hpp"
#include "ua/server/state_machine.hpp"

namespace pnp::skill::server {

struct SkillNodes {
    ua::NodeId node;
    std::vector<ua::NodeId> parameters;  // by declaration index
    ua::NodeId lock;
    ua::NodeId result, message;                 // FinalResultData/Result, /Message
    std::map<std::string, ua::NodeId> results;  // other FinalResultData children by name
    ua::NodeId skillStep;                       // ParameterSet/SkillStep, if any
    ua::NodeId eventType;                       // SkillTransitionEventType
};

class SkillRuntime : public std::enable_shared_from_this<SkillRuntime> {
  public:
    SkillRuntime(ua::server::Server& server, std::shared_ptr<Skill> skill, SkillNodes nodes,
                 std::chrono::milliseconds maxInactiveLockTime);
    ~SkillRuntime();
    // Binds the method handlers and write guards and starts the worker (after construction:
    // the handlers hold weak references).
    void bind();
    // Halts a run, stops the worker, unbinds (the controller's destructor).
    void shutdown();

    const SkillNodes& nodes() const { return nodes_; }
    const Skill& skill() const { return *skill_; }
    ProgramState state() const;
    bool locked() const { return lock_->locked(); }
    std::uint64_t runs() const { return runs_.load(); }

    // For Execution (worker thread).
    bool waitWhileSuspended(std::stop_token stop);
    bool sleepRunning(std::chrono::nanoseconds d, std::stop_token stop);
    void progress(ua::Variant intermediateResult);

  private:
    using Fields = std::vector<std::pair<std::vector<ua::QualifiedName>, ua::Variant>>;
    struct Job {
        std::vector<ua::Variant> values;
        std::uint64_t generation = 0;
        std::stop_token stop;
    };
    void start(const ua::server::MethodCallContext& ctx, ua::server::MethodCompletion done);
    void halt(const ua::server::MethodCallContext& ctx, ua::server::MethodCompletion done);
    void suspend(const ua::server::MethodCallContext& ctx, ua::server::MethodCompletion done);
    void resume(const ua::server::MethodCallContext& ctx, ua::server::MethodCompletion done);
    void reset(const ua::server::MethodCallContext& ctx, ua::server::MethodCompletion done);
    void work(std::stop_token stop);
    void finish(const Job& job, Outcome outcome);
    // With mutex_ held.
    void setFinalResult(SkillResult result, const std::string& message);
    Fields eventFields(const std::string& message, ua::UInt16 severity) const;

    ua::server::Server& server_;
    std::shared_ptr<Skill> skill_;
    SkillNodes nodes_;
    std::unique_ptr<ua::server::FiniteStateMachine> fsm_;
    std::vector<ProgramState> stateOfIndex_;  // by index in fsm_->states()
    // nodes_.parameters and {nodes_.result, nodes_.message}: read / written under mutex_
    // without a lookup per node.
    ua::server::AddressSpace::VariableGroup parameterGroup_, resultGroup_;
    std::unique_ptr<LockingServices> lock_;

    mutable std::mutex mutex_;
    std::condition_variable_any wake_;
    std::optional<Job> job_;  // handed to the worker
    bool busy_ = false;       // execute() is running
    bool suspended_ = false;
    std::uint64_t generation_ = 0;   // of the current run
    std::stop_source stop_;          // of the current run
    ua::Variant intermediate_;       // IntermediateResult of the next events
    bool finalResultClear_ = false;  // FinalResultData is None / "" (as written last)
    std::vector<ua::server::MethodCompletion> pendingResets_;
    std::atomic<std::uint64_t> runs_{0};
    std::jthread worker_;  // last: joined first
};

}  // namespace pnp::skill::server
