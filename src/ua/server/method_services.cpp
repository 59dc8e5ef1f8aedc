// Method Service Set (OPC 10000-4 §5.11): Call with asynchronous completion.
#include <atomic>
#include <future>
#include <memory>
#include <optional>

#include "ua/server/address_space_impl.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::server {

namespace {
class CallState;
}

// One method of a Call request in flight. `refs` counts the MethodCompletion copies; the
// last one to go completes the method with Bad_InternalError if nobody did.
struct MethodCompletion::Slot {
    CallState* state = nullptr;
    std::size_t index = 0;
    std::atomic<std::size_t> refs{0};
    std::atomic<bool> completed{false};
    void release() noexcept;
};

namespace {

// One Call request in flight: the response being filled in, a slot per method and `done`.
// One allocation per request, no lock: every method writes only its own result, and the
// completion that brings `pending` to zero (acquire-release) delivers the response.
// `refs` keeps it alive: one for AddressSpace::call() itself, one per slot with completions.
class CallState {
  public:
    CallState(std::size_t n, std::function<void(CallResponse)> d)
        : pending_(n + 1), done_(std::move(d)) {
        response.results.resize(n);
        if (n > 1) moreSlots_ = std::make_unique<MethodCompletion::Slot[]>(n - 1);
        for (std::size_t k = 0; k < n; ++k) {
            slot(k).state = this;
            slot(k).index = k;
        }
    }

    MethodCompletion::Slot& slot(std::size_t k) { return k == 0 ? firstSlot_ : moreSlots_[k - 1]; }
    // A method that never runs (its checks failed): only before the state is shared.
    void skip() { pending_.fetch_sub(1, std::memory_order_relaxed); }
    void retain() { refs_.fetch_add(1, std::memory_order_relaxed); }
    void release() {
        if (refs_.fetch_sub(1, std::memory_order_acq_rel) == 1) delete this;
    }
    // Records a method's result (each index once); the last one delivers the response.
    void complete(std::size_t index, StatusCode status, std::vector<Variant> outputs) {
        auto& r = response.results[index];
        r.statusCode = status;
        if (status.isGood()) r.outputArguments = std::move(outputs);
        finishOne();
    }
    void finishOne() {
        if (pending_.fetch_sub(1, std::memory_order_acq_rel) != 1) return;
        auto done = std::move(done_);
        if (done) done(std::move(response));
    }

    CallResponse response;

  private:
    std::atomic<std::size_t> pending_;  // methods not yet completed, +1 while call() runs
    std::atomic<std::size_t> refs_{1};
    std::function<void(CallResponse)> done_;
    MethodCompletion::Slot firstSlot_;
    std::unique_ptr<MethodCompletion::Slot[]> moreSlots_;
};

}  // namespace

void MethodCompletion::Slot::release() noexcept {
    if (refs.fetch_sub(1, std::memory_order_acq_rel) != 1) return;
    if (!completed.exchange(true, std::memory_order_acq_rel)) {
        try {
            state->complete(index, status::BadInternalError, {});
        } catch (...) {
            // `done` threw: nothing left to tell (a destructor must not throw)
        }
    }
    state->release();
}

MethodCompletion::MethodCompletion(const MethodCompletion& other) noexcept : slot_(other.slot_) {
    if (slot_ != nullptr) slot_->refs.fetch_add(1, std::memory_order_relaxed);
}

MethodCompletion::~MethodCompletion() {
    if (slot_ != nullptr) slot_->release();
}

void MethodCompletion::operator()(StatusCode status, std::vector<Variant> outputs) const {
    if (slot_ == nullptr || slot_->completed.exchange(true, std::memory_order_acq_rel)) return;
    slot_->state->complete(slot_->index, status, std::move(outputs));
}

MethodHandler makeMethodHandler(SyncMethodHandler handler) {
    return [h = std::move(handler)](const MethodCallContext& context, std::vector<Variant> inputs,
                                    MethodCompletion done) {
        std::vector<Variant> outputs;
        StatusCode s = h(context, inputs, outputs);
        done(s, std::move(outputs));
    };
}

namespace {

// Whether `method` is a component of `object`, of its type or of a supertype of that type.
// Walks the method's inverse HasComponent references (usually one) rather than the
// object's references (an object may have hundreds of components).
bool methodBelongsTo(const AddressSpace::Impl& s, NodeIndex object, NodeIndex method) {
    auto isComponentOf = [&](NodeIndex holder) {
        for (const Ref& r : s.nodes[method].refs)
            if (r.target == holder && !r.isForward() && !r.isExternal() &&
                s.refTypeMatches(r.type, s.rtHasComponent, true))
                return true;
        return false;
    };
    if (isComponentOf(object)) return true;
    NodeIndex type = s.nodes[object].nodeClass == NodeClassBits::Object ? s.typeDefinitionOf(object)
                                                                        : s.supertypeOf(object);
    for (int depth = 0; type != kNoNode && depth < 64; ++depth) {
        if (isComponentOf(type)) return true;
        type = s.supertypeOf(type);
    }
    return false;
}

}  // namespace

