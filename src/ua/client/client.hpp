// pnp OPC UA client (namespace pnp::ua::client).
//
//   Client client;                                            // ClientConfig{} defaults
//   client.connect("opc.tcp://127.0.0.1:4840");               // Anonymous
//   client.connect(url, UserName{"operator", "secret"});
//   Variant v = client.readValue(NodeId(0, ns0::Server_ServerStatus_CurrentTime));
//   UInt16 demo = client.namespaceIndex("urn:pnp:demo");
//   client.writeValue(NodeId(demo, "Scalar.Int32"), Int32{42});
//   CallResult r = client.call(NodeId(demo, "Demo"), NodeId(demo, "Demo.Add"), {Int32{2},
//   Int32{3}});
//
// Services. Every service is built on the generic request<Req, Resp>(req, deadline), which
// fills the RequestHeader, encodes straight into the transport's message buffer, sends,
// waits for the response on the calling thread and decodes it. Adding a service is one
// PNP_UA_CLIENT_SERVICE line in services.hpp.
//
// Errors. Service-level failures (ServiceFault, a Bad serviceResult, an undecodable
// response) and transport failures throw ua::client::Error carrying the StatusCode.
// Per-operation statuses are returned in the results (DataValue::status, the StatusCodes of
// write(), CallResult::status, BrowseResult::statusCode, ...). Convenience calls that
// return a bare value (readValue, resolve, browse(NodeId), registerNodes, namespaceIndex)
// throw Error with the operation's status instead, since they have nowhere else to put it.
//
// Deadlines. Every blocking call takes a Deadline (default: config().requestTimeout, or
// config().connectTimeout for connect()). When it passes, the call throws Error(BadTimeout);
// the connection stays usable and a late response is discarded.
//
// Reconnect. When the connection drops (or is found closed before a request is sent), the
// next call, or the background thread when it runs, reconnects: a new secure channel, then
// ActivateSession on the existing session with the same authentication token and identity;
// when the server no longer knows the session (BadSessionIdInvalid, BadSessionClosed, ...) a
// new session is created and activated transparently (the namespace cache is then cleared;
// registered node ids and continuation points of the old session are invalid). The call
// that hit the drop is then retried once, but only if the request could not be sent at all,
// or if the service is idempotent (ServiceTraits<Req>::idempotent: Read, Browse,
// TranslateBrowsePathsToNodeIds, GetEndpoints, FindServers, HistoryRead); otherwise it
// throws the transport's error (e.g. BadConnectionClosed) and the next call reconnects.
// See ReconnectPolicy.
//
// Asynchronous calls and threads. requestAsync()/readAsync()/... send the request at once
// and return; the callback runs exactly once, with the response or the Error, on whichever
// thread dispatches completions: a thread inside runIterate(), a thread inside any blocking
// call of this client (after that call's own response, before it returns), or the
// background thread started by startBackgroundThread(). If the request cannot be sent the
// callback runs before requestAsync() returns. Callbacks run without the client's lock held,
// so they may call the client (blocking calls included); they must not throw (exceptions
// are swallowed) and must not destroy the client. The std::future forms complete the same
// way: waiting on such a future only makes progress if another thread (e.g. the background
// thread) dispatches.
//
// Thread safety. All member functions may be called from any thread. One mutex guards the
// connection: blocking calls from several threads are serialised (each holds the
// connection for its round trip); use the async forms to pipeline requests.
//
// Background thread (optional): dispatches async completions as responses arrive, expires
// async deadlines, reconnects with back-off (ReconnectPolicy::initialDelay/maxDelay), lets
// the transport renew the secure channel token while idle, and keeps the session alive by
// reading Server_ServerStatus_CurrentTime after keepAliveInterval without requests. It is
// stopped and joined by stopBackgroundThread() and by the destructor. runIterate() does the
// same work on the calling thread.
//
// Subscriptions: see subscription.hpp (Subscription, MonitoredItem); their Publish requests
// are async requests of this client and complete on the threads named above.
//
// Performance. A blocking call is: encode into the transport buffer, one send, poll/recv on
// the calling thread, decode; no thread hop. connect() costs TCP + HEL/ACK +
// OpenSecureChannel + CreateSession + ActivateSession and nothing else (no NamespaceArray or
// endpoint reads unless asked).
#pragma once

