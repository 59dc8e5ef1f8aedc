// The run-time of one skill instance: method handlers (network thread), the worker thread
// and the only path to transitions, the program state machine.
#include "skill/server/runtime.hpp"

#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::skill::server {

using ua::NodeId;
using ua::StatusCode;
using ua::Variant;
using ua::server::MethodCallContext;
using ua::server::MethodCompletion;
namespace status = ua::status;

namespace {
constexpr ua::UInt16 kSeverityNormal = 100;
constexpr ua::UInt16 kSeverityFailure = 700;
}  // namespace

SkillRuntime::SkillRuntime(ua::server::Server& server, std::shared_ptr<Skill> skill,
                           SkillNodes nodes, std::chrono::milliseconds maxInactiveLockTime)
    : server_(server),
      skill_(std::move(skill)),
      nodes_(std::move(nodes)),
      parameterGroup_(nodes_.parameters),
      resultGroup_({nodes_.result, nodes_.message}) {
    ua::server::FiniteStateMachine::Options options;
    options.eventType = nodes_.eventType;
    options.eventSeverity = kSeverityNormal;
    fsm_ = std::make_unique<ua::server::FiniteStateMachine>(server_, nodes_.node, options);
    for (const auto& s : fsm_->states())
        stateOfIndex_.push_back(programStateFromName(s.browseName.name));
    lock_ = std::make_unique<LockingServices>(server_, nodes_.lock, maxInactiveLockTime);
    std::lock_guard l(mutex_);
    setFinalResult(SkillResult::None, "");
}

SkillRuntime::~SkillRuntime() { shutdown(); }

void SkillRuntime::bind() {
    auto& space = server_.addressSpace();
    std::weak_ptr<SkillRuntime> weak = weak_from_this();
    using Handler = void (SkillRuntime::*)(const MethodCallContext&, MethodCompletion);
    auto on = [&](std::string_view name, Handler h) {
        NodeId m = fsm_->method(name);
        if (m.isNull())
            throw SkillError("skill " + nodes_.node.toString() + " has no " + std::string(name) +
                             " method");
        space.setMethodHandler(m, [weak, h](const MethodCallContext& ctx, std::vector<Variant>,
                                            MethodCompletion done) {
            auto self = weak.lock();
            if (!self) return done.fail(status::BadInvalidState);
            ((*self).*h)(ctx, std::move(done));
        });
    };
    on("Start", &SkillRuntime::start);
    on("Halt", &SkillRuntime::halt);
    on("Suspend", &SkillRuntime::suspend);
    on("Resume", &SkillRuntime::resume);
    on("Reset", &SkillRuntime::reset);
    // Only the lock holder writes the parameters while the skill is locked.
    LockingServices* lock = lock_.get();
    for (const NodeId& p : nodes_.parameters)
        server_.setWriteGuard(p, [weak, lock](const NodeId& session, const ua::WriteValue&) {
            auto self = weak.lock();
            if (!self) return StatusCode(status::BadInvalidState);
            return lock->allows(session) ? StatusCode{} : StatusCode(status::BadLocked);
        });
    worker_ = std::jthread([this](std::stop_token stop) { work(stop); });
}

void SkillRuntime::shutdown() {
    for (const NodeId& p : nodes_.parameters) server_.setWriteGuard(p, {});
    {
        std::lock_guard l(mutex_);
        stop_.request_stop();
    }
    if (worker_.joinable()) {
        worker_.request_stop();
        wake_.notify_all();
        worker_.join();
    }
    std::lock_guard l(mutex_);
    for (auto& done : pendingResets_) done.fail(status::BadShutdown);
    pendingResets_.clear();
}

ProgramState SkillRuntime::state() const {
    const std::size_t i = fsm_->currentStateIndex();
    return i < stateOfIndex_.size() ? stateOfIndex_[i] : ProgramState::Unknown;
}