void AddressSpace::call(const CallRequest& request, const NodeId& sessionId,
                        std::function<void(CallResponse)> done, const SessionIdentity* user) {
    call(CallRequest(request), sessionId, std::move(done), user);
}

void AddressSpace::call(CallRequest&& request, const NodeId& sessionId,
                        std::function<void(CallResponse)> done, const SessionIdentity* user) {
    if (request.methodsToCall.empty()) {
        CallResponse r;
        r.responseHeader.serviceResult = status::BadNothingToDo;
        if (done) done(std::move(r));
        return;
    }
    const std::size_t n = request.methodsToCall.size();
    struct Release {
        void operator()(CallState* s) const { s->release(); }
    };
    std::unique_ptr<CallState, Release> state(new CallState(n, std::move(done)));
    struct Run {
        std::size_t index;
        std::shared_ptr<const MethodHandler> handler;
        MethodCallContext context;
    };
    // Most Calls carry one method: its Run stays on the stack.
    std::optional<Run> firstRun;
    std::vector<Run> moreRuns;
    {
        std::shared_lock lock(impl_->mutex);
        const Impl& s = *impl_;
        const bool checked = s.checksPermissions(user);
        for (std::size_t k = 0; k < n; ++k) {
            const CallMethodRequest& m = request.methodsToCall[k];
            CallMethodResult& res = state->response.results[k];
            NodeIndex object = s.find(m.objectId);
            NodeIndex method = s.find(m.methodId);
            StatusCode st;
            if (object == kNoNode) {
                st = status::BadNodeIdUnknown;
            } else if (s.nodes[object].nodeClass != NodeClassBits::Object &&
                       s.nodes[object].nodeClass != NodeClassBits::ObjectType) {
                st = status::BadNodeIdInvalid;
            } else if (method == kNoNode || s.nodes[method].nodeClass != NodeClassBits::Method ||
                       !methodBelongsTo(s, object, method)) {
                st = status::BadMethodInvalid;
            } else if (!s.nodes[method].has(Node::kExecutable)) {
                st = status::BadNotExecutable;
            } else if (!s.nodes[method].has(Node::kUserExecutable) ||
                       (checked && (s.userPermissions(object, user) &
                                    s.userPermissions(method, user) & permission::Call) == 0)) {
                // The Call permission is needed on the method and on the object it is called
                // on (OPC 10000-3 §8.55).
                st = status::BadUserAccessDenied;
            } else {
                const auto declared = s.inputArguments(method);  // keeps them alive
                const std::vector<Argument>& args = *declared;
                if (m.inputArguments.size() < args.size()) {
                    st = status::BadArgumentsMissing;
                } else if (m.inputArguments.size() > args.size()) {
                    st = status::BadTooManyArguments;
                } else {
                    // inputArgumentResults only when one is bad (no allocation otherwise).
                    const NodeIndex baseDataType = s.find(ns0::BaseDataType);
                    auto check = [&](std::size_t a) {
                        NodeIndex dt = s.find(args[a].dataType);
                        return s.checkValue(m.inputArguments[a], dt, args[a].valueRank,
                                            args[a].arrayDimensions, dt == baseDataType);
                    };
                    std::size_t firstBad = 0;
                    while (firstBad < args.size() && !check(firstBad).isBad()) ++firstBad;
                    if (firstBad < args.size()) {
                        st = status::BadInvalidArgument;
                        res.inputArgumentResults.resize(args.size());
                        for (std::size_t a = 0; a < args.size(); ++a)
                            res.inputArgumentResults[a] = check(a);
                    } else {
                        auto h = s.handlerOf(method);
                        if (h == nullptr) {
                            st = status::BadNotImplemented;
                        } else {
                            Run run{k, std::move(h),
                                    MethodCallContext{m.objectId, m.methodId, sessionId}};
                            if (!firstRun)
                                firstRun.emplace(std::move(run));
                            else
                                moreRuns.push_back(std::move(run));
                            continue;
                        }
                    }
                }
            }
            res.statusCode = st;
            state->skip();
        }
    }
    // Handlers run without the lock; each may complete now or later, on any thread.
    auto start = [&](Run& run) {
        MethodCompletion::Slot& slot = state->slot(run.index);
        slot.refs.store(1, std::memory_order_relaxed);
        state->retain();  // released with the slot's last completion
        try {
            (*run.handler)(run.context, std::move(request.methodsToCall[run.index].inputArguments),
                           MethodCompletion(&slot));
        } catch (...) {
            // A handler that throws fails its method now, even if it kept a completion.
            if (!slot.completed.exchange(true, std::memory_order_acq_rel))
                state->complete(run.index, status::BadInternalError, {});
        }
    };
    if (firstRun) start(*firstRun);
    for (auto& run : moreRuns) start(run);
    state->finishOne();
}

CallResponse AddressSpace::callSync(const CallRequest& request, const NodeId& sessionId) {
    auto promise = std::make_shared<std::promise<CallResponse>>();
    auto future = promise->get_future();
    call(request, sessionId, [promise](CallResponse r) { promise->set_value(std::move(r)); });
    return future.get();
}

}  // namespace pnp::ua::server