#include <chrono>
#include <concepts>
#include <cstddef>
#include <functional>
#include <future>
#include <memory>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "ua/client/config.hpp"
#include "ua/client/deadline.hpp"
#include "ua/client/error.hpp"
#include "ua/client/services.hpp"
#include "ua/transport/client_connection.hpp"
#include "ua/types/ns0_types_services.hpp"

namespace pnp::ua::client {

// The outcome of one method call. A Bad status is not thrown.
struct CallResult {
    StatusCode status;
    std::vector<StatusCode> inputArgumentResults;  // empty unless the server reported them
    std::vector<Variant> outputs;
    bool ok() const { return !status.isBad(); }
};

// Options of the convenience browse(NodeId), which follows continuation points.
struct BrowseOptions {
    BrowseDirection direction = BrowseDirection::Forward;
    NodeId referenceTypeId = NodeId(0, 33);  // HierarchicalReferences
    bool includeSubtypes = true;
    UInt32 nodeClassMask = 0;         // 0: all node classes
    UInt32 resultMask = 0x3F;         // all ReferenceDescription fields
    UInt32 maxReferencesPerNode = 0;  // per Browse/BrowseNext; 0: the server's choice
};

class SubscriptionEngine;

struct ClientStats {
    std::uint64_t requestsSent = 0;
    std::uint64_t timeouts = 0;            // calls that ran past their deadline
    std::uint64_t discardedResponses = 0;  // late or unknown responses
    std::uint64_t connectionsLost = 0;
    std::uint64_t reconnects = 0;  // successful reconnects
    std::uint64_t sessionsCreated = 0;
    std::uint64_t sessionsReactivated = 0;  // ActivateSession on a new channel
    std::uint64_t retries = 0;              // requests sent again after a reconnect
    std::uint64_t keepAlives = 0;
};

class Client {
  public:
    explicit Client(ClientConfig config = {});
    // Stops the background thread, closes the session (CloseSession) and the channel (CLO);
    // never throws. Pending async callbacks complete with BadShutdown.
    ~Client();
    Client(Client&&) noexcept;
    Client& operator=(Client&&) noexcept;
    Client(const Client&) = delete;
    Client& operator=(const Client&) = delete;

    const ClientConfig& config() const;

    // ---- connection -------------------------------------------------------------------
    // Opens a secure channel (SecurityPolicy None) and an activated session. A previous
    // connection is closed first. Throws Error (BadTimeout, BadConnectionRejected,
    // BadIdentityTokenRejected, BadUserAccessDenied, ...).
    void connect(std::string_view endpointUrl, Identity identity = Anonymous{},
                 Deadline deadline = {});
    // CloseSession + CloseSecureChannel; never throws. Pending async calls complete with
    // BadShutdown. The client can connect() again.
    void disconnect() noexcept;
    // A session was established and disconnect() was not called (the channel may currently
    // be down and about to be reconnected).
    bool isConnected() const;
    // The channel is open right now.
    bool isChannelOpen() const;
    std::string endpointUrl() const;
    NodeId sessionId() const;
    // Revised session timeout in ms (0 without a session).
    Double sessionTimeout() const;
    // The socket, for integration with an external poll loop (call runIterate(0ms) when it
    // is readable), or -1.
    int nativeHandle() const;
    ClientStats stats() const;

