// fuzz_ua_messages: the server's message path end to end, without sockets.
//
// Bytes -> transport::ServerChannel (framing, HEL/ACK, OPN, MSG/CLO chunks, assembly)
//       -> server::Server::onRequest (service dispatch, bounded decoding, session checks,
//          address space services) through a fake ServerConnection
//       -> responses back through the same ServerChannel (chunking, size limits).
// One Server (with the demo namespace and two extra methods) is built once per process.
//
// Input: byte 0 % 4 selects the mode.
//   0  stream       the rest is what a client sends on a fresh connection (HEL, OPN, MSG ...)
//   1  open stream  the harness has already sent a valid HEL and OPN (channel id 1, token id
//                   1, sequence number 1), the rest continues that connection: MSG chunks
//                   with sequence numbers from 2 reach the services at once
//   2  service      byte 1 picks a request type (kServices); the rest is the request body
//                   after its RequestHeader, which the harness builds with a valid session
//   3  raw service  byte 1 picks a request type; the rest is the whole request body
// In every mode a RequestHeader whose AuthenticationToken is the placeholder below is given
// the token of the harness' activated session (same encoded length, patched in place), so
// seeds and mutations reach the session services. CloseSession is never patched: the
// harness session stays open.
//
// Checks (abort = a finding):
//   - sanitizers (ASan, UBSan, LSan) and libFuzzer's timeout / rss limits;
//   - every request handed to the server is answered exactly once (send or ServiceFault),
//     also when a method completes later or a password is checked on the auth worker (the
//     harness completes deferred calls and runs what the server posted at the end);
//   - every response the server encodes decodes again with the ns0 codecs, consumes all
//     bytes and re-encodes to the same bytes;
//   - everything the transport writes is a sequence of well-formed ACK / ERR / OPN / MSG
//     chunks within the negotiated send buffer size.
//
// Seeds: fuzz_ua_messages -pnp_write_seeds=<dir> (see fuzz_support.hpp).
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "fuzz_support.hpp"
#include "ua/demo/demo.hpp"
#include "ua/server/server.hpp"
#include "ua/transport/secure_channel.hpp"
#include "ua/types/extension_object.hpp"
#include "ua/types/ns0_ids.hpp"
#include "ua/types/ns0_types.hpp"
#include "ua/types/status_codes.hpp"

using namespace pnp::ua;
namespace tp = pnp::ua::transport;
using pnp::fuzz::check;

