// Method Service Set (OPC 10000-4 §5.11): Call with asynchronous completion.
#include <future>
#include <optional>

#include "ua/server/address_space_impl.hpp"

namespace pnp::ua::server {

namespace {

// Collects the results of one Call request; completes it when the last method finished.
struct CallState {
    CallState(std::size_t n, std::function<void(CallResponse)> d)
        : pending(n + 1), done(std::move(d)) {
        response.results.resize(n);
    }
    // Records a result; the last one (pending reaches 0) delivers the response.
    void complete(std::size_t index, StatusCode status, std::vector<Variant> outputs) {
        std::unique_lock lock(mutex);
        auto& r = response.results[index];
        r.statusCode = status;
        if (status.isGood()) r.outputArguments = std::move(outputs);
        finishOne(lock);
    }
    void finishOne(std::unique_lock<std::mutex>& lock) {
        if (--pending != 0) return;
        CallResponse out = std::move(response);
        auto callback = std::move(done);
        lock.unlock();
        if (callback) callback(std::move(out));
    }

    std::mutex mutex;
    CallResponse response;
    std::size_t pending;
    std::function<void(CallResponse)> done;
};

}  // namespace

struct MethodCompletion::Slot {
    Slot(std::shared_ptr<CallState> s, std::size_t i) : state(std::move(s)), index(i) {}
    ~Slot() {
        if (!completed.exchange(true)) state->complete(index, status::BadInternalError, {});
    }
    std::shared_ptr<CallState> state;
    std::size_t index;
    std::atomic<bool> completed{false};
};

void MethodCompletion::operator()(StatusCode status, std::vector<Variant> outputs) const {
    if (!slot_ || slot_->completed.exchange(true)) return;
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
                        std::function<void(CallResponse)> done) {
    call(CallRequest(request), sessionId, std::move(done));
}

void AddressSpace::call(CallRequest&& request, const NodeId& sessionId,
                        std::function<void(CallResponse)> done) {
    if (request.methodsToCall.empty()) {
        CallResponse r;
        r.responseHeader.serviceResult = status::BadNothingToDo;
        if (done) done(std::move(r));
        return;
    }
    const std::size_t n = request.methodsToCall.size();
    auto state = std::make_shared<CallState>(n, std::move(done));
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
            } else if (!s.nodes[method].has(Node::kUserExecutable)) {
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
            --state->pending;  // not shared with any thread yet
        }
    }
    // Handlers run without the lock; each may complete now or later, on any thread.
    auto start = [&](Run& run) {
        auto slot = std::make_shared<MethodCompletion::Slot>(state, run.index);
        MethodCompletion completion(slot);
        try {
            (*run.handler)(run.context, std::move(request.methodsToCall[run.index].inputArguments),
                           completion);
        } catch (...) {
            completion(status::BadInternalError);
        }
    };
    if (firstRun) start(*firstRun);
    for (auto& run : moreRuns) start(run);
    std::unique_lock lock(state->mutex);
    state->finishOne(lock);
}

CallResponse AddressSpace::callSync(const CallRequest& request, const NodeId& sessionId) {
    auto promise = std::make_shared<std::promise<CallResponse>>();
    auto future = promise->get_future();
    call(request, sessionId, [promise](CallResponse r) { promise->set_value(std::move(r)); });
    return future.get();
}

}  // namespace pnp::ua::server