    // ---- generic service call ---------------------------------------------------------
    // Sends req and returns the response. The RequestHeader (authentication token,
    // timestamp, request handle, timeoutHint from the deadline) is supplied by the client;
    // whatever req.requestHeader holds is ignored. req is taken by value: pass an rvalue
    // (std::move) to avoid a copy. Throws Error for a ServiceFault, a Bad serviceResult, a
    // timeout or a transport failure. Resp defaults to ServiceTraits<Req>::Response; name it
    // explicitly for services without a trait: request<MyRequest, MyResponse>(req).
    template <class Req, class Resp = ResponseOf<Req>>
    Resp request(Req req, Deadline deadline = {});

    // Asynchronous forms; see "Asynchronous calls and threads" above.
    template <class Req, class Resp = ResponseOf<Req>, class F>
    requires std::invocable<F&, Result<Resp>>
    void requestAsync(Req req, F callback, Deadline deadline = {});
    template <class Req, class Resp = ResponseOf<Req>>
    std::future<Resp> requestAsync(Req req, Deadline deadline = {});

    // ---- discovery (no session needed) ------------------------------------------------
    // With an empty url, or the url of the current connection, the current channel is used;
    // otherwise a temporary connection to url is opened and closed.
    std::vector<EndpointDescription> getEndpoints(std::string_view url = {},
                                                  Deadline deadline = {});
    std::vector<ApplicationDescription> findServers(std::string_view url = {},
                                                    Deadline deadline = {});
    // Any discovery service (FindServersOnNetwork, RegisterServer2, ...) the same way: on
    // the current channel, or without a session on a temporary connection to url.
    template <class Req, class Resp = ResponseOf<Req>>
    Resp discoveryRequest(std::string_view url, Req req, Deadline deadline = {});

    // ---- view -------------------------------------------------------------------------
    // One Browse; the result may carry a continuation point (see browseNext()).
    BrowseResult browse(const BrowseDescription& node, UInt32 maxReferencesPerNode = 0,
                        Deadline deadline = {});
    std::vector<BrowseResult> browse(std::vector<BrowseDescription> nodes,
                                     UInt32 maxReferencesPerNode = 0, Deadline deadline = {});
    // All references of a node: follows continuation points with BrowseNext. Throws Error
    // with the operation's status when it is Bad. The deadline covers the whole sequence.
    std::vector<ReferenceDescription> browse(const NodeId& node, const BrowseOptions& options = {},
                                             Deadline deadline = {});
    BrowseResult browseNext(const ByteString& continuationPoint, bool release = false,
                            Deadline deadline = {});
    std::vector<BrowseResult> browseNext(std::vector<ByteString> continuationPoints, bool release,
                                         Deadline deadline = {});
    std::vector<BrowsePathResult> translateBrowsePaths(std::vector<BrowsePath> paths,
                                                       Deadline deadline = {});
    // The node at a text path (see browse_path.hpp), from the Root folder when the path is
    // "/Objects/Server/ServerStatus"-like, or from `start`. Namespace URI prefixes are
    // resolved with namespaceIndex(). Throws Error (e.g. BadNoMatch) when there is no match.
    NodeId resolve(std::string_view path, Deadline deadline = {});
    NodeId resolve(const NodeId& start, std::string_view path, Deadline deadline = {});
    std::vector<NodeId> registerNodes(std::vector<NodeId> nodes, Deadline deadline = {});
    void unregisterNodes(std::vector<NodeId> nodes, Deadline deadline = {});

    // ---- attributes -------------------------------------------------------------------
    // Server and source timestamps are requested.
    std::vector<DataValue> read(std::vector<ReadValueId> nodes, Deadline deadline = {});
    std::vector<DataValue> read(std::vector<ReadValueId> nodes, TimestampsToReturn timestamps,
                                Deadline deadline = {});
    // The DataValue with its status (not thrown).
    DataValue readAttribute(const NodeId& node, AttributeId attribute, Deadline deadline = {});
    // The Value attribute; throws Error with the operation's status when it is Bad.
    Variant readValue(const NodeId& node, Deadline deadline = {});
    std::vector<StatusCode> write(std::vector<WriteValue> nodes, Deadline deadline = {});
    StatusCode writeAttribute(const NodeId& node, AttributeId attribute, DataValue value,
                              Deadline deadline = {});
    StatusCode writeValue(const NodeId& node, Variant value, Deadline deadline = {});