namespace {

constexpr UInt32 kChannelId = 1;  // the channel id of every fake connection
constexpr const char* kUrl = "opc.tcp://fuzz.invalid:4840/pnp";

enum Mode : Byte { kStream = 0, kOpenStream = 1, kServiceBody = 2, kServiceRaw = 3 };

template <class T>
constexpr UInt32 idOf() {
    return DataTypeInfo<T>::binaryEncodingId;
}

// Request types of the service modes. The last two are not served by the server.
constexpr UInt32 kServices[] = {
    idOf<GetEndpointsRequest>(),
    idOf<FindServersRequest>(),
    idOf<CreateSessionRequest>(),
    idOf<ActivateSessionRequest>(),
    idOf<CloseSessionRequest>(),
    idOf<ReadRequest>(),
    idOf<WriteRequest>(),
    idOf<BrowseRequest>(),
    idOf<BrowseNextRequest>(),
    idOf<TranslateBrowsePathsToNodeIdsRequest>(),
    idOf<RegisterNodesRequest>(),
    idOf<UnregisterNodesRequest>(),
    idOf<CallRequest>(),
    idOf<AddNodesRequest>(),
    4242,
};
constexpr std::size_t kServiceCount = sizeof kServices / sizeof kServices[0];

std::size_t serviceIndex(UInt32 encodingId) {
    for (std::size_t i = 0; i < kServiceCount; ++i)
        if (kServices[i] == encodingId) return i;
    return kServiceCount - 1;
}

// 32 bytes, like the server's tokens (NodeId(0, 32 random bytes)).
NodeId placeholderToken() {
    return NodeId(0, ByteString(std::string("pnp-fuzz-session-token-32-bytes!")));
}

// ---- the response / output checks -------------------------------------------------------
// PNP_FUZZ_VERBOSE=1: prints every response (to see what a seed or crash input reaches).
bool verbose() {
    static const bool v = std::getenv("PNP_FUZZ_VERBOSE") != nullptr;
    return v;
}

// A response as the server hands it to the transport: 24 reserved bytes, the encoding
// NodeId, the body.
void checkResponse(const Buffer& m) {
    check(m.size() >= tp::kSymmetricHeaderSize, "response without header space");
    const Byte* p = m.data() + tp::kSymmetricHeaderSize;
    const std::size_t n = m.size() - tp::kSymmetricHeaderSize;
    try {
        BinaryDecoder d(p, n);
        NodeId type;
        decode(d, type);
        check(type.namespaceIndex() == 0 && type.isNumeric(), "response type", type.toString());
        const DataTypeCodec* codec = findCodecByEncodingId(type.numeric());
        check(codec != nullptr, "response type without codec", type.toString());
        const std::size_t prefix = n - d.remaining();
        Buffer again;
        BinaryEncoder e(again);
        codec->reencode(d, e);
        check(d.remaining() == 0, "trailing bytes after the response", type.toString());
        if (verbose()) {
            std::fprintf(stderr, "  response %s (%zu bytes)", std::string(codec->name).c_str(), n);
            if (type.numeric() == idOf<ServiceFault>()) {
                BinaryDecoder f(p + prefix, n - prefix);
                ServiceFault fault;
                decode(f, fault);
                std::fprintf(stderr, " %s", fault.responseHeader.serviceResult.toString().c_str());
            }
            std::fprintf(stderr, "\n");
        }
        check(again.size() == n - prefix && std::equal(again.begin(), again.end(), p + prefix),
              "response does not re-encode to the same bytes", type.toString());
    } catch (const DecodeError& e) {
        pnp::fuzz::fail("the server's response does not decode", e.what());
    }
}

// What a ServerChannel writes: complete chunks only.
void checkOutput(const Buffer& b, const tp::NegotiatedLimits& limits, bool negotiated) {
    std::size_t at = 0;
    while (at < b.size()) {
        check(b.size() - at >= tp::kMessageHeaderSize, "output: partial header");
        tp::MessageHeader h;
        try {
            h = tp::decodeMessageHeader(b.data() + at);
        } catch (const tp::TransportError& e) {
            pnp::fuzz::fail("output: invalid header", e.what());
        }
        check(h.size <= b.size() - at, "output: chunk exceeds the write");
        switch (h.type) {
            case tp::MessageType::Acknowledge:
            case tp::MessageType::Error:
            case tp::MessageType::OpenSecureChannel:
                break;
            case tp::MessageType::Message:
                check(negotiated && h.size <= limits.sendBufferSize,
                      "output: MSG chunk larger than the send buffer",
                      std::to_string(h.size) + " > " + std::to_string(limits.sendBufferSize));
                break;
            default:
                pnp::fuzz::fail("output: unexpected message type");
        }
        if (h.type == tp::MessageType::Error) {
            try {
                auto err = tp::decodeError(b.data() + at + tp::kMessageHeaderSize,
                                           h.size - tp::kMessageHeaderSize);
                check(err.error.isBad(), "output: ERR with a good status");
                check(err.reason.size() <= tp::kMaxReasonLength, "output: ERR reason too long");
            } catch (const tp::TransportError& e) {
                pnp::fuzz::fail("output: ERR does not decode", e.what());
            }
        }
        at += h.size;
    }
}

// ---- the harness -------------------------------------------------------------------------
struct Harness;
Harness& harness();

// Requests in, responses out: every request is answered exactly once. Only a request still
// open when its channel closed may stay unanswered (an answer that comes later from another
// thread, e.g. a password check, finds the connection closed and is dropped).
class Accounting {
  public:
    void requested() { ++requests_; }
    void responded() {
        ++responses_;
        check(responses_ <= requests_, "more responses than requests");
    }
    // Called once the channel is closed, before anything answers later.
    void channelClosed() {
        if (!closed_) openAtClose_ = requests_ - responses_;
        closed_ = true;
    }
    void checkBalanced() const {
        check(requests_ - responses_ <= openAtClose_, "a request was not answered",
              std::to_string(requests_) + " requests, " + std::to_string(responses_) +
                  " responses, " + std::to_string(openAtClose_) + " open when the channel closed");
    }

  private:
    std::size_t requests_ = 0;
    std::size_t responses_ = 0;
    std::size_t openAtClose_ = 0;
    bool closed_ = false;
};

// Without a transport: the response is checked and kept.
class DirectConnection final : public tp::ServerConnection {
  public:
    UInt32 channelId() const override { return kChannelId; }
    const std::string& endpointUrl() const override { return url_; }
    std::string peerAddress() const override { return "127.0.0.1:40000"; }
    void send(UInt32, Buffer&& message) override {
        if (message.size() < tp::kSymmetricHeaderSize)
            throw std::invalid_argument("short response buffer");
        accounting.responded();
        checkResponse(message);
        last = std::move(message);
        lastFault = StatusCode{};
    }
    void sendServiceFault(UInt32, UInt32, StatusCode status) override {
        accounting.responded();
        if (verbose()) std::fprintf(stderr, "  ServiceFault %s\n", status.toString().c_str());
        check(status.isBad(), "ServiceFault with a good status");
        last.clear();
        lastFault = status;
    }
    void close() override { closed_ = true; }
    bool isClosed() const override { return closed_; }

