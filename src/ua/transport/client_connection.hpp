// The opc.tcp client transport: one TCP connection with its secure channel, driven from the
// caller's thread. No internal thread: a request and its response stay on one thread, which
// keeps latency lowest. The socket is non-blocking and every wait is a poll() bounded by a
// Deadline; TCP_NODELAY is set.
//
//   auto c = ClientConnection::connect("opc.tcp://host:4840/path", config,
//                                      Clock::now() + std::chrono::seconds(5));
//   Buffer b = ClientConnection::newMessageBuffer();
//   BinaryEncoder e(b);
//   encode(e, NodeId(0, DataTypeInfo<ReadRequest>::binaryEncodingId));
//   encode(e, request);
//   UInt32 id = c->send(std::move(b));
//   while (auto r = c->receive(deadline)) if (r->requestId == id) ...;   // nullopt: deadline
//
// Token renewal: send(), receive() and renewIfDue() send the OpenSecureChannel renew
// request once 75 % of the token lifetime has passed; its response is consumed inside
// receive() (or inside send() when it is already there). receive() wakes up for the renewal
// by itself while it waits. A caller that stays idle for long without calling any of them
// should call renewIfDue() at renewalDue() (poll nativeHandle() until then), else the server
// closes the channel once the token expired.
//
// Errors: every failure is a TransportError (see common.hpp for the status codes):
//   connect():  BadTcpEndpointUrlInvalid, BadCommunicationError (resolution, refused),
//               BadTimeout, the code of the server's ERR, BadProtocolVersionUnsupported, ...
//   send():     BadRequestTooLarge (connection stays usable), BadTimeout (the server did not
//               take the bytes in time: the connection is closed), BadConnectionClosed,
//               BadCommunicationError
//   receive():  returns nullopt when the deadline passes (connection still usable);
//               throws BadConnectionClosed when the server closed the connection, the ERR
//               code when it sent an ERR, a protocol violation's code.
// After any throw except BadRequestTooLarge, isOpen() is false and the object can only be
// destroyed.
//
// Not thread-safe: one thread at a time.
#pragma once

#include <sys/uio.h>

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ua/transport/secure_channel.hpp"

namespace pnp::ua::transport {

// opc.tcp://host[:port][/path]; host may be a name, an IPv4 address or [IPv6].
struct EndpointUrl {
    std::string host;
    UInt16 port = 4840;
    std::string path;  // "" or "/..."
};
// Throws TransportError(BadTcpEndpointUrlInvalid).
EndpointUrl parseEndpointUrl(const std::string& url);

class ClientConnection final : private ClientChannel::Hooks {
  public:
    // TCP connect (name resolution included; getaddrinfo itself is not bounded by the
    // deadline), HEL/ACK, OpenSecureChannel (Issue).
    static std::unique_ptr<ClientConnection> connect(const std::string& endpointUrl,
                                                     const ClientConfig& config, Deadline deadline);
    ~ClientConnection();  // close()
    ClientConnection(const ClientConnection&) = delete;
    ClientConnection& operator=(const ClientConnection&) = delete;

    static Buffer newMessageBuffer() { return transport::newMessageBuffer(); }
    // The same, reusing the memory of the last request sent when it is small enough.
    Buffer messageBuffer();

    // Sends a request (a newMessageBuffer() with type NodeId + body appended); returns the
    // request id assigned to it. The default deadline is now + config.sendTimeout.
    UInt32 send(Buffer&& message);
    UInt32 send(Buffer&& message, Deadline deadline);
    // A message encoded with Splices: the referenced bytes are written from where they are
    // (or copied when the message needs several chunks) before send() returns.
    UInt32 send(Buffer&& message, Splices&& splices, Deadline deadline);

    // The next response (any request id, in arrival order), nullopt when the deadline
    // passed first. Deadline in the past: only what is already there (non-blocking).
    // The body may be a view of the receive buffer (no copy): valid until the next call of
    // receive(), send(), drainAvailable() or close(); body.own() keeps it longer.
    std::optional<IncomingResponse> receive(Deadline deadline);

    // For an event loop that polled the socket: `readable` (poll reported POLLIN) reads once
    // without waiting, then the responses already received are handed out one per call. No
    // readiness check of its own: one system call per wake-up (poll is level-triggered, so
    // bytes left in the socket wake the loop again). Same body lifetime as receive().
    std::optional<IncomingResponse> receiveReady(bool readable);

    // Sends the renew request when due (see above). True when one was sent.
    bool renewIfDue();
    TimePoint renewalDue() const { return channel_.renewalDue(); }

    // Sends CloseSecureChannel (best effort) and closes the socket. Idempotent.
    void close();
    bool isOpen() const;

    // The socket, for poll()/epoll by the caller (readable: call receive()). -1 when closed.
    int nativeHandle() const { return fd_; }

    UInt32 channelId() const { return channel_.channelId(); }
    UInt32 tokenId() const { return channel_.currentTokenId(); }
    std::chrono::milliseconds revisedLifetime() const { return channel_.revisedLifetime(); }
    const NegotiatedLimits& limits() const { return channel_.limits(); }
    const std::string& endpointUrl() const { return url_; }

  private:
    ClientConnection(const std::string& url, const ClientConfig& config);
    void write(Buffer&& bytes) override;
    void writeSpliced(Buffer&& bytes, const Splices& splices) override;
    // Writes everything (blocking until writeDeadline_).
    void writeAll(::iovec* iov, std::size_t count);
    void keepForReuse(Buffer&& bytes);
    void response(IncomingResponse&& response) override;
    // Reads once (waiting until `deadline`) and feeds the channel. False on timeout.
    bool readOnce(Deadline deadline);
    void drainAvailable();
    void closeSocket();
    [[noreturn]] void failClosed(StatusCode status, const std::string& what);

    std::string url_;
    ClientConfig config_;
    ClientChannel channel_;
    int fd_ = -1;
    Deadline writeDeadline_{};
    // Responses received, not yet handed out: ready_[readyHead_ ...] (a vector: no
    // allocation per response once it has grown).
    std::vector<IncomingResponse> ready_;
    std::size_t readyHead_ = 0;
    Buffer spare_;  // the last request sent, kept for its memory (see messageBuffer())
    // SO_RCVTIMEO now set on the (blocking) socket; zero: none set yet.
    std::chrono::nanoseconds receiveTimeout_{0};
    // Blocking recv() for up to `left`: re-arms SO_RCVTIMEO only when the one set is off.
    long receiveBlocking(std::span<Byte> space, std::chrono::nanoseconds left);
};

}  // namespace pnp::ua::transport