    // ---- methods ----------------------------------------------------------------------
    std::vector<CallMethodResult> call(std::vector<CallMethodRequest> calls,
                                       Deadline deadline = {});
    CallResult call(const NodeId& object, const NodeId& method, std::vector<Variant> inputs,
                    Deadline deadline = {});

    // ---- asynchronous convenience forms -----------------------------------------------
    void readAsync(std::vector<ReadValueId> nodes,
                   std::function<void(Result<std::vector<DataValue>>)> callback,
                   Deadline deadline = {});
    void readValueAsync(const NodeId& node, std::function<void(Result<Variant>)> callback,
                        Deadline deadline = {});
    void writeAsync(std::vector<WriteValue> nodes,
                    std::function<void(Result<std::vector<StatusCode>>)> callback,
                    Deadline deadline = {});
    void callAsync(const NodeId& object, const NodeId& method, std::vector<Variant> inputs,
                   std::function<void(Result<CallResult>)> callback, Deadline deadline = {});

    // ---- namespaces -------------------------------------------------------------------
    // The index of a namespace URI. The NamespaceArray is read on first use and cached (and
    // re-read once when the URI is not in the cache). Throws Error(BadNotFound).
    UInt16 namespaceIndex(std::string_view uri, Deadline deadline = {});
    // Reads the NamespaceArray now (and refreshes the cache).
    std::vector<std::string> namespaceArray(Deadline deadline = {});
    // Parses "i=85", "ns=2;s=Demo" or "nsu=urn:pnp:demo;s=Demo" (the URI is resolved with
    // namespaceIndex()). Throws Error(BadNodeIdInvalid) for malformed text.
    NodeId parseNodeId(std::string_view text, Deadline deadline = {});
    // Resolves the namespace URI of an ExpandedNodeId (server index must be 0).
    NodeId toNodeId(const ExpandedNodeId& id, Deadline deadline = {});

    // ---- event loop -------------------------------------------------------------------
    // Dispatches completions of async calls, expires their deadlines, reconnects if needed
    // and keeps the session alive, waiting at most `timeout` for at least one completion.
    // Returns the number of callbacks run.
    std::size_t runIterate(milliseconds timeout = milliseconds(0));
    // Starts/stops a thread doing what runIterate() does, continuously.
    void startBackgroundThread();
    void stopBackgroundThread();
    bool backgroundThreadRunning() const;

    // The Publish loop of this client's subscriptions (subscription.hpp), created on first
    // use.
    std::shared_ptr<SubscriptionEngine> subscriptionEngine();

    class Impl;

  private:
    // Appends the request (encoding NodeId + body) to `buffer`, with `header` encoded in
    // place of the request's own RequestHeader (no copy of the authentication token).
    // With `splices`, large byte runs of the request are referenced, not copied: the
    // request must stay unchanged until the message is sent.
    struct EncodeRef {
        const void* object;
        void (*function)(const void*, Buffer&, const RequestHeader&, Splices*);
        void operator()(Buffer& b, const RequestHeader& h, Splices* splices = nullptr) const {
            function(object, b, h, splices);
        }
    };
    template <class Req>
    static EncodeRef encoderFor(const Req& req) {
        return {&req, [](const void* p, Buffer& b, const RequestHeader& h, Splices* splices) {
                    detail::encodeRequest(b, *static_cast<const Req*>(p), h, splices);
                }};
    }
    // Decodes a response while the client's lock is still held: its body may be a view of
    // the connection's receive buffer, which the next receive (any thread) overwrites.
    struct DecodeRef {
        void* object;
        void (*function)(void*, const transport::IncomingResponse&, const DecodeLimits&);
        void operator()(const transport::IncomingResponse& r, const DecodeLimits& l) const {
            function(object, r, l);
        }
    };
    template <class Req, class Resp>
    static DecodeRef decoderInto(Resp& out) {
        return {&out, [](void* p, const transport::IncomingResponse& r, const DecodeLimits& l) {
                    *static_cast<Resp*>(p) = decodeIncoming<Resp>(r, detail::serviceName<Req>(), l);
                }};
    }
    using RawCallback = std::function<void(Result<transport::IncomingResponse>)>;