    Accounting accounting;
    Buffer last;  // the last response (24 header bytes + type + body), empty after a fault
    StatusCode lastFault;

  private:
    std::string url_ = kUrl;
    bool closed_ = false;
};

// Behind a sans-I/O ServerChannel, like TcpServerConnection without the socket.
class ChannelConnection final : public tp::ServerConnection, private tp::ServerChannel::Hooks {
  public:
    ChannelConnection(const tp::ServerTransportConfig& config, tp::TimePoint now)
        : channel_(config, *this, now) {}

    tp::ServerChannel& channel() { return channel_; }

    UInt32 channelId() const override { return channel_.channelId(); }
    const std::string& endpointUrl() const override { return channel_.endpointUrl(); }
    std::string peerAddress() const override { return "127.0.0.1:40001"; }
    void send(UInt32 requestId, Buffer&& message) override {
        if (message.size() < tp::kSymmetricHeaderSize)
            throw std::invalid_argument("short response buffer");
        accounting.responded();
        checkResponse(message);
        channel_.send(requestId, std::move(message));
    }
    void sendServiceFault(UInt32 requestId, UInt32 requestHandle, StatusCode status) override {
        accounting.responded();
        if (verbose()) std::fprintf(stderr, "  ServiceFault %s\n", status.toString().c_str());
        check(status.isBad(), "ServiceFault with a good status");
        channel_.sendServiceFault(requestId, requestHandle, status);
    }
    void close() override { channel_.close(); }
    bool isClosed() const override { return channel_.isClosed(); }

    Accounting accounting;
    std::size_t written = 0;

  private:
    void write(Buffer&& bytes) override {
        if (verbose()) {
            std::fprintf(stderr, "  transport wrote %.3s, %zu bytes %s\n",
                         reinterpret_cast<const char*>(bytes.data()), bytes.size(),
                         channel_.isClosed() ? channel_.closeReason().c_str() : "");
        }
        checkOutput(bytes, channel_.limits(),
                    channel_.state() != tp::ServerChannel::State::AwaitHello);
        written += bytes.size();
        if (channel_.isClosed()) accounting.channelClosed();  // the ERR: noted when it leaves
    }
    void request(const tp::IncomingRequest& r) override;
    UInt32 newChannelId() override { return kChannelId; }

    tp::ServerChannel channel_;
};

struct Harness {
    Harness();

    // Hands a request to the server as the TcpServer would.
    void dispatch(const std::shared_ptr<tp::ServerConnection>& conn, tp::IncomingRequest r) {
        Buffer patched;
        if (r.typeId != NodeId(0, idOf<CloseSessionRequest>()) &&
            r.size >= placeholderEncoded.size() &&
            std::equal(placeholderEncoded.begin(), placeholderEncoded.end(), r.body)) {
            patched.assign(r.body, r.body + r.size);
            std::copy(tokenEncoded.begin(), tokenEncoded.end(), patched.begin());
            r.body = patched.data();
        }
        static_cast<tp::ServiceHandler&>(*server).onRequest(conn, r);
    }
    // Completes the method calls the Fuzz.Deferred handler kept, and answers what the server
    // answers later from another thread (a password is checked on its auth worker): the
    // transport is not started, so what that thread post()s is run here.
    void completeLater() {
        auto calls = std::move(deferred);
        deferred.clear();
        for (auto& done : calls) done.succeed({});
        check(server->runPostedWork(std::chrono::steady_clock::now() + std::chrono::seconds(5)),
              "the server's posted work did not finish within 5 s");
    }

