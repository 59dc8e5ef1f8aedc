#include "skill/server/locking.hpp"

#include <algorithm>

#include "skill/model/model.hpp"
#include "ua/server/address_space.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::skill::server {

using ua::NodeId;
using ua::StatusCode;
using ua::Variant;
using ua::server::MethodCallContext;
using ua::server::MethodCompletion;
using Clock = std::chrono::steady_clock;

struct LockingServices::State {
    ua::server::AddressSpace& space;
    std::chrono::milliseconds maxInactive;
    mutable std::mutex mutex;
    NodeId holder;  // null: not locked
    std::string context;
    Clock::time_point lastActivity{};
    NodeId lockedVar, clientVar, userVar, remainingVar;

    State(ua::server::AddressSpace& s, std::chrono::milliseconds m) : space(s), maxInactive(m) {}

    // With mutex held: ends a lock whose holder was inactive too long.
    void expire(Clock::time_point now) {
        if (!holder.isNull() && now - lastActivity >= maxInactive) release();
    }
    void release() {
        holder = NodeId();
        context.clear();
        publish();
    }
    void publish() {
        const bool locked = !holder.isNull();
        if (!lockedVar.isNull()) space.setValue(lockedVar, ua::DataValue(Variant(locked)));
        if (!clientVar.isNull())
            space.setValue(clientVar,
                           ua::DataValue(Variant(ua::String(locked ? holder.toString() : ""))));
        if (!userVar.isNull())
            space.setValue(userVar, ua::DataValue(Variant(ua::String(locked ? context : ""))));
    }
    double remainingMs(Clock::time_point now) const {
        if (holder.isNull()) return 0;
        auto left = maxInactive - (now - lastActivity);
        return std::max(0.0, std::chrono::duration<double, std::milli>(left).count());
    }
};

namespace {
NodeId child(const ua::server::AddressSpace& space, const NodeId& parent, ua::UInt16 ns,
             const char* name) {
    std::vector<ua::QualifiedName> path{ua::QualifiedName(ns, name)};
    return space.resolvePath(parent, path).value_or(NodeId());
}
}  // namespace

LockingServices::LockingServices(ua::server::Server& server, const NodeId& lockObject,
                                 std::chrono::milliseconds maxInactiveLockTime)
    : state_(std::make_shared<State>(server.addressSpace(), maxInactiveLockTime)) {
    auto& space = server.addressSpace();
    const auto di = space.namespaceIndex(kDiUri);
    if (!di) throw std::runtime_error("LockingServices: the DI model is not loaded");
    State& s = *state_;
    s.lockedVar = child(space, lockObject, *di, "Locked");
    s.clientVar = child(space, lockObject, *di, "LockingClient");
    s.userVar = child(space, lockObject, *di, "LockingUser");
    s.remainingVar = child(space, lockObject, *di, "RemainingLockTime");
    {
        std::lock_guard lock(s.mutex);
        s.publish();
    }
    std::weak_ptr<State> weak = state_;
    if (!s.remainingVar.isNull())
        space.setValueCallback(s.remainingVar, {.read =
                                                    [weak](const NodeId&) {
                                                        auto st = weak.lock();
                                                        double ms = 0;
                                                        if (st) {
                                                            std::lock_guard l(st->mutex);
                                                            st->expire(Clock::now());
                                                            ms = st->remainingMs(Clock::now());
                                                        }
                                                        return ua::DataValue(Variant(ms));
                                                    },
                                                .write = {}});

    using Op = ua::Int32 (*)(State&, const NodeId& session, const std::vector<Variant>& in);
    auto bind = [&](const char* name, Op op) {
        NodeId m = child(space, lockObject, *di, name);
        if (m.isNull()) throw std::runtime_error(std::string("LockingServices: no method ") + name);
        space.setMethodHandler(m, [weak, op](const MethodCallContext& ctx,
                                             std::vector<Variant> inputs, MethodCompletion done) {
            auto st = weak.lock();
            if (!st) return done.fail(ua::status::BadInvalidState);
            ua::Int32 result = 0;
            {
                std::lock_guard l(st->mutex);
                st->expire(Clock::now());
                result = op(*st, ctx.sessionId, inputs);
            }
            done.succeed({Variant(result)});
        });
    };
    bind("InitLock", [](State& st, const NodeId& session, const std::vector<Variant>& in) {
        if (!st.holder.isNull()) return lock_status::AlreadyLocked;
        st.holder = session;
        const auto* context = in.empty() ? nullptr : in[0].scalar<ua::String>();
        st.context = context != nullptr ? *context : "";
        st.lastActivity = Clock::now();
        st.publish();
        return lock_status::Ok;
    });
    bind("RenewLock", [](State& st, const NodeId& session, const std::vector<Variant>&) {
        if (st.holder.isNull()) return lock_status::NotLocked;
        if (st.holder != session) return lock_status::LockedByOther;
        st.lastActivity = Clock::now();
        return lock_status::Ok;
    });
    bind("ExitLock", [](State& st, const NodeId& session, const std::vector<Variant>&) {
        if (st.holder.isNull()) return lock_status::NotLocked;
        if (st.holder != session) return lock_status::LockedByOther;
        st.release();
        return lock_status::Ok;
    });
    bind("BreakLock", [](State& st, const NodeId&, const std::vector<Variant>&) {
        if (st.holder.isNull()) return lock_status::NotLocked;
        st.release();
        return lock_status::Ok;
    });
    // A session that ends gives its locks up.
    server.onSessionClosed([weak](const NodeId& session) {
        if (auto st = weak.lock()) {
            std::lock_guard l(st->mutex);
            if (st->holder == session) st->release();
        }
    });
}

LockingServices::~LockingServices() = default;

bool LockingServices::allows(const NodeId& session) {
    State& s = *state_;
    std::lock_guard lock(s.mutex);
    const auto now = Clock::now();
    s.expire(now);
    if (s.holder.isNull()) return true;
    if (s.holder != session) return false;
    s.lastActivity = now;
    return true;
}

bool LockingServices::locked() const {
    std::lock_guard lock(state_->mutex);
    state_->expire(Clock::now());
    return !state_->holder.isNull();
}

NodeId LockingServices::holder() const {
    std::lock_guard lock(state_->mutex);
    state_->expire(Clock::now());
    return state_->holder;
}

}  // namespace pnp::skill::server
