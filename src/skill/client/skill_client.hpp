// The client side of one skill (docs/skill_client.md; contract: the skill model, model.hpp).
//
//   auto ua = std::make_shared<ua::client::Client>();
//   ua->connect("opc.tcp://robot:4840");
//   SkillClient delay(ua, skillNode);                  // discovers the skill (few round trips)
//   RunResult r = delay.run({{"DurationMs", 50.0}}, 5s);
//   if (r.result != SkillResult::Completed) std::cerr << r.message;
//
// A SkillClient is a handle on ONE skill node: it learns the skill's type (and supertypes up
// to SkillType, for isA()), its method nodes, ParameterSet, FinalResultData and CurrentState
// in batched Browse / Read requests when constructed, then each operation is one request.
// Transition events come from one event monitored item on the skill node, created at the
// first use and kept; they are queued and handed to onTransition() callbacks.
//
// Errors: a Bad status of a Write or Call throws ua::client::Error with that status and a
// message naming the operation (parameter or method). Every blocking call takes a Deadline.
// All members may be called from any thread; run() is meant for one caller at a time.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "skill/model/model.hpp"
#include "ua/client/client.hpp"
#include "ua/client/subscription.hpp"

namespace pnp::skill::client {

using ua::client::Deadline;
using ua::client::Error;
using NamedValues = std::vector<std::pair<std::string, ua::Variant>>;

// A type of the skill's type hierarchy, as the server names it.
struct TypeInfo {
    std::string uri;    // namespace URI of the type node
    ua::UInt32 id = 0;  // numeric id in that namespace (0 for non-numeric ids)
    std::string name;   // BrowseName's name
    ua::NodeId node;
    bool is(const ModelNode& m) const { return uri == m.uri && id == m.id; }
};

struct ParameterInfo {
    std::string name;
    ua::NodeId node;
    ua::NodeId dataType;
    ua::Int32 valueRank = -1;
    bool writable = false;  // AccessLevel has CurrentWrite
};

struct FinalResult {
    SkillResult result = SkillResult::None;
    std::string message;
    NamedValues values;  // the type-specific children of FinalResultData
};

// One SkillTransitionEvent of this skill.
struct Transition {
    ua::UInt32 number = 0;  // ProgramStateMachineType: 1 Halted->Ready, 2 Ready->Running, ...
    std::string name;       // "ReadyToRunning"
    ProgramState from = ProgramState::Unknown;
    ProgramState to = ProgramState::Unknown;
    ua::Variant intermediateResult;
    ua::DateTime time;
    std::string message;
    ua::UInt16 severity = 0;
    ua::NodeId source;
    // Not from an event: run() saw the run end by a Read (CurrentState, LastTransition)
    // before this transition's event arrived; the event still goes to onTransition().
    bool polled = false;
};

// The transition of ProgramStateMachineType with this number (1 HaltedToReady ... 9
// ReadyToHalted): states and name; number 0 / unknown: states Unknown.
Transition transitionFromNumber(ua::UInt32 number);

struct RunResult {
    SkillResult result = SkillResult::None;
    std::string message;
    FinalResult finalResult;
    // Those of this run, in order. A run that ends within the subscription's publishing
    // interval is seen ended by a Read before its last event arrives: that transition is
    // then built from LastTransition (Transition::polled; onTransition() still gets the event).
    std::vector<Transition> transitions;
    bool timedOut = false;  // the deadline passed: the run was halted
};

struct SkillClientOptions {
    // Used when the Lock has no MaxInactiveLockTime property; run() renews every third.
    std::chrono::milliseconds lockTime{10000};
    // Context passed to InitLock by run().
    std::string lockContext = "pnp skill client";
    // Publishing interval of the transition subscription (the server's minimum is 10 ms; a
    // waiting Publish is answered as soon as the interval allows).
    double publishingInterval = 10;
    // The time given to Halt / ExitLock after run()'s deadline passed or it was cancelled.
    std::chrono::milliseconds cleanupTime{2000};
    // A subscription of the same session that the transition events' item is created on,
    // shared by many skills (a dashboard or an MES watching hundreds: one subscription and
    // one waiting Publish per session instead of one per skill; created by the caller); null:
    // the client's own.
    std::shared_ptr<ua::client::Subscription> subscription{};
};

class SkillClient {
  public:
    using Client = ua::client::Client;
    using TransitionCallback = std::function<void(const Transition&)>;

    // Discovers the skill below `skill` on a connected client (starts the client's
    // background thread if it is not running: the transition subscription needs it). Throws
    // Error (BadNodeIdUnknown, BadTypeMismatch: not a skill, BadTimeout, ...).
    SkillClient(std::shared_ptr<Client> client, ua::NodeId skill, Deadline deadline = {},
                SkillClientOptions options = {});
    virtual ~SkillClient();
    SkillClient(const SkillClient&) = delete;
    SkillClient& operator=(const SkillClient&) = delete;

    const std::shared_ptr<Client>& uaClient() const { return client_; }
    const ua::NodeId& node() const { return node_; }
    const std::string& browseName() const { return browseName_; }
    // The skill's type first, then its supertypes up to SkillType.
    const std::vector<TypeInfo>& typeChain() const { return types_; }
    const TypeInfo& type() const { return types_.front(); }
    // True when the skill's type is `type` or one of its subtypes.
    bool isA(const ModelNode& type) const;
    const SkillClientOptions& options() const { return options_; }

