// The opc.tcp server transport: accepts TCP connections, runs HEL/ACK and the secure
// channel (OpenSecureChannel issue / renew, CloseSecureChannel) by itself and hands every
// MSG request to a ServiceHandler.
//
// Threading: connections are spread over a few event loops (ServerTransportConfig::
// eventLoops; by default one per core, and one more per core once every loop serves 8
// connections), each a thread with an epoll set: it reads what its
// ready connections received and hands all of it to the protocol under one acquisition of
// the network lock, so with many busy clients one wake-up serves many requests and the
// cost per request does not grow with the number of clients. A service thread (asio)
// accepts and runs the timers and post()ed functions. Protocol and upper layer are
// serialised by one lock, the network lock: every callback (ServiceHandler, post(),
// setTick()) runs while its thread holds it, and "the network thread" below means "the
// thread holding the network lock" (isNetworkThread()). ServerConnection::send() / close()
// may be called from any thread; under the network lock they act immediately. Elsewhere
// send() writes at once when the lock is free (a try-lock, never a wait) and nothing of the
// connection is queued; otherwise, and for close(), they are posted to the service thread.
// Responses are written without blocking by the thread that releases the lock; what the
// socket does not take is written by the connection's loop when the socket has room.
//
// Usage:
//   class Handler : public ServiceHandler {
//       void onRequest(const std::shared_ptr<ServerConnection>& c,
//                      const IncomingRequest& r) override {
//           // decode r.body / r.size according to r.typeId, then:
//           Buffer b = ServerConnection::newMessageBuffer();
//           BinaryEncoder e(b);
//           encode(e, NodeId(0, DataTypeInfo<ReadResponse>::binaryEncodingId));
//           encode(e, response);
//           c->send(r.requestId, std::move(b));
//       }
//   };
//   TcpServer server(config, handler);  // handler must outlive the server
//   server.start();                      // throws on bind failure
//   ... server.port() ...
//   server.stop();
//
// Errors on a connection (protocol violations, limits, timeouts) are answered with an ERR
// message and close that connection only. The connection then lingers briefly (reads and
// discards until the peer closes, at most 2 s) so that the ERR is not lost in a TCP reset.
//
// Memory per connection: the receive buffer (receiveBufferSize + 16 KiB, allocated once,
// its pages touched only as far as messages fill it), one message being reassembled (at
// most maxMessageSize) and the responses waiting for the socket. While more than 4 MiB of
// responses wait (a client that sends but does not read), the connection stops reading
// requests until the backlog drains.
#pragma once

#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <string>

#include "ua/transport/secure_channel.hpp"

namespace pnp::ua::transport {

// One accepted TCP connection with its secure channel, as the upper layer sees it.
// Thread-safe. Abstract so that the upper layer can test its handlers with a fake.
// Do not call send() / close() after the TcpServer is destroyed (between stop() and the
// destruction they are no-ops).
class ServerConnection : public std::enable_shared_from_this<ServerConnection> {
  public:
    virtual ~ServerConnection() = default;

    // The secure channel id (0 before OpenSecureChannel; requests only arrive after it).
    virtual UInt32 channelId() const = 0;
    // The EndpointUrl of the client's Hello. Set before the first onRequest and constant
    // afterwards.
    virtual const std::string& endpointUrl() const = 0;
    // "127.0.0.1:53412", "[::1]:53412".
    virtual std::string peerAddress() const = 0;
    // The secure channel's policy, mode and client certificate; null for SecurityPolicy None.
    // Set before the first onRequest and constant afterwards (a renew keeps them).
    virtual const ChannelSecurity* security() const { return nullptr; }

    // A buffer for a response: kSymmetricHeaderSize bytes reserved for the headers; append
    // the response's encoding NodeId and body with a BinaryEncoder, then send() it.
    static Buffer newMessageBuffer() { return transport::newMessageBuffer(); }

