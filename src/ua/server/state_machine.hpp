// Finite state machines (OPC 10000-16 §4.4, §5.2; Programs: OPC 10000-10 §5.2): a reusable
// server-side building block for instances of FiniteStateMachineType and its subtypes
// (e.g. ProgramStateMachineType).
//
// A FiniteStateMachine binds to an existing state machine Object in the address space and
// keeps its Variables in step with the current state:
//   CurrentState (LocalizedText: the state's DisplayName), CurrentState/Id (the state's
//   NodeId), CurrentState/Number (its StateNumber);
//   LastTransition (the transition's DisplayName), /Id, /Number, /TransitionTime,
//   /EffectiveTransitionTime;
//   AvailableStates / AvailableTransitions (NodeId[]: the states reachable and the
//   transitions possible from the current state).
// Children that the instance does not have (optional ones) are skipped. Every change goes
// through AddressSpace::setValue, so data-change subscriptions see it.
//
// The states and transitions come from either
//   * the type definition (the usual case): the StateType / TransitionType components of the
//     machine's type and its supertypes, their StateNumber / TransitionNumber, the
//     FromState / ToState / HasCause / HasEffect references (ProgramStateMachineType in
//     namespace 0 defines Ready/Running/Suspended/Halted and nine transitions caused by
//     Start/Suspend/Resume/Halt/Reset), or
//   * an explicit StateMachineDescription (custom machines): the state and transition
//     nodes are then created as components of the machine object.
//
// Each valid transition fires an event (TransitionEventType, or the subtype named by the
// transition's HasEffect reference, e.g. ProgramTransitionEventType, or Options::eventType)
// with SourceNode = the machine and the fields Transition, Transition/Id, Transition/Number,
// FromState, FromState/Id, FromState/Number, ToState, ToState/Id, ToState/Number.
//
// Methods: every method that causes a transition (HasCause) gets a handler on the machine
// instance (it is created there when the instance lacks it, e.g. the OptionalPlaceholder
// methods of ProgramStateMachineType). Its Executable / UserExecutable attributes are true
// exactly in the states where one of its transitions starts. The Call service refuses a
// non-executable method with Bad_NotExecutable (OPC 10000-4 §5.11.2); the handler checks the
// state again (a transition may happen between that check and the handler) and answers
// Bad_InvalidState. With Options::trackExecutable = false the methods stay executable and a
// call in a wrong state is answered with Bad_InvalidState by the handler.
// An application hook (onMethod) may run before the transition to accept or refuse it. The
// hook runs on the network thread: it must be quick (hand long-running work to a worker
// thread, which then calls transition() / fire() when it is done, e.g. Running -> Halted).
//
// Threads: every member function may be called from any thread (the network thread included,
// e.g. from a method handler). Transitions are serialised by the machine's own mutex; the
// address space and the subscription engine are called through their thread-safe entry
// points (setValue, writeAttribute, Server::fireEvent), never holding a lock they know of,
// so the lock order is always machine -> address space -> subscription engine. The several
// Variables of one transition are set one after the other (a concurrent Read may see the new
// CurrentState with the old LastTransition for a moment); the transition event is fired after
// all of them are set. Construction changes the address space structurally (method nodes,
// and the nodes of an explicit description): construct the machine before Server::start()
// or inside Server::post().
//
// Errors: setup problems (not a FiniteStateMachineType, no states, an unknown state name,
// CurrentState missing, ...) throw StateMachineError; run-time requests return StatusCodes
// (Bad_InvalidState for a transition not possible from the current state, Bad_NotFound for
// an unknown state / transition / method name).
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ua/server/address_space.hpp"
#include "ua/server/server.hpp"