    // ---- state and parameters ---------------------------------------------------------
    ProgramState state(Deadline deadline = {});
    const std::vector<ParameterInfo>& parameters() const { return parameters_; }
    const ParameterInfo* findParameter(std::string_view name) const;
    // Throws Error(BadNotFound) for an unknown name, or the Read's Bad status.
    ua::Variant parameter(std::string_view name, Deadline deadline = {});
    NamedValues parameterValues(Deadline deadline = {});  // all, in one Read
    void setParameter(std::string_view name, ua::Variant value, Deadline deadline = {});
    // All in ONE Write; the first Bad status throws Error naming its parameter.
    void setParameters(const NamedValues& values, Deadline deadline = {});

    // ---- program methods (Bad status -> Error) ---------------------------------------
    void start(Deadline deadline = {});
    void suspend(Deadline deadline = {});
    void resume(Deadline deadline = {});
    void halt(Deadline deadline = {});
    void reset(Deadline deadline = {});

    // ---- DI lock ------------------------------------------------------------------------
    // true: locked by this session; false: already locked (InitLock returned -1).
    bool lock(std::string_view context = {}, Deadline deadline = {});
    bool renewLock(Deadline deadline = {});  // false: not locked by us
    bool unlock(Deadline deadline = {});     // ExitLock; false: was not locked
    bool breakLock(Deadline deadline = {});  // false: was not locked
    // The Lock's RemainingLockTime right after lock(): the server's lock time (else
    // options().lockTime); run() renews the lock every third of it.
    std::chrono::milliseconds lockTime() const { return lockTime_.load(); }

    // ---- results and transitions ------------------------------------------------------
    FinalResult finalResult(Deadline deadline = {});
    // Creates the event monitored item if needed (run() does this itself).
    void subscribeTransitions(Deadline deadline = {});
    // Called for every transition (on the client's dispatching thread; must not block).
    // Subscribes if needed. Returns an id for removeTransitionCallback().
    std::size_t onTransition(TransitionCallback callback, Deadline deadline = {});
    void removeTransitionCallback(std::size_t id);
    // The transitions received and not yet taken (the queue keeps the last 1000).
    std::vector<Transition> takeTransitions();
    // Waits for the next queued transition until the deadline; nullopt on timeout.
    std::optional<Transition> nextTransition(Deadline deadline, std::stop_token cancel = {});

    // ---- one complete run -------------------------------------------------------------
    // Lock (retrying while another session holds it, until the deadline), Reset when
    // Halted, write `params` in one Write, Start, wait for the end of this run, read
    // FinalResultData, ExitLock (always). When the deadline passes or `cancel` is requested:
    // Halt, ExitLock, and return timedOut (deadline) / Aborted. Throws Error for refused
    // calls (BadLocked at the deadline, BadInvalidState, a parameter's Write status, ...).
    RunResult run(const NamedValues& params, Deadline deadline, std::stop_token cancel = {});

  protected:
    // Throws Error(BadTypeMismatch) unless isA(type): the typed clients' check.
    void requireType(const ModelNode& type) const;

  private:
    struct Queue;
    void discover(Deadline deadline);
    // FinalResultData (and CurrentState, LastTransition/Number and /TransitionTime when
    // withState) in one Read.
    struct Polled {
        ProgramState state = ProgramState::Unknown;
        ua::UInt32 lastTransition = 0;
        ua::DateTime lastTransitionTime;
        FinalResult result;
    };
    Polled stateAndResult(bool withState, Deadline deadline);
    ua::client::CallResult callMethod(const ua::NodeId& object, const ua::NodeId& method,
                                      std::vector<ua::Variant> inputs, std::string_view what,
                                      Deadline deadline);
    void callProgram(const ua::NodeId& method, std::string_view what, Deadline deadline);
    ua::Int32 callLock(const ua::NodeId& method, std::vector<ua::Variant> inputs,
                       std::string_view what, Deadline deadline);

    std::shared_ptr<Client> client_;
    ua::NodeId node_;
    SkillClientOptions options_;
    std::string browseName_;
    std::vector<TypeInfo> types_;
    std::vector<ParameterInfo> parameters_;
    ua::NodeId start_, suspend_, resume_, halt_, reset_;
    ua::NodeId lockNode_, initLock_, renewLock_, exitLock_, breakLock_, remainingLockTime_;
    ua::NodeId stateNumber_, stateId_;  // CurrentState/Number (preferred) and /Id
    ua::NodeId lastTransitionNumber_, lastTransitionTime_;
    ua::NodeId resultNode_, messageNode_;
    std::vector<std::pair<std::string, ua::NodeId>> resultValues_;
    std::atomic<std::chrono::milliseconds> lockTime_;
    std::atomic<bool> lockTimeKnown_{false};

    std::mutex subscribeMutex_;  // creation of the subscription and its item
    ua::client::Subscription subscription_;
    ua::client::MonitoredItem events_;
    std::shared_ptr<Queue> queue_;  // shared with the event callback
};

}  // namespace pnp::skill::client
