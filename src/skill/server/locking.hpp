// DI LockingServices (OPC 10000-100 §7) on one Lock object (a LockingServicesType instance,
// e.g. every skill's DI:Lock): InitLock, RenewLock, ExitLock, BreakLock, and the properties
// Locked, LockingClient, LockingUser, RemainingLockTime kept current.
//
// A lock belongs to the session that called InitLock. While it is held, allows(session) is
// false for every other session: the skill refuses their parameter writes and method calls
// with Bad_Locked. The lock ends with ExitLock, BreakLock, the end of the holder's session,
// or MaxInactiveLockTime without activity of the holder (every allowed write or call of the
// holder, and RenewLock, count as activity).
//
// Threads: every member may be called from any thread (the method handlers run on the
// network thread); one mutex.
#pragma once

#include <chrono>
#include <memory>
#include <mutex>

#include "ua/server/server.hpp"

namespace pnp::skill::server {

class LockingServices {
  public:
    // Binds the methods and properties below `lockObject`. Construct before Server::start()
    // or inside Server::post() (it sets method handlers and value callbacks).
    LockingServices(ua::server::Server& server, const ua::NodeId& lockObject,
                    std::chrono::milliseconds maxInactiveLockTime);
    ~LockingServices();
    LockingServices(const LockingServices&) = delete;
    LockingServices& operator=(const LockingServices&) = delete;

    // Whether `session` may change the locked element now: no lock, or its own lock (which
    // counts as activity and renews it).
    bool allows(const ua::NodeId& session);
    bool locked() const;
    ua::NodeId holder() const;  // null when not locked

    struct State;

  private:
    std::shared_ptr<State> state_;
};

}  // namespace pnp::skill::server