namespace pnp::ua::server {

class StateMachineError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

// A custom machine, for FiniteStateMachine's second constructor. Names are BrowseNames in
// the namespace of the machine's NodeId; DisplayNames default to the names.
struct StateMachineDescription {
    struct State {
        std::string name = {};
        UInt32 number = 0;
        LocalizedText displayName = {};
        bool initial = false;  // InitialStateType (the state after construction)
    };
    struct Transition {
        std::string name = {};
        UInt32 number = 0;
        std::string from = {};
        std::string to = {};
        // Methods that cause the transition (HasCause), by BrowseName; created on the machine
        // when it has no component of that name.
        std::vector<std::string> causes = {};
        LocalizedText displayName = {};
        NodeId eventType = {};  // HasEffect; null: TransitionEventType
    };
    std::vector<State> states;
    std::vector<Transition> transitions;
};

// Options of FiniteStateMachine (FiniteStateMachine::Options).
struct StateMachineOptions {
    // The state after construction, by BrowseName name. Empty: the state of type
    // InitialStateType; for ProgramStateMachineType (and subtypes) without one, Ready.
    std::string initialState = {};
    // Event type of every transition event; null: the transition's HasEffect event type
    // (a subtype of TransitionEventType) or TransitionEventType.
    NodeId eventType = {};
    UInt16 eventSeverity = 100;
    // Keep each cause method's Executable / UserExecutable in step with the state.
    bool trackExecutable = true;
    // Create cause methods the instance does not have.
    bool createMethods = true;
};

class FiniteStateMachine {
  public:
    using Options = StateMachineOptions;

    struct State {
        NodeId node;
        QualifiedName browseName;
        LocalizedText displayName;
        UInt32 number = 0;
    };
    struct Transition {
        NodeId node;
        QualifiedName browseName;
        LocalizedText displayName;
        UInt32 number = 0;
        std::size_t from = 0;  // index into states()
        std::size_t to = 0;
        std::vector<QualifiedName> causes;  // method BrowseNames
        NodeId eventType;
    };
    // Called after each transition (any thread, the machine's lock NOT held).
    using TransitionObserver =
        std::function<void(const State& from, const Transition& via, const State& to)>;
    // Runs before a method's transition; Good lets the transition happen, anything else is
    // returned to the caller and nothing changes. Must be quick (network thread).
    using MethodHook =
        std::function<StatusCode(const MethodCallContext& context, const Transition& transition,
                                 const std::vector<Variant>& inputs)>;

    // States and transitions from the type definition of `machine`.
    FiniteStateMachine(Server& server, const NodeId& machine, Options options);
    FiniteStateMachine(Server& server, const NodeId& machine)
        : FiniteStateMachine(server, machine, Options{}) {}
    // States and transitions from an explicit description.
    FiniteStateMachine(Server& server, const NodeId& machine,
                       const StateMachineDescription& description, Options options = {});
    // The machine's method handlers answer Bad_InvalidState from now on.
    ~FiniteStateMachine();
    FiniteStateMachine(const FiniteStateMachine&) = delete;
    FiniteStateMachine& operator=(const FiniteStateMachine&) = delete;

    const NodeId& node() const;
    const std::vector<State>& states() const;
    const std::vector<Transition>& transitions() const;
    State currentState() const;
    // The index of the current state in states() (no copy).
    std::size_t currentStateIndex() const;
    std::optional<Transition> lastTransition() const;
    // The method node on the machine instance that has BrowseName `name` (name only), or null.
    NodeId method(std::string_view name) const;

    // Goes to state `to` (by BrowseName name) along the transition from the current state
    // to it. Bad_InvalidState when there is none (nothing changes), Bad_NotFound for an
    // unknown state. `extraFields` are added to the event (e.g. IntermediateResult); fields
    // "Message" (LocalizedText or String) and "Severity" (UInt16) replace the defaults.
    StatusCode transitionTo(
        std::string_view to,
        std::vector<std::pair<std::vector<QualifiedName>, Variant>> extraFields = {});
    // Takes the transition `name` (BrowseName name), or the one caused by method `name`,
    // from the current state. Bad_InvalidState / Bad_NotFound as above.
    StatusCode fire(std::string_view name,
                    std::vector<std::pair<std::vector<QualifiedName>, Variant>> extraFields = {});

    // Hook for method `name` (BrowseName name); empty: none. Bad_NotFound if no such cause.
    StatusCode onMethod(std::string_view name, MethodHook hook);
    void onTransition(TransitionObserver observer);

    struct Impl;

  private:
    std::shared_ptr<Impl> impl_;
};

}  // namespace pnp::ua::server