    // Sends a response to request `requestId`. Callable from any thread. The common case
    // (one chunk) fills the headers in place without copying the body and costs one write
    // system call. A response larger than the client accepts becomes a ServiceFault
    // BadResponseTooLarge. Dropped silently when the connection is closed.
    // Throws std::invalid_argument when message is shorter than kSymmetricHeaderSize.
    virtual void send(UInt32 requestId, Buffer&& message) = 0;
    // The same for a message encoded with Splices (large byte runs referenced, not
    // copied): keepAlive holds the referenced bytes until they are written. The default
    // joins them into the buffer.
    virtual void sendSpliced(UInt32 requestId, Buffer&& message, Splices&& splices,
                             std::shared_ptr<const void> /*keepAlive*/) {
        send(requestId, joinSplices(std::move(message), splices));
    }
    // Sends a ServiceFault (ResponseHeader with serviceResult = status).
    virtual void sendServiceFault(UInt32 requestId, UInt32 requestHandle, StatusCode status) = 0;
    // Closes the connection (no ERR). Pending responses are written first. onConnectionClosed
    // follows on the network thread.
    virtual void close() = 0;

    // True once the connection is closed or closing (any thread).
    virtual bool isClosed() const = 0;
    // Writes what is queued for this connection now, from the calling thread (also under the
    // network lock), instead of when the lock is released: for a message that should not
    // wait for the rest of the request being served, e.g. a notification its handler
    // caused. Never blocks: what the socket does not take now is written as usual.
    virtual void flush() {}
};

class ServiceHandler {
  public:
    virtual ~ServiceHandler() = default;
    // A MSG request (OPN / CLO are handled inside the transport). On the network thread.
    // Respond now or later (from any thread) with conn->send(request.requestId, ...).
    virtual void onRequest(const std::shared_ptr<ServerConnection>& conn,
                           const IncomingRequest& request) = 0;
    // The connection is gone (peer closed, error, timeout, close(), stop()). On the network
    // thread, once per accepted connection (not for connections refused with
    // BadTcpServerTooBusy because maxConnections was reached).
    virtual void onConnectionClosed(const std::shared_ptr<ServerConnection>& /*conn*/) {}
};

class TcpServer {
  public:
    TcpServer(ServerTransportConfig config, ServiceHandler& handler);
    ~TcpServer();  // stop()
    TcpServer(const TcpServer&) = delete;
    TcpServer& operator=(const TcpServer&) = delete;

    // Binds config.host:config.port, listens and starts the service thread. Throws
    // TransportError(BadCommunicationError) when the address cannot be bound.
    void start();
    // Closes the listener and every connection (onConnectionClosed for each, on the network
    // thread) and joins the event loops and the service thread. Idempotent. Must not
    // be called under the network lock (from a callback).
    void stop();
    bool running() const;

    // The bound port (the ephemeral one when config.port was 0). Valid after start().
    UInt16 port() const;

    // Runs fn on the service thread under the network lock (also when called under it:
    // queued, not run inline). Exceptions escaping fn are dropped.
    void post(std::function<void()> fn);
    // Only while not started (a server driven by calling its handler directly: tests,
    // fuzzing): runs the functions post()ed so far on this thread, under the network lock,
    // and returns how many ran. Returns 0 at once while running.
    std::size_t runPosted();
    // True while this thread holds the network lock (inside every callback).
    bool isNetworkThread() const;
    // On the network thread: runs fn on this thread once it has released the network lock
    // and written the responses queued meanwhile. Elsewhere: runs fn at once. Exceptions
    // escaping fn are dropped.
    void afterResponsesWritten(std::function<void()> fn);
    // Runs fn under the network lock every `period` (replaces an earlier tick). Callable
    // before start() or from any thread afterwards. A period of 0 removes the tick.
    void setTick(std::chrono::milliseconds period, std::function<void()> fn);

    // Open connections (any thread; approximate while connections come and go).
    std::size_t connectionCount() const;
    const ServerTransportConfig& config() const;

  private:
    friend class TcpServerConnection;
    friend class NetworkLock;
    friend class EventLoop;
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::ua::transport