void SkillRuntime::setFinalResult(SkillResult result, const std::string& message) {
    // Start clears it: skipped when it is clear already (two variable writes less per run).
    const bool clear = result == SkillResult::None && message.empty();
    if (clear && finalResultClear_) return;
    finalResultClear_ = clear;
    std::vector<std::pair<std::size_t, ua::DataValue>> values;
    if (!nodes_.result.isNull())
        values.emplace_back(0, ua::DataValue(Variant(static_cast<ua::Int32>(result))));
    if (!nodes_.message.isNull())
        values.emplace_back(1, ua::DataValue(Variant(ua::String(message))));
    server_.addressSpace().setValues(resultGroup_, std::move(values));
}

SkillRuntime::Fields SkillRuntime::eventFields(const std::string& message,
                                               ua::UInt16 severity) const {
    Fields f;
    f.push_back({{ua::QualifiedName(0, "IntermediateResult")}, intermediate_});
    if (!message.empty()) f.push_back({{ua::QualifiedName(0, "Message")}, Variant(message)});
    f.push_back({{ua::QualifiedName(0, "Severity")}, Variant(severity)});
    return f;
}

void SkillRuntime::start(const MethodCallContext& ctx, MethodCompletion done) {
    if (!lock_->allows(ctx.sessionId)) return done.fail(status::BadLocked);
    std::unique_lock l(mutex_);
    if (busy_ || state() != ProgramState::Ready) return done.fail(status::BadInvalidState);
    // The parameters as they are now: the run never sees a later Write.
    std::vector<Variant> values;
    values.reserve(nodes_.parameters.size());
    for (ua::DataValue& dv : server_.addressSpace().readValues(parameterGroup_))
        values.push_back(dv.value ? std::move(*dv.value) : Variant());
    intermediate_ = Variant();
    setFinalResult(SkillResult::None, "");
    StatusCode st = fsm_->fire("Start", eventFields("", kSeverityNormal));
    if (st.isBad()) return done.fail(st);
    ++generation_;
    busy_ = true;
    suspended_ = false;
    stop_ = std::stop_source();
    job_ = Job{std::move(values), generation_, stop_.get_token()};
    l.unlock();
    done(StatusCode{});
    // The worker starts once the reply and the Running event are written: waking it first
    // puts a system call and a thread that competes for the CPU before them.
    server_.afterResponsesWritten([w = weak_from_this()] {
        if (auto self = w.lock()) self->wake_.notify_all();
    });
}

void SkillRuntime::halt(const MethodCallContext& ctx, MethodCompletion done) {
    if (!lock_->allows(ctx.sessionId)) return done.fail(status::BadLocked);
    std::unique_lock l(mutex_);
    const ProgramState s = state();
    if (s == ProgramState::Halted) return done.fail(status::BadInvalidState);
    const bool running = s == ProgramState::Running || s == ProgramState::Suspended;
    if (running) {
        stop_.request_stop();
        suspended_ = false;
        setFinalResult(SkillResult::Aborted, "halted by a client");
    }
    StatusCode st =
        fsm_->fire("Halt", eventFields(running ? "halted by a client" : "", kSeverityNormal));
    l.unlock();
    wake_.notify_all();
    if (st.isGood() && running) skill_->onHalt();
    done(st);
}

void SkillRuntime::suspend(const MethodCallContext& ctx, MethodCompletion done) {
    if (!lock_->allows(ctx.sessionId)) return done.fail(status::BadLocked);
    std::unique_lock l(mutex_);
    if (state() != ProgramState::Running) return done.fail(status::BadInvalidState);
    if (StatusCode st = skill_->onSuspend(); st.isBad()) return done.fail(st);
    suspended_ = true;
    done(fsm_->fire("Suspend", eventFields("", kSeverityNormal)));
}

void SkillRuntime::resume(const MethodCallContext& ctx, MethodCompletion done) {
    if (!lock_->allows(ctx.sessionId)) return done.fail(status::BadLocked);
    std::unique_lock l(mutex_);
    if (state() != ProgramState::Suspended) return done.fail(status::BadInvalidState);
    if (StatusCode st = skill_->onResume(); st.isBad()) return done.fail(st);
    suspended_ = false;
    StatusCode st = fsm_->fire("Resume", eventFields("", kSeverityNormal));
    l.unlock();
    wake_.notify_all();
    done(st);
}

