// The protocol state machines of one opc.tcp connection, without any I/O (sans-I/O):
// ServerChannel (HEL -> ACK, OPN issue / renew, MSG, CLO) and ClientChannel (the other
// side). TcpServer and ClientConnection feed them the bytes read from their sockets and
// write what they produce; tests connect the two in memory.
//
// SecurityPolicy None (OPC 10000-6 §6.7.2.3: asymmetric header with empty certificate and
// thumbprint) and the RSA policies with Sign / SignAndEncrypt (ChannelSecurity, when the
// configuration has a ServerSecurityConfig / ClientSecurityConfig).
#pragma once

#include <algorithm>
#include <chrono>
#include <cstring>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <utility>

#include "ua/transport/channel_security.hpp"
#include "ua/transport/chunks.hpp"

namespace pnp::ua::transport {

// A request handed to the upper layer. body / size are the encoded request after its type
// NodeId; the pointer is valid only during the call. When block is set the body lies in it
// (the receive buffer): a decoder may keep references to it (BinaryDecoder::shareFrom).
struct IncomingRequest {
    UInt32 requestId = 0;
    NodeId typeId;  // the binary encoding id of the request, e.g. i=631 ReadRequest
    const Byte* body = nullptr;
    std::size_t size = 0;
    ByteBlock* block = nullptr;
};

// A response handed to the client. For a response the server aborted with an abort chunk
// (OPC 10000-6 §6.7.3) status is the abort chunk's Error, typeId is null and body empty;
// otherwise status is Good.
// The bytes of a received message body: a slice of a buffer it owns, so a large body can
// stay where it was received (no copy) and a multi-chunk one where it was assembled; or a
// view of the receive buffer (ClientChannel::setViewBodies), valid until that buffer is
// read into again: own() copies it out.
class MessageBody {
  public:
    MessageBody() = default;
    explicit MessageBody(Buffer bytes) : storage_(std::move(bytes)), size_(storage_.size()) {}
    MessageBody(Buffer storage, std::size_t offset, std::size_t size)
        : storage_(std::move(storage)), offset_(offset), size_(size) {}
    // A copy of n bytes at p.
    MessageBody(const Byte* p, std::size_t n) : storage_(n), size_(n) {
        if (n != 0) std::memcpy(storage_.data(), p, n);
    }
    // A view of n bytes at p (not copied), which lie in `block`.
    static MessageBody viewOf(const Byte* p, std::size_t n, ByteBlock* block) {
        MessageBody b;
        b.view_ = p;
        b.block_ = block;
        b.size_ = n;
        return b;
    }
    MessageBody(MessageBody&& o) noexcept
        : storage_(std::move(o.storage_)),
          view_(std::exchange(o.view_, nullptr)),
          block_(std::exchange(o.block_, nullptr)),
          offset_(std::exchange(o.offset_, 0)),
          size_(std::exchange(o.size_, 0)) {}
    MessageBody& operator=(MessageBody&& o) noexcept {
        if (this != &o) {
            storage_ = std::move(o.storage_);
            view_ = std::exchange(o.view_, nullptr);
            block_ = std::exchange(o.block_, nullptr);
            offset_ = std::exchange(o.offset_, 0);
            size_ = std::exchange(o.size_, 0);
        }
        return *this;
    }
    // A copy owns its bytes.
    MessageBody(const MessageBody& o) : MessageBody(o.data(), o.size()) {}
    MessageBody& operator=(const MessageBody& o) {
        if (this != &o) *this = MessageBody(o);
        return *this;
    }

    const Byte* data() const { return view_ != nullptr ? view_ : storage_.data() + offset_; }
    std::size_t size() const { return size_; }
    bool empty() const { return size_ == 0; }
    const Byte* begin() const { return data(); }
    const Byte* end() const { return data() + size_; }
    // True while the bytes are a view of a buffer owned elsewhere.
    bool isView() const { return view_ != nullptr; }
    // The block a view lies in (a decoder may keep references to it, see
    // BinaryDecoder::shareFrom); null when the body owns its bytes.
    ByteBlock* block() const { return block_; }
    // Makes the body own its bytes (copies a view; no-op otherwise).
    void own() {
        if (view_ == nullptr) return;
        *this = MessageBody(view_, size_);
    }
    friend bool operator==(const MessageBody& a, const Buffer& b) {
        return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin());
    }