    server::ServerConfig config;
    tp::ServerTransportConfig transport;
    std::unique_ptr<server::Server> server;
    std::unique_ptr<demo::DemoNamespace> demoNamespace;
    UInt16 ns = 0;
    NodeId authenticationToken;
    Buffer tokenEncoded;        // the session's token, encoded
    Buffer placeholderEncoded;  // placeholderToken(), encoded
    Buffer helloAndOpen;        // what mode 1 feeds before the input
    std::vector<server::MethodCompletion> deferred;
};

void ChannelConnection::request(const tp::IncomingRequest& r) {
    accounting.requested();
    if (verbose()) std::fprintf(stderr, "request %s\n", r.typeId.toString().c_str());
    harness().dispatch(shared_from_this(), r);
}

// ---- encoding helpers (harness set-up and seeds) -------------------------------------------
template <class Req>
Buffer requestBody(const Req& req) {
    Buffer b;
    BinaryEncoder e(b);
    encode(e, NodeId(0, idOf<Req>()));
    encode(e, req);
    return b;
}

RequestHeader header(UInt32 handle, NodeId token = placeholderToken()) {
    RequestHeader h;
    h.authenticationToken = std::move(token);
    h.timestamp = DateTime{133'000'000'000'000'000LL};
    h.requestHandle = handle;
    h.timeoutHint = 10'000;
    return h;
}

Buffer helloMessage(UInt32 bufferSize = 8192, UInt32 maxMessage = 0, UInt32 maxChunks = 0) {
    tp::Hello h;
    h.receiveBufferSize = bufferSize;
    h.sendBufferSize = bufferSize;
    h.maxMessageSize = maxMessage;
    h.maxChunkCount = maxChunks;
    h.endpointUrl = kUrl;
    return tp::encodeMessage(h);
}

Buffer openChunk(UInt32 channelId, UInt32 seq, UInt32 requestId, SecurityTokenRequestType type,
                 UInt32 lifetimeMs = 600'000) {
    OpenSecureChannelRequest req;
    req.requestHeader = header(requestId, NodeId());
    req.clientProtocolVersion = 0;
    req.requestType = type;
    req.securityMode = MessageSecurityMode::None;
    req.requestedLifetime = lifetimeMs;
    Buffer body = requestBody(req);
    return tp::makeOpenChunk(channelId, seq, requestId, body.data(), body.size());
}

// A request (type NodeId + body) as MSG chunks of at most maxChunk bytes on channel 1,
// token 1.
Buffer msgChunks(const Buffer& typeAndBody, UInt32 requestId, tp::SequenceGenerator& seq,
                 std::size_t maxChunk = 8192, tp::MessageType type = tp::MessageType::Message,
                 UInt32 tokenId = 1) {
    Buffer m = tp::newMessageBuffer();
    m.insert(m.end(), typeAndBody.begin(), typeAndBody.end());
    tp::writeSymmetricChunks(m, type, kChannelId, tokenId, requestId, seq, maxChunk);
    return m;
}

using pnp::fuzz::append;

Harness::Harness() {
    config.host = "127.0.0.1";
    config.publicHost = "fuzz.invalid";
    config.port = 0;
    config.applicationUri = "urn:pnp:fuzz";
    config.accessControl = std::make_shared<server::DefaultAccessControl>(
        true, std::map<std::string, std::string>{{"operator", "secret"}});
    config.limits.maxNodesPerRead = 64;
    config.limits.maxNodesPerWrite = 64;
    config.limits.maxNodesPerBrowse = 64;
    config.limits.maxNodesPerMethodCall = 16;
    config.limits.maxNodesPerTranslateBrowsePathsToNodeIds = 64;
    config.limits.maxNodesPerRegisterNodes = 64;
    config.maxSessions = 20;
    server = std::make_unique<server::Server>(config);

    // The demo namespace: a variable of every built-in type (scalar and array), Echo, Add,
    // Sleep. No Sleep may wait (maxPendingSleeps 0): everything stays on this thread.
    demo::DemoOptions demoOptions;
    demoOptions.maxPendingSleeps = 0;
    demoNamespace = std::make_unique<demo::DemoNamespace>(*server, demoOptions);
    ns = demoNamespace->namespaceIndex();
    auto& as = server->addressSpace();
    // A method completed after the request returned (at the end of the input), and one whose
    // completion is dropped (the address space answers BadInternalError).
    as.addMethod(NodeId(ns, "Demo"), NodeId(ns, "Fuzz.Deferred"), QualifiedName{ns, "Deferred"}, {},
                 {},
                 [this](const server::MethodCallContext&, std::vector<Variant>,
                        server::MethodCompletion done) { deferred.push_back(std::move(done)); });
    as.addMethod(
        NodeId(ns, "Demo"), NodeId(ns, "Fuzz.Forget"), QualifiedName{ns, "Forget"}, {}, {},
        [](const server::MethodCallContext&, std::vector<Variant>, server::MethodCompletion) {});

    // The transport settings of the fake connections: small buffers and limits, so that
    // the fuzzer reaches chunking and the limits with small inputs.
    transport.receiveBufferSize = 8192;
    transport.sendBufferSize = 8192;
    transport.maxMessageSize = 64 * 1024;
    transport.maxChunkCount = 0;
    transport.helloTimeout = std::chrono::milliseconds(1000);
    transport.minTokenLifetime = std::chrono::milliseconds(1000);

    check(findCodecByEncodingId(idOf<ServiceFault>()) != nullptr, "no ServiceFault codec");

    // The harness' own session, activated on channel kChannelId.
    auto conn = std::make_shared<DirectConnection>();
    CreateSessionRequest create;
    create.requestHeader = header(1, NodeId());
    create.endpointUrl = kUrl;
    create.sessionName = "fuzz";
    create.requestedSessionTimeout = 3'600'000;
    Buffer b = requestBody(create);
    {
        BinaryDecoder d(b.data(), b.size());
        tp::IncomingRequest r;
        r.requestId = 1;
        decode(d, r.typeId);
        r.body = d.position();
        r.size = d.remaining();
        conn->accounting.requested();
        static_cast<tp::ServiceHandler&>(*server).onRequest(conn, r);
    }
    check(!conn->last.empty(), "CreateSession failed");
    {
        BinaryDecoder d(conn->last.data() + tp::kSymmetricHeaderSize,
                        conn->last.size() - tp::kSymmetricHeaderSize);
        NodeId type;
        decode(d, type);
        CreateSessionResponse resp;
        decode(d, resp);
        authenticationToken = resp.authenticationToken;
    }
    ActivateSessionRequest activate;
    activate.requestHeader = header(2, authenticationToken);
    activate.userIdentityToken = toExtensionObject(AnonymousIdentityToken{"anonymous"});
    b = requestBody(activate);
    {
        BinaryDecoder d(b.data(), b.size());
        tp::IncomingRequest r;
        r.requestId = 2;
        decode(d, r.typeId);
        r.body = d.position();
        r.size = d.remaining();
        conn->accounting.requested();
        static_cast<tp::ServiceHandler&>(*server).onRequest(conn, r);
    }
    check(!conn->last.empty(), "ActivateSession failed");
    tokenEncoded = encodeToBuffer(authenticationToken);
    placeholderEncoded = encodeToBuffer(placeholderToken());
    check(tokenEncoded.size() == placeholderEncoded.size(),
          "the placeholder token must have the size of a real one");

    helloAndOpen = helloMessage();
    append(helloAndOpen, openChunk(0, 1, 1, SecurityTokenRequestType::Issue));
}

Harness& harness() {
    // Never destroyed: the server lives until the process exits.
    static Harness* h = new Harness();
    return *h;
}

// ---- seeds ---------------------------------------------------------------------------------
struct SeedRequests {
    std::vector<std::pair<std::string, Buffer>> list;  // name, type NodeId + body
    template <class Req>
    void add(std::string name, const Req& req) {
        list.emplace_back(std::move(name), requestBody(req));
    }
};

SeedRequests seedRequests(UInt16 ns) {
    SeedRequests s;
    UInt32 handle = 100;
    auto hdr = [&] { return header(handle++); };

    GetEndpointsRequest ge;
    ge.requestHeader = hdr();
    ge.endpointUrl = kUrl;
    ge.profileUris = {"http://opcfoundation.org/UA-Profile/Transport/uatcp-uasc-uabinary"};
    s.add("getendpoints", ge);

    FindServersRequest fs;
    fs.requestHeader = hdr();
    fs.serverUris = {"urn:pnp:fuzz"};
    s.add("findservers", fs);

    CreateSessionRequest cs;
    cs.requestHeader = header(handle++, NodeId());
    cs.clientDescription.applicationUri = "urn:fuzz:client";
    cs.clientDescription.applicationType = ApplicationType::Client;
    cs.endpointUrl = kUrl;
    cs.sessionName = "seed";
    cs.clientNonce = ByteString(std::string(32, 'n'));
    cs.requestedSessionTimeout = 60'000;
    cs.maxResponseMessageSize = 1 << 20;
    s.add("createsession", cs);

    ActivateSessionRequest as;
    as.requestHeader = hdr();
    as.localeIds = {"en"};
    as.userIdentityToken = toExtensionObject(AnonymousIdentityToken{"anonymous"});
    s.add("activatesession-anonymous", as);
    UserNameIdentityToken user;
    user.policyId = "username";
    user.userName = "operator";
    user.password = ByteString(std::string("secret"));
    as.userIdentityToken = toExtensionObject(user);
    s.add("activatesession-user", as);

    CloseSessionRequest cl;
    cl.requestHeader = hdr();
    cl.deleteSubscriptions = true;
    s.add("closesession", cl);

    ReadRequest rd;
    rd.requestHeader = hdr();
    rd.timestampsToReturn = TimestampsToReturn::Both;
    for (UInt32 attr : {1u, 2u, 3u, 4u, 5u, 13u, 14u, 15u, 16u, 17u, 18u, 20u, 27u}) {
        ReadValueId r;
        r.nodeId = NodeId(ns, "Scalar.Int32");
        r.attributeId = attr;
        rd.nodesToRead.push_back(r);
    }
    {
        ReadValueId r;
        r.nodeId = NodeId(0, ns0::Server_ServerStatus);
        r.attributeId = 13;
        rd.nodesToRead.push_back(r);
        r.nodeId = NodeId(ns, "Array.Double");
        r.indexRange = "0:1";
        rd.nodesToRead.push_back(r);
        r.nodeId = NodeId(ns, "Scalar.String");
        r.indexRange = "1:3";
        rd.nodesToRead.push_back(r);
        r.nodeId = NodeId(0, ns0::Server_NamespaceArray);
        r.indexRange = "";
        r.dataEncoding = QualifiedName{0, "Default Binary"};
        rd.nodesToRead.push_back(r);
    }
    s.add("read", rd);

    WriteRequest wr;
    wr.requestHeader = hdr();
    auto write = [&](std::string id, Variant v, std::string range = {}) {
        WriteValue w;
        w.nodeId = NodeId(ns, std::move(id));
        w.attributeId = 13;
        w.indexRange = std::move(range);
        w.value = DataValue(std::move(v));
        w.value.sourceTimestamp = DateTime{133'000'000'000'000'000LL};
        wr.nodesToWrite.push_back(std::move(w));
    };
    write("Scalar.Int32", Int32{42});
    write("Scalar.Double", Double{3.5});
    write("Scalar.String", String("hello"));
    write("Scalar.LocalizedText", LocalizedText("en", "text"));
    write("Scalar.QualifiedName", QualifiedName{1, "name"});
    write("Scalar.NodeId", NodeId(2, "node"));
    write("Scalar.ExpandedNodeId", ExpandedNodeId(NodeId(0, 85), "urn:x", 1));
    write("Scalar.Guid", Guid{1, 2, 3, {4, 5, 6, 7, 8, 9, 10, 11}});
    write("Scalar.ByteString", ByteString(std::string("\x01\x02\x03")));
    Range range;
    range.low = 1;
    range.high = 2;
    write("Scalar.ExtensionObject", toExtensionObject(range));
    DataValue inner(Variant(Int16{7}));
    inner.status = StatusCode(status::BadOutOfRange);
    write("Scalar.DataValue", inner);
    DiagnosticInfo di;
    di.symbolicId = 1;
    di.additionalInfo = "info";
    di.innerStatusCode = StatusCode(status::BadInternalError);
    write("Scalar.DiagnosticInfo", di);
    write("Scalar.Variant", Variant(std::vector<Variant>{Int32{1}, String("x")}));
    write("Array.Int32", Variant(std::vector<Int32>{1, 2, 3, 4}));
    write("Array.Int32", Variant(std::vector<Int32>{9, 9}), "1:2");
    {
        Variant matrix(std::vector<Double>{1, 2, 3, 4, 5, 6});
        matrix.setArrayDimensions({2, 3});
        write("Array.Double", matrix);
    }
    write("Array.String", Variant(std::vector<String>{"a", "b"}));
    write("Array.Variant", Variant(std::vector<Variant>{Variant(std::vector<Byte>{1, 2})}));
    {
        WriteValue w;
        w.nodeId = NodeId(ns, "Scalar.Int32");
        w.attributeId = 4;  // DisplayName: not writable
        w.value = DataValue(Variant(LocalizedText("", "x")));
        wr.nodesToWrite.push_back(w);
    }
    s.add("write", wr);

    BrowseRequest br;
    br.requestHeader = hdr();
    br.requestedMaxReferencesPerNode = 3;
    for (NodeId id : {NodeId(0, ns0::ObjectsFolder), NodeId(ns, "Demo"), NodeId(0, ns0::Server)}) {
        BrowseDescription d;
        d.nodeId = id;
        d.browseDirection = BrowseDirection::Both;
        d.referenceTypeId = NodeId(0, ns0::HierarchicalReferences);
        d.includeSubtypes = true;
        d.resultMask = 0x3F;
        br.nodesToBrowse.push_back(d);
    }
    s.add("browse", br);

    BrowseNextRequest bn;
    bn.requestHeader = hdr();
    bn.continuationPoints = {ByteString(std::string(16, '\1'))};
    s.add("browsenext", bn);

    TranslateBrowsePathsToNodeIdsRequest tr;
    tr.requestHeader = hdr();
    {
        BrowsePath p;
        p.startingNode = NodeId(0, ns0::RootFolder);
        for (auto name : {"Objects", "Server", "ServerStatus", "State"}) {
            RelativePathElement e;
            e.referenceTypeId = NodeId(0, ns0::HierarchicalReferences);
            e.includeSubtypes = true;
            e.targetName = QualifiedName{0, name};
            p.relativePath.elements.push_back(e);
        }
        tr.browsePaths.push_back(p);
        p.startingNode = NodeId(0, ns0::ObjectsFolder);
        p.relativePath.elements.resize(1);
        p.relativePath.elements[0].targetName = QualifiedName{ns, "Demo"};
        tr.browsePaths.push_back(p);
    }
    s.add("translate", tr);

    RegisterNodesRequest rn;
    rn.requestHeader = hdr();
    rn.nodesToRegister = {NodeId(ns, "Scalar.Int32"), NodeId(0, 2256)};
    s.add("registernodes", rn);

    UnregisterNodesRequest un;
    un.requestHeader = hdr();
    un.nodesToUnregister = {NodeId(ns, "Scalar.Int32")};
    s.add("unregisternodes", un);

    CallRequest call;
    call.requestHeader = hdr();
    auto method = [&](const char* id, std::vector<Variant> in) {
        CallMethodRequest m;
        m.objectId = NodeId(ns, "Demo");
        m.methodId = NodeId(ns, id);
        m.inputArguments = std::move(in);
        call.methodsToCall.push_back(std::move(m));
    };
    method("Demo.Add", {Int32{2}, Int32{3}});
    method("Demo.Echo", {ByteString(std::string("echo"))});
    method("Demo.Sleep", {UInt32{1}});
    method("Fuzz.Deferred", {});
    method("Fuzz.Forget", {});
    s.add("call", call);
    call.methodsToCall.resize(1);
    call.methodsToCall[0].inputArguments = {String("wrong type"), Int32{1}, Int32{2}};
    s.add("call-badargs", call);

    AddNodesRequest an;
    an.requestHeader = hdr();
    an.nodesToAdd.resize(1);
    s.add("addnodes-unsupported", an);
    return s;
}

// Strips the encoding NodeId and the RequestHeader.
Buffer bodyAfterHeader(const Buffer& typeAndBody) {
    BinaryDecoder d(typeAndBody.data(), typeAndBody.size());
    NodeId type;
    decode(d, type);
    RequestHeader h;
    decode(d, h);
    return Buffer(d.position(), d.position() + d.remaining());
}
Buffer bodyWithHeader(const Buffer& typeAndBody, NodeId* type) {
    BinaryDecoder d(typeAndBody.data(), typeAndBody.size());
    decode(d, *type);
    return Buffer(d.position(), d.position() + d.remaining());
}

void makeSeeds(pnp::fuzz::SeedWriter& w) {
    Harness& h = harness();
    SeedRequests reqs = seedRequests(h.ns);

    // Modes 2 and 3: one seed per request.
    for (const auto& [name, typeAndBody] : reqs.list) {
        NodeId type;
        Buffer body = bodyWithHeader(typeAndBody, &type);
        auto index = static_cast<Byte>(serviceIndex(type.numeric()));
        w.add("service-" + name, kServiceBody, index, bodyAfterHeader(typeAndBody));
        w.add("raw-" + name, kServiceRaw, index, body);
    }

    // Mode 1: MSG chunks on the open channel.
    {
        tp::SequenceGenerator seq(2);
        UInt32 requestId = 2;
        Buffer all;
        for (const auto& [name, typeAndBody] : reqs.list) {
            tp::SequenceGenerator one(2);
            w.add("open-" + name, kOpenStream, msgChunks(typeAndBody, 2, one));
            if (name != "closesession") append(all, msgChunks(typeAndBody, requestId++, seq));
        }
        w.add("open-all", kOpenStream, all);
        // The Write request in chunks of 300 bytes (the server takes at most 10 chunks).
        for (const auto& [name, typeAndBody] : reqs.list) {
            if (name != "write") continue;
            tp::SequenceGenerator s(2);
            w.add("open-write-chunked", kOpenStream, msgChunks(typeAndBody, 9, s, 300));
            // An abort chunk after two intermediate ones, then the request again.
            tp::SequenceGenerator s2(2);
            Buffer m = msgChunks(typeAndBody, 9, s2, 300);
            Buffer abortThenAgain(m.begin(), m.begin() + 600);
            Buffer abortChunk = tp::newMessageBuffer();
            BinaryEncoder e(abortChunk);
            e.number<UInt32>(status::BadRequestCancelledByClient.value);
            e.lengthPrefixed("cancelled");
            tp::SequenceGenerator s3(4);
            tp::writeSymmetricChunks(abortChunk, tp::MessageType::Message, kChannelId, 1, 9, s3,
                                     8192);
            abortChunk[3] = 'A';
            append(abortThenAgain, abortChunk);
            tp::SequenceGenerator s4(5);
            append(abortThenAgain, msgChunks(typeAndBody, 10, s4, 300));
            w.add("open-abort", kOpenStream, abortThenAgain);
        }
        // Renew, then a request with the new token, then CLO.
        tp::SequenceGenerator s(2);
        Buffer renew = openChunk(kChannelId, 2, 3, SecurityTokenRequestType::Renew, 5000);
        s.next();
        Buffer read;
        for (const auto& [name, typeAndBody] : reqs.list)
            if (name == "read") read = typeAndBody;
        Buffer m = tp::newMessageBuffer();
        m.insert(m.end(), read.begin(), read.end());
        tp::writeSymmetricChunks(m, tp::MessageType::Message, kChannelId, 2, 4, s, 8192);
        append(renew, m);
        CloseSecureChannelRequest clo;
        clo.requestHeader = header(0, NodeId());
        append(renew,
               msgChunks(requestBody(clo), 5, s, 8192, tp::MessageType::CloseSecureChannel, 2));
        w.add("open-renew-read-close", kOpenStream, renew);
    }

    // Mode 0: whole connections.
    {
        w.add("stream-hello", kStream, helloMessage());
        w.add("stream-hello-small-limits", kStream, helloMessage(8192, 8192, 1));
        Buffer b = helloMessage(8192, 16384, 2);
        append(b, openChunk(0, 1, 1, SecurityTokenRequestType::Issue));
        tp::SequenceGenerator seq(2);
        UInt32 requestId = 2;
        for (const auto& [name, typeAndBody] : reqs.list) {
            if (name == "read" || name == "browse" || name == "call" || name == "write" ||
                name == "getendpoints")
                append(b, msgChunks(typeAndBody, requestId++, seq));
        }
        CloseSecureChannelRequest clo;
        clo.requestHeader = header(0, NodeId());
        append(b, msgChunks(requestBody(clo), requestId, seq, 8192,
                            tp::MessageType::CloseSecureChannel));
        w.add("stream-session", kStream, b);
        Buffer rhe = tp::encodeMessage(tp::ReverseHello{"urn:x", kUrl});
        w.add("stream-reversehello", kStream, rhe);
        Buffer open = helloMessage();
        append(open, openChunk(0, 1, 1, SecurityTokenRequestType::Issue));
        w.add("stream-open", kStream, open);
    }
}

// ---- one input -------------------------------------------------------------------------------
void runStream(Harness& h, const Byte* data, std::size_t size, bool preopen) {
    const auto now = tp::Clock::now();
    auto conn = std::make_shared<ChannelConnection>(h.transport, now);
    if (preopen) {
        conn->channel().feed(h.helloAndOpen.data(), h.helloAndOpen.size(), now);
        check(conn->channel().state() == tp::ServerChannel::State::Open, "pre-open failed");
    }
    // Two reads, split where the data says, so that chunks also arrive in pieces.
    std::size_t split = size > 0 ? data[0] % (size + 1) : 0;
    // A close without an ERR (CloseSecureChannel) is noted after the feed: nothing answers
    // later while the input is fed (deferred calls and posted work run only afterwards).
    conn->channel().feed(data, split, now);
    if (conn->isClosed()) conn->accounting.channelClosed();
    conn->channel().feed(data + split, size - split, now);
    if (conn->isClosed()) conn->accounting.channelClosed();
    h.completeLater();
    conn->accounting.checkBalanced();
    // Timeouts: hello timeout, token expiry.
    conn->channel().tick(now + std::chrono::hours(2));
    check(conn->channel().isClosed(), "channel survives its token / hello timeout");
    conn->close();
}

void runService(Harness& h, const Byte* data, std::size_t size, bool withHeader) {
    if (size < 1) return;
    const UInt32 type = kServices[data[0] % kServiceCount];
    ++data;
    --size;
    auto conn = std::make_shared<DirectConnection>();
    Buffer body;
    if (!withHeader) {
        body = encodeToBuffer(header(77, h.authenticationToken));
        body.insert(body.end(), data, data + size);
    } else {
        body.assign(data, data + size);
    }
    tp::IncomingRequest r;
    r.requestId = 5;
    r.typeId = NodeId(0, type);
    r.body = body.data();
    r.size = body.size();
    if (verbose()) std::fprintf(stderr, "request %s\n", r.typeId.toString().c_str());
    conn->accounting.requested();
    h.dispatch(conn, r);
    h.completeLater();
    conn->accounting.checkBalanced();
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int* argc, char*** argv) {
    pnp::fuzz::handleSeedFlag(argc, argv, makeSeeds);
    harness();
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    if (size < 1) return 0;
    Harness& h = harness();
    switch (data[0] % 4) {
        case kStream:
            runStream(h, data + 1, size - 1, false);
            break;
        case kOpenStream:
            runStream(h, data + 1, size - 1, true);
            break;
        case kServiceBody:
            runService(h, data + 1, size - 1, false);
            break;
        case kServiceRaw:
            runService(h, data + 1, size - 1, true);
            break;
    }
    return 0;
}