    void roundTrip(EncodeRef encode, DecodeRef decode, bool idempotent, Deadline deadline,
                   std::string_view service);
    void sendAsync(EncodeRef encode, Deadline deadline, std::string_view service,
                   RawCallback callback);
    // secured: a temporary connection uses the client's security, if it has one (Part 4
    // §5.4.5: RegisterServer is only accepted over a channel that authenticates the server).
    transport::IncomingResponse discoveryRoundTrip(std::string_view url, EncodeRef encode,
                                                   Deadline deadline, std::string_view service,
                                                   bool secured = false);
    const DecodeLimits& decodeLimits() const;

    template <class Resp>
    static Resp decodeIncoming(const transport::IncomingResponse& r, std::string_view service,
                               const DecodeLimits& limits);

    std::unique_ptr<Impl> impl_;
};

// ---- templates ---------------------------------------------------------------------------

template <class Resp>
Resp Client::decodeIncoming(const transport::IncomingResponse& r, std::string_view service,
                            const DecodeLimits& limits) {
    if (r.status.isBad()) throw Error(r.status, std::string(service) + ": response aborted");
    return detail::decodeResponse<Resp>(r.typeId, r.body.data(), r.body.size(), service, limits,
                                        r.body.block());
}

template <class Req, class Resp>
Resp Client::discoveryRequest(std::string_view url, Req req, Deadline deadline) {
    constexpr std::string_view service = detail::serviceName<Req>();
    constexpr bool secured =
        std::is_same_v<Req, RegisterServerRequest> || std::is_same_v<Req, RegisterServer2Request>;
    auto r = discoveryRoundTrip(url, encoderFor(req), deadline, service, secured);
    return decodeIncoming<Resp>(r, service, decodeLimits());
}

template <class Req, class Resp>
Resp Client::request(Req req, Deadline deadline) {
    constexpr std::string_view service = detail::serviceName<Req>();
    Resp out{};
    roundTrip(encoderFor(req), decoderInto<Req>(out), ServiceTraits<Req>::idempotent, deadline,
              service);
    return out;
}

template <class Req, class Resp, class F>
requires std::invocable<F&, Result<Resp>>
void Client::requestAsync(Req req, F callback, Deadline deadline) {
    static constexpr std::string_view service = detail::serviceName<Req>();
    sendAsync(encoderFor(req), deadline, service,
              [cb = std::move(callback),
               limits = decodeLimits()](Result<transport::IncomingResponse> r) mutable {
                  auto result = [&]() -> Result<Resp> {
                      if (!r.ok()) return *r.error();
                      try {
                          return decodeIncoming<Resp>(r.value(), service, limits);
                      } catch (const Error& e) {
                          return e;
                      }
                  }();
                  cb(std::move(result));
              });
}

template <class Req, class Resp>
std::future<Resp> Client::requestAsync(Req req, Deadline deadline) {
    auto promise = std::make_shared<std::promise<Resp>>();
    std::future<Resp> future = promise->get_future();
    requestAsync<Req, Resp>(
        std::move(req),
        [promise](Result<Resp> r) {
            if (r.ok())
                promise->set_value(std::move(r).value());
            else
                promise->set_exception(std::make_exception_ptr(*r.error()));
        },
        deadline);
    return future;
}

}  // namespace pnp::ua::client