  private:
    Buffer storage_;
    const Byte* view_ = nullptr;
    ByteBlock* block_ = nullptr;
    std::size_t offset_ = 0;
    std::size_t size_ = 0;
};

struct IncomingResponse {
    UInt32 requestId = 0;
    NodeId typeId;     // the binary encoding id of the response, e.g. i=634 ReadResponse
    MessageBody body;  // the encoded response after its type NodeId
    StatusCode status;
};

// Transport settings of a server. The limits (TransportLimits) are announced in the
// Acknowledge and enforced on every connection.
struct ServerTransportConfig : TransportLimits {
    std::string host = "0.0.0.0";  // listen address (name or literal), "::" for IPv6
    UInt16 port = 4840;            // 0: ephemeral, see TcpServer::port()
    // Connections beyond this are refused with an ERR BadTcpServerTooBusy. Worst-case
    // memory is about maxConnections * (maxMessageSize + receiveBufferSize + 4 MiB).
    std::size_t maxConnections = 1000;
    // Threads doing the connections' I/O (epoll loops; a new connection goes to the loop
    // with the fewest). 0: one per core (at most 4), and up to one more per core, started
    // once every loop serves 8 connections.
    std::size_t eventLoops = 0;
    // All connections together hold at most this many bytes of partially received
    // (multi-chunk) messages; a chunk beyond it ends its connection with ERR
    // BadTcpNotEnoughResources (see MemoryBudget).
    std::size_t maxIncompleteMessageBytes = 256u << 20;
    // A connection that has not completed HEL/ACK and OpenSecureChannel within this time is
    // closed (ERR BadTimeout).
    std::chrono::milliseconds helloTimeout{10'000};
    // A connection that received no byte for this long is closed (ERR BadTimeout).
    // 0: never (token expiry still closes channels whose client vanished).
    std::chrono::milliseconds idleTimeout{0};
    // The revised token lifetime is the requested one clamped to [min, max].
    std::chrono::milliseconds minTokenLifetime{10'000};
    std::chrono::milliseconds maxTokenLifetime{3'600'000};
    // Secured channels (certificate, policies, trust); null: SecurityPolicy None only.
    std::shared_ptr<const ServerSecurityConfig> security;
};

// Transport settings of a client. The limits (TransportLimits) are announced in the Hello
// and enforced on what the client receives.
struct ClientConfig : TransportLimits {
    // RequestedLifetime of the OpenSecureChannel requests; renewed at 75 %.
    std::chrono::milliseconds requestedLifetime{600'000};
    // Deadline of ClientConnection::send() when none is given (a server that stops reading).
    std::chrono::milliseconds sendTimeout{10'000};
    // A secured channel (policy, mode, certificates); null: SecurityPolicy None.
    std::shared_ptr<const ClientSecurityConfig> security;
};

// A SecurityToken as both sides track it. Usable until created + lifetime * 1.25: the 25 %
// tolerance Part 4 §5.5.2.1 asks of clients, also applied by the server to cover network
// latency and timer jitter of clients that renew at 75 %.
struct TokenState {
    UInt32 tokenId = 0;
    TimePoint created{};
    std::chrono::milliseconds lifetime{0};
    TimePoint usableUntil() const { return created + lifetime + lifetime / 4; }
    bool usable(TimePoint now) const { return now <= usableUntil(); }
};

// ---------------------------------------------------------------------------------------
class ServerChannel {
  public:
    // Implemented by the I/O layer. Called synchronously from received(), send(), tick().
    class Hooks {
      public:
        // Bytes to write: one or more complete chunks, in order.
        virtual void write(Buffer&& bytes) = 0;
        // One chunk whose spliced byte runs are written from where they are; keepAlive holds
        // them until then. By default joined and written with write().
        virtual void writeSpliced(Buffer&& bytes, Splices&& splices,
                                  std::shared_ptr<const void> /*keepAlive*/) {
            write(joinSplices(std::move(bytes), splices));
        }
        // A complete MSG. The I/O layer hands it to the ServiceHandler. Exceptions escaping
        // it close the connection with ERR BadTcpInternalError.
        virtual void request(const IncomingRequest& request) = 0;
        // A server-wide unique secure channel id (never 0).
        virtual UInt32 newChannelId() = 0;

      protected:
        ~Hooks() = default;
    };

    enum class State { AwaitHello, AwaitOpen, Open, Closed };

    // `budget`: shared by the server's channels for partially received messages (may be
    // null: no server-wide limit); it must outlive the channel.
    ServerChannel(const ServerTransportConfig& config, Hooks& hooks, TimePoint now,
                  MemoryBudget* budget = nullptr);

    // Input: read into readSpace(), then received(n). feed() copies (tests).
    std::span<Byte> readSpace() { return reader_.readSpace(); }
    void received(std::size_t n, TimePoint now);
    void feed(const Byte* p, std::size_t n, TimePoint now);

    // Sends a response built in a newMessageBuffer(): fills the headers in place, or splits
    // it into chunks. A response larger than the client's MaxMessageSize / MaxChunkCount is
    // replaced by a ServiceFault BadResponseTooLarge (its RequestHandle is read from the
    // response's ResponseHeader). Against MaxMessageSize we count the body plus the chunk
    // headers: the spec counts the body, some stacks the whole chunks; this satisfies both.
    // False when the channel is not open (message dropped).
    bool send(UInt32 requestId, Buffer&& message);
    // The same for a message encoded with Splices (large byte runs referenced, not copied);
    // keepAlive holds the referenced bytes until they are written.
    bool send(UInt32 requestId, Buffer&& message, Splices&& splices,
              std::shared_ptr<const void> keepAlive);
    bool sendServiceFault(UInt32 requestId, UInt32 requestHandle, StatusCode status);

    // Timeouts: HEL/OPN not completed in time, idle connection, token expired.
    void tick(TimePoint now);
    // Closes without an ERR message (CLO received, server shutdown).
    void close();
    // Sends ERR `status` and closes.
    void fail(StatusCode status, const std::string& reason);
    // The connection is gone: gives back what an incomplete message held of the budget
    // passed to the constructor, and stops using it.
    void leaveBudget() { assembler_.leaveBudget(); }

    State state() const { return state_; }
    bool isClosed() const { return state_ == State::Closed; }
    // Why the channel closed: Good after CLO / close(), else the status of the ERR sent.
    StatusCode closeStatus() const { return closeStatus_; }
    const std::string& closeReason() const { return closeReason_; }
    UInt32 channelId() const { return channelId_; }
    const std::string& endpointUrl() const { return endpointUrl_; }
    const NegotiatedLimits& limits() const { return limits_; }
    UInt32 currentTokenId() const { return current_.tokenId; }
    // The channel's security: null for SecurityPolicy None.
    const ChannelSecurity* security() const { return security_.get(); }
    std::string_view securityPolicyUri() const;
    MessageSecurityMode securityMode() const;

  private:
    // send(); `isFault`: the message is the ServiceFault replacing a response too large.
    bool sendMessage(UInt32 requestId, Buffer&& message, bool isFault, Splices&& splices = {},
                     std::shared_ptr<const void> keepAlive = {});
    void handleChunk(const RawChunk& raw, TimePoint now);
    void handleHello(const RawChunk& raw);
    void handleSecureChunk(const RawChunk& raw, TimePoint now);
    // A secured OPN chunk: checks policy, receiver and sender, decrypts and verifies; then
    // the request is handled as any OPN.
    void handleSecuredOpen(const RawChunk& raw, TimePoint now);
    void handleOpen(UInt32 requestId, const Byte* body, std::size_t size, TimePoint now);
    std::size_t chunksFor(std::size_t body) const;
    void handleMessage(UInt32 requestId, const Byte* body, std::size_t size, ByteBlock* block);
    void checkToken(UInt32 tokenId, TimePoint now);
    void dropExpiredPrevious(TimePoint now);

    const ServerTransportConfig& config_;
    Hooks& hooks_;
    ChunkReader reader_;
    MessageAssembler assembler_;
    SequenceValidator receiveSequence_;
    SequenceGenerator sendSequence_;
    State state_ = State::AwaitHello;
    StatusCode closeStatus_;
    std::string closeReason_;
    TimePoint started_;
    TimePoint lastReceive_;
    NegotiatedLimits limits_;
    UInt32 helloVersion_ = 0;
    std::string endpointUrl_;
    UInt32 channelId_ = 0;
    UInt32 nextTokenId_ = 1;
    TokenState current_;
    std::optional<TokenState> previous_;  // after a renew, until the client uses the new one
    UInt32 sendTokenId_ = 0;              // the token our messages carry
    std::unique_ptr<ChannelSecurity> security_;
};

// ---------------------------------------------------------------------------------------
class ClientChannel {
  public:
    class Hooks {
      public:
        virtual void write(Buffer&& bytes) = 0;
        // One chunk whose spliced byte runs are written from where they are (before send()
        // returns). By default joined and written with write().
        virtual void writeSpliced(Buffer&& bytes, const Splices& splices) {
            write(joinSplices(std::move(bytes), splices));
        }
        // A complete MSG response, or an aborted one (IncomingResponse::status).
        virtual void response(IncomingResponse&& response) = 0;

      protected:
        ~Hooks() = default;
    };

    enum class State { Idle, AwaitAcknowledge, AwaitOpen, Open, Closed };

    ClientChannel(const ClientConfig& config, std::string endpointUrl, Hooks& hooks);

    // Writes the Hello. The OpenSecureChannel request follows by itself on the Acknowledge.
    void start(TimePoint now);

    // Input. Throws TransportError (the channel is then Closed): the server's ERR code, or
    // the status of a protocol violation by the server (a CLO is written first when the
    // channel was open).
    std::span<Byte> readSpace() { return reader_.readSpace(); }
    // A single-chunk response's body as a view of the receive buffer instead of a copy:
    // valid until the next readSpace() / received() / feed(). Off by default.
    void setViewBodies(bool on) { viewBodies_ = on; }
    void received(std::size_t n, TimePoint now);
    void feed(const Byte* p, std::size_t n, TimePoint now);

    // Sends a request built in a newMessageBuffer(); returns its request id. Throws
    // TransportError(BadRequestTooLarge) when it exceeds the server's limits (counted like
    // ServerChannel::send; nothing is written, the channel stays open),
    // BadSecureChannelClosed when the channel is not open.
    UInt32 send(Buffer&& message);
    // The same for a message encoded with Splices; the referenced bytes are written (or
    // copied) before it returns.
    UInt32 send(Buffer&& message, Splices&& splices);
    // Sends an OpenSecureChannel renew request when 75 % of the token lifetime has passed
    // and none is outstanding. True when one was written.
    bool renewIfDue(TimePoint now);
    TimePoint renewalDue() const;
    bool renewPending() const { return renewRequestId_ != 0; }
    // Writes a CLO when open; the channel is Closed afterwards.
    void close();

    State state() const { return state_; }
    bool isOpen() const { return state_ == State::Open; }
    UInt32 channelId() const { return channelId_; }
    UInt32 currentTokenId() const { return current_.tokenId; }
    std::chrono::milliseconds revisedLifetime() const { return current_.lifetime; }
    const NegotiatedLimits& limits() const { return limits_; }
    const ChannelSecurity* security() const { return security_.get(); }

  private:
    void handleChunk(const RawChunk& raw, TimePoint now);
    void handleSecureChunk(const RawChunk& raw, TimePoint now);
    void handleOpenResponse(UInt32 requestId, const Byte* body, std::size_t size, TimePoint now);
    std::size_t chunksFor(std::size_t body) const;
    void writeOpenRequest(bool renew, TimePoint now);
    void checkToken(UInt32 tokenId, TimePoint now);
    UInt32 nextRequestId();

    const ClientConfig config_;
    std::string endpointUrl_;
    Hooks& hooks_;
    ChunkReader reader_;
    MessageAssembler assembler_;
    SequenceValidator receiveSequence_;
    SequenceGenerator sendSequence_;
    State state_ = State::Idle;
    Hello hello_;
    NegotiatedLimits limits_;
    UInt32 channelId_ = 0;
    TokenState current_;
    std::optional<TokenState> previous_;
    UInt32 requestIdCounter_ = 0;
    UInt32 openRequestId_ = 0;   // outstanding Issue request
    UInt32 renewRequestId_ = 0;  // outstanding Renew request
    bool viewBodies_ = false;
    std::unique_ptr<ChannelSecurity> security_;
    crypto::Bytes clientNonce_;  // of the outstanding OpenSecureChannel request
};

}  // namespace pnp::ua::transport
