// The demo namespace "urn:pnp:demo" (module pnp_ua_demo): one variable per built-in type
// (scalar and array) and three methods. It is what `pnp ua serve` exposes, what the CLI
// tests and the benchmark run against, and exactly what tests/interop/demo_types.js
// specifies for the node-opcua interop test:
//
//   ns=<demo>;s=Demo               Object, BrowseName "Demo", Organizes from ObjectsFolder
//     s=Scalar.<T>                 Variable, DataType T, ValueRank -1, AccessLevel read+write
//     s=Array.<T>                  Variable, DataType T, ValueRank 1, ArrayDimensions [0]
//                                  (T: the 25 built-in types Boolean ... DiagnosticInfo;
//                                  ExtensionObject -> DataType Structure (i=22), initial
//                                  value a Range; Variant -> BaseDataType (i=24))
//     s=Demo.Echo  Echo(Data: ByteString) -> (Data: ByteString)
//     s=Demo.Add   Add(a: Int32, b: Int32) -> (sum: Int32)      (wraps around on overflow)
//     s=Demo.Sleep Sleep(milliseconds: UInt32) -> ()
//   With a Server (events and live values need one):
//     Demo is an event notifier (EventNotifier SubscribeToEvents, HasNotifier from Server)
//     s=Demo.Counter  UInt32, read-only, +1 every 100 ms (DemoNamespace only: its ticker)
//     s=Demo.FireEvent FireEvent(message: String, severity: UInt16) -> () fires a
//                  DemoEventType event at Demo; the ticker fires one every second too
//     s=DemoEventType ObjectType, subtype of BaseEventType, Property Sequence (UInt32): a
//                  custom field, counting the demo's events
//     s=Demo.Program  ProgramStateMachineType instance (OPC 10000-10; a
//                  server::FiniteStateMachine): methods Start/Suspend/Resume/Halt/Reset move
//                  it between Ready/Running/Suspended/Halted; CurrentState, LastTransition,
//                  AvailableStates/Transitions follow; each transition fires a
//                  ProgramTransitionEventType event (source Demo.Program, notifier Demo)
//
// Demo.Sleep completes ASYNCHRONOUSLY: the handler returns at once and a worker thread
// completes the call when the time is up, so a long method never blocks the server's network
// thread. One worker serves every pending Sleep (a timer queue, started on the first call);
// at most DemoOptions::maxPendingSleeps calls wait at once (more: BadTooManyOperations) and
// none longer than DemoOptions::maxSleep (BadOutOfRange).
//
// Lifetime of the worker. With DemoNamespace (preferred) the worker belongs to that object:
// its destructor completes the pending Sleep calls with BadShutdown and joins the thread, so
// declare it after the Server (destroyed first). With the free addDemoNamespace() the worker
// belongs to the Sleep method handler and is joined when the address space is destroyed.
#pragma once

#include <chrono>
#include <cstddef>
#include <memory>
#include <span>
#include <string_view>

#include "ua/server/address_space.hpp"
#include "ua/server/server.hpp"

namespace pnp::ua::demo {

inline constexpr std::string_view kNamespaceUri = "urn:pnp:demo";

struct DemoOptions {
    // Demo.Sleep calls waiting at the same time; more fail with BadTooManyOperations.
    std::size_t maxPendingSleeps = 64;
    // Longest accepted Demo.Sleep; longer requests fail with BadOutOfRange.
    std::chrono::milliseconds maxSleep{60'000};
};

// The built-in types of the Scalar.<T> / Array.<T> variables, in the order of
// tests/interop/demo_types.js (Boolean ... DiagnosticInfo).
std::span<const BuiltinType> demoTypes();
// The DataType node of the variables of built-in type t (Structure for ExtensionObject,
// BaseDataType for Variant, the built-in DataType otherwise).
NodeId demoDataType(BuiltinType t);
// The initial values (the scalarDefault / empty arrays of demo_types.js).
Variant demoInitialScalar(BuiltinType t);
Variant demoInitialArray(BuiltinType t);

class SleepWorker;
class DemoTicker;

// Builds the demo namespace in a server's address space and owns the Sleep worker.
// Throws server::AddressSpaceError when the demo nodes exist already.
class DemoNamespace {
  public:
    explicit DemoNamespace(server::Server& server, DemoOptions options = {});
    explicit DemoNamespace(server::AddressSpace& addressSpace, DemoOptions options = {});
    // Completes pending Sleep calls with BadShutdown and joins the worker. Later Sleep calls
    // fail at once with BadShutdown.
    ~DemoNamespace();
    DemoNamespace(const DemoNamespace&) = delete;
    DemoNamespace& operator=(const DemoNamespace&) = delete;

    UInt16 namespaceIndex() const { return ns_; }
    NodeId nodeId(std::string_view stringId) const;  // ns=<demo>;s=<stringId>
    // Sleep calls currently waiting.
    std::size_t pendingSleeps() const;

  private:
    UInt16 ns_ = 0;
    std::shared_ptr<SleepWorker> worker_;
    std::unique_ptr<DemoTicker> ticker_;  // with a Server only
};

// The same nodes, without an owner object: the Sleep worker lives as long as the method
// handler (i.e. the address space). Returns the namespace index.
UInt16 addDemoNamespace(server::Server& server, const DemoOptions& options = {});
UInt16 addDemoNamespace(server::AddressSpace& addressSpace, const DemoOptions& options = {});

}  // namespace pnp::ua::demo