void SkillRuntime::reset(const MethodCallContext& ctx, MethodCompletion done) {
    if (!lock_->allows(ctx.sessionId)) return done.fail(status::BadLocked);
    std::unique_lock l(mutex_);
    if (state() != ProgramState::Halted) return done.fail(status::BadInvalidState);
    if (StatusCode st = skill_->onReset(); st.isBad()) return done.fail(st);
    if (busy_) {
        // The halted run has not returned yet: Ready once it has (worker thread).
        pendingResets_.push_back(std::move(done));
        return;
    }
    intermediate_ = Variant();
    done(fsm_->fire("Reset", eventFields("", kSeverityNormal)));
}

void SkillRuntime::work(std::stop_token stop) {
    while (!stop.stop_requested()) {
        Job job;
        {
            std::unique_lock l(mutex_);
            if (!wake_.wait(l, stop, [&] { return job_.has_value(); })) return;
            job = std::move(*job_);
            job_.reset();
        }
        Execution run(*this, std::move(job.values), job.stop);
        Outcome outcome;
        try {
            outcome = skill_->execute(run);
        } catch (const std::exception& e) {
            outcome = Outcome::failed(e.what());
        } catch (...) {
            outcome = Outcome::failed("unknown exception");
        }
        finish(job, std::move(outcome));
    }
}

void SkillRuntime::finish(const Job& job, Outcome outcome) {
    {
        std::unique_lock l(mutex_);
        busy_ = false;
        suspended_ = false;
        runs_.fetch_add(1);
        const ProgramState s = state();
        const bool current = job.generation == generation_ && !job.stop.stop_requested() &&
                             (s == ProgramState::Running || s == ProgramState::Suspended);
        // A run halted by a client (Halt set Result and Message already) still leaves what it
        // reports, e.g. how far a composite got — unless a new run has started since.
        const bool halted = job.generation == generation_ && job.stop.stop_requested() &&
                            s == ProgramState::Halted;
        if (current || halted) {
            auto& space = server_.addressSpace();
            for (auto& [name, value] : outcome.results) {
                auto it = nodes_.results.find(name);
                if (it != nodes_.results.end()) space.setValue(it->second, ua::DataValue(value));
            }
        }
        if (current) {
            const bool ok = outcome.result == SkillResult::Completed;
            if (!ok && outcome.message.empty())
                outcome.message = std::string(toString(outcome.result));
            setFinalResult(outcome.result, outcome.message);
            fsm_->transitionTo(
                ok ? "Ready" : "Halted",
                eventFields(outcome.message, ok ? kSeverityNormal : kSeverityFailure));
        }
        if (!pendingResets_.empty() && state() == ProgramState::Halted) {
            intermediate_ = Variant();
            StatusCode st = fsm_->fire("Reset", eventFields("", kSeverityNormal));
            for (auto& done : pendingResets_) done(st);
        }
        pendingResets_.clear();
    }
    wake_.notify_all();
}

bool SkillRuntime::waitWhileSuspended(std::stop_token stop) {
    std::unique_lock l(mutex_);
    wake_.wait(l, stop, [&] { return !suspended_; });
    return !stop.stop_requested();
}

bool SkillRuntime::sleepRunning(std::chrono::nanoseconds d, std::stop_token stop) {
    using Clock = std::chrono::steady_clock;
    std::unique_lock l(mutex_);
    auto left = d;
    while (left > std::chrono::nanoseconds::zero()) {
        if (!wake_.wait(l, stop, [&] { return !suspended_; })) return false;
        const auto from = Clock::now();
        // Returns early when suspended or stopped.
        wake_.wait_for(l, stop, left, [&] { return suspended_; });
        if (stop.stop_requested()) return false;
        left -= Clock::now() - from;
    }
    return !stop.stop_requested();
}

void SkillRuntime::progress(Variant intermediateResult) {
    std::lock_guard l(mutex_);
    if (!nodes_.skillStep.isNull())
        if (const auto* text = intermediateResult.scalar<ua::String>())
            server_.addressSpace().setValue(nodes_.skillStep, ua::DataValue(Variant(*text)));
    intermediate_ = std::move(intermediateResult);
}

}  // namespace pnp::skill::server
