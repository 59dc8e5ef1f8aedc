#include "ua/transport/tcp_server.hpp"

#include <asio.hpp>
#include <atomic>
#include <optional>
#include <thread>
#include <unordered_set>
#include <vector>

#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {

namespace {

// After an ERR / close: how long a connection keeps reading (and discarding) while waiting
// for the peer to close, so that the kernel does not answer unread data with a reset that
// could destroy the ERR before the client read it.
constexpr std::chrono::milliseconds kLinger{2000};
// Period of the sweep over all connections (hello / idle timeouts, token expiry, linger).
constexpr std::chrono::milliseconds kHousekeeping{100};
// Backpressure: while more than this many response bytes wait for the socket, the
// connection stops reading requests (a client that sends but never reads cannot make the
// server queue without bound).
constexpr std::size_t kMaxQueuedOutput = 4u << 20;

using asio::ip::tcp;

// A buffer sequence over a vector of asio::const_buffer, cheap to copy (the composed write
// operation keeps a copy of the sequence; copying a std::vector would allocate).
struct BufferView {
    const asio::const_buffer* b;
    const asio::const_buffer* e;
    const asio::const_buffer* begin() const { return b; }
    const asio::const_buffer* end() const { return e; }
};

std::string endpointString(const tcp::endpoint& ep) {
    auto a = ep.address();
    std::string s = a.is_v6() ? "[" + a.to_string() + "]" : a.to_string();
    return s + ":" + std::to_string(ep.port());
}

}  // namespace

class TcpServerConnection;

struct TcpServer::Impl {
    Impl(ServerTransportConfig c, ServiceHandler& h) : config(std::move(c)), handler(h) {
        // Channel ids should differ across restarts (Part 6 §6.7.2.2): start from the clock.
        auto t = std::chrono::system_clock::now().time_since_epoch();
        nextChannelId = static_cast<UInt32>(
                            std::chrono::duration_cast<std::chrono::seconds>(t).count() & 0xFFFFF) *
                            1000 +
                        1;
    }

    void accept();
    void onAccepted(const asio::error_code& ec, tcp::socket socket);
    void scheduleHousekeeping();
    void housekeeping();
    void scheduleTick(std::uint64_t generation);
    void shutdownAll();
    void removeConnection(const std::shared_ptr<TcpServerConnection>& c, bool notify);
    UInt32 newChannelId() {
        UInt32 id = nextChannelId++;
        if (nextChannelId == 0) nextChannelId = 1;
        return id == 0 ? newChannelId() : id;
    }

    ServerTransportConfig config;
    ServiceHandler& handler;
    // All socket operations run on the network thread (other threads post to it), so the
    // reactor's per-descriptor locks can go; posting and registration stay thread-safe.
    asio::io_context io{ASIO_CONCURRENCY_HINT_UNSAFE_IO};
    // Declared before the connections' owners: every channel gives its bytes back first.
    MemoryBudget incompleteMessages{config.maxIncompleteMessageBytes};
    tcp::acceptor acceptor{io};
    asio::steady_timer housekeepingTimer{io};
    asio::steady_timer acceptRetryTimer{io};
    asio::steady_timer tickTimer{io};
    std::optional<asio::executor_work_guard<asio::io_context::executor_type>> work;
    std::thread thread;
    std::atomic<bool> running{false};
    UInt16 boundPort = 0;

    // Network thread only.
    std::unordered_set<std::shared_ptr<TcpServerConnection>> connections;
    std::vector<std::shared_ptr<TcpServerConnection>> sweepList;
    std::size_t activeConnections = 0;  // without the rejected ones lingering
    std::size_t rejectedConnections = 0;
    UInt32 nextChannelId = 1;
    std::chrono::milliseconds tickPeriod{0};
    std::function<void()> tickFn;
    std::uint64_t tickGeneration = 0;

    std::atomic<std::size_t> connectionCount{0};
};

// =======================================================================================
class TcpServerConnection final : public ServerConnection, private ServerChannel::Hooks {
  public:
    TcpServerConnection(TcpServer::Impl& server, tcp::socket socket, std::string peer,
                        bool rejected)
        : server_(server),
          socket_(std::move(socket)),
          peer_(std::move(peer)),
          channel_(server.config, *this, Clock::now(), &server.incompleteMessages),
          rejected_(rejected) {}

    bool rejected() const { return rejected_; }

    // ---- ServerConnection -------------------------------------------------------------
    UInt32 channelId() const override { return channelId_.load(std::memory_order_acquire); }
    const std::string& endpointUrl() const override { return channel_.endpointUrl(); }
    std::string peerAddress() const override { return peer_; }
    bool isClosed() const override { return closedFlag_.load(std::memory_order_acquire); }

    void send(UInt32 requestId, Buffer&& message) override {
        if (message.size() < kSymmetricHeaderSize)
            throw std::invalid_argument("ServerConnection::send: buffer without header space");
        if (isClosed()) return;
        if (server_.io.get_executor().running_in_this_thread()) {
            sendHere(requestId, std::move(message));
            return;
        }
        asio::post(server_.io, [self = self(), requestId, m = std::move(message)]() mutable {
            self->sendHere(requestId, std::move(m));
        });
    }

    void sendServiceFault(UInt32 requestId, UInt32 requestHandle, StatusCode status) override {
        if (isClosed()) return;
        if (server_.io.get_executor().running_in_this_thread()) {
            if (lingering_ || finished_) return;
            channel_.sendServiceFault(requestId, requestHandle, status);
            afterActivity();
            return;
        }
        asio::post(server_.io, [self = self(), requestId, requestHandle, status] {
            self->sendServiceFault(requestId, requestHandle, status);
        });
    }

    void close() override {
        if (isClosed()) return;
        if (server_.io.get_executor().running_in_this_thread()) {
            channel_.close();
            afterActivity();
            return;
        }
        asio::post(server_.io, [self = self()] { self->close(); });
    }

    // ---- network thread ---------------------------------------------------------------
    void start() {
        asio::error_code ignored;
        socket_->non_blocking(true, ignored);  // for the direct write in flush()
        if (rejected_) {
            channel_.fail(status::BadTcpServerTooBusy, "too many connections");
            afterActivity();
        }
        startRead();
    }

    void housekeeping(TimePoint now) {
        if (finished_) return;
        if (lingering_) {
            if (now >= lingerUntil_) finish(true);
            return;
        }
        channel_.tick(now);
        afterActivity();
    }

    // Server stop: close at once.
    void shutdownNow() {
        if (!channel_.isClosed()) channel_.close();
        finish(true);
    }

  private:
    std::shared_ptr<TcpServerConnection> self() {
        return std::static_pointer_cast<TcpServerConnection>(shared_from_this());
    }

    // ---- ServerChannel::Hooks ---------------------------------------------------------
    void write(Buffer&& bytes) override {
        queuedBytes_ += bytes.size();
        pending_.push_back(std::move(bytes));
    }

    void request(const IncomingRequest& r) override {
        auto s = std::static_pointer_cast<ServerConnection>(self());
        server_.handler.onRequest(s, r);
    }

    UInt32 newChannelId() override {
        UInt32 id = server_.newChannelId();
        channelId_.store(id, std::memory_order_release);
        return id;
    }

    // ---- I/O ------------------------------------------------------------------------
    void sendHere(UInt32 requestId, Buffer&& message) {
        if (lingering_ || finished_) return;
        channel_.send(requestId, std::move(message));
        afterActivity();
    }

    // After the channel produced output or closed outside of a read batch.
    void afterActivity() {
        if (inBatch_ || finished_) return;
        flush();
        if (channel_.isClosed()) beginClose();
    }

    void startRead() {
        if (finished_ || readInFlight_) return;
        if (queuedBytes_ > kMaxQueuedOutput && !lingering_) return;  // resumed by onWritten
        auto space = channel_.readSpace();
        readInFlight_ = true;
        socket_->async_read_some(
            asio::buffer(space.data(), space.size()),
            [self = self()](const asio::error_code& ec, std::size_t n) { self->onRead(ec, n); });
    }

    void onRead(const asio::error_code& ec, std::size_t n) {
        readInFlight_ = false;
        if (finished_) return;
        if (ec) {
            // The peer closed or reset (possibly in the middle of a message).
            if (!channel_.isClosed()) channel_.close();
            finish(true);
            return;
        }
        inBatch_ = true;
        channel_.received(n, coarseNow());  // never throws: errors become ERR + Closed
        inBatch_ = false;
        flush();
        if (channel_.isClosed()) beginClose();
        startRead();
    }

    void flush() {
        if (writeInFlight_ || pending_.empty() || finished_) return;
        writing_.swap(pending_);
        iov_.clear();
        for (const auto& b : writing_) iov_.emplace_back(b.data(), b.size());
        // Fast path: the kernel almost always takes a response at once. Writing it here
        // (the socket is in non-blocking mode) saves the asynchronous write's completion
        // handler and the extra reactor round (epoll_wait) it costs on every request. What
        // is left (a full send buffer, an error) goes the asynchronous way, which also
        // reports errors as before.
        std::size_t first = 0;
        asio::error_code ec;
        std::size_t n = socket_->write_some(BufferView{iov_.data(), iov_.data() + iov_.size()}, ec);
        if (!ec) {
            while (first < iov_.size() && n >= iov_[first].size()) n -= iov_[first++].size();
            if (first == iov_.size()) {  // all written: what onWritten() would do
                for (const auto& b : writing_) queuedBytes_ -= b.size();
                writing_.clear();
                return;
            }
            iov_[first] += n;
        }
        writeInFlight_ = true;
        asio::async_write(
            *socket_, BufferView{iov_.data() + first, iov_.data() + iov_.size()},
            [self = self()](const asio::error_code& ec, std::size_t) { self->onWritten(ec); });
    }

    void onWritten(const asio::error_code& ec) {
        writeInFlight_ = false;
        for (const auto& b : writing_) queuedBytes_ -= b.size();
        writing_.clear();
        if (finished_) return;
        if (ec) {
            if (!channel_.isClosed()) channel_.close();
            finish(true);
            return;
        }
        flush();
        if (lingering_ && !writeInFlight_) sendFin();
        startRead();  // no-op unless paused by backpressure
    }

    // The channel is closed: write what is pending, send FIN, read until the peer closes.
    void beginClose() {
        if (lingering_ || finished_) return;
        lingering_ = true;
        closedFlag_.store(true, std::memory_order_release);
        lingerUntil_ = Clock::now() + kLinger;
        flush();
        if (!writeInFlight_) sendFin();
    }

    void sendFin() {
        if (finSent_ || !socket_) return;
        finSent_ = true;
        asio::error_code ignored;
        socket_->shutdown(tcp::socket::shutdown_send, ignored);
    }

    void finish(bool notify) {
        if (finished_) return;
        finished_ = true;
        closedFlag_.store(true, std::memory_order_release);
        asio::error_code ignored;
        socket_->close(ignored);
        // Destroying the socket here (pending operations complete with operation_aborted)
        // keeps a ServerConnection the upper layer still holds from touching the
        // io_context after the server is gone.
        socket_.reset();
        channel_.leaveBudget();  // the server's budget may be gone before this connection
        for (const auto& b : pending_) queuedBytes_ -= b.size();
        pending_.clear();
        server_.removeConnection(self(), notify && !rejected_);
    }

    TcpServer::Impl& server_;
    std::optional<tcp::socket> socket_;
    std::string peer_;
    ServerChannel channel_;
    bool rejected_;
    std::atomic<UInt32> channelId_{0};
    std::atomic<bool> closedFlag_{false};

    std::vector<Buffer> pending_;  // produced, not yet handed to the socket
    std::vector<Buffer> writing_;  // being written
    std::vector<asio::const_buffer> iov_;
    bool writeInFlight_ = false;
    bool readInFlight_ = false;
    bool inBatch_ = false;
    bool lingering_ = false;
    bool finSent_ = false;
    bool finished_ = false;
    std::size_t queuedBytes_ = 0;  // in pending_ + writing_
    TimePoint lingerUntil_{};
};

// =======================================================================================
void TcpServer::Impl::accept() {
    acceptor.async_accept([this](const asio::error_code& ec, tcp::socket socket) {
        onAccepted(ec, std::move(socket));
    });
}

void TcpServer::Impl::onAccepted(const asio::error_code& ec, tcp::socket socket) {
    if (!acceptor.is_open()) return;  // stopping
    if (ec) {
        if (ec == asio::error::operation_aborted) return;
        // EMFILE / ENFILE / ENOBUFS ...: try again a little later instead of spinning.
        acceptRetryTimer.expires_after(std::chrono::milliseconds(50));
        acceptRetryTimer.async_wait([this](const asio::error_code& e) {
            if (!e && acceptor.is_open()) accept();
        });
        return;
    }
    asio::error_code ignored;
    socket.set_option(tcp::no_delay(true), ignored);
    std::string peer;
    auto remote = socket.remote_endpoint(ignored);
    if (!ignored) peer = endpointString(remote);

    bool reject = activeConnections >= config.maxConnections;
    if (reject && rejectedConnections >= std::max<std::size_t>(config.maxConnections, 16)) {
        socket.close(ignored);  // flooded: not even an ERR
    } else {
        auto c = std::make_shared<TcpServerConnection>(*this, std::move(socket), std::move(peer),
                                                       reject);
        connections.insert(c);
        if (reject)
            ++rejectedConnections;
        else
            ++activeConnections;
        connectionCount.store(activeConnections, std::memory_order_relaxed);
        c->start();
    }
    accept();
}

void TcpServer::Impl::removeConnection(const std::shared_ptr<TcpServerConnection>& c, bool notify) {
    if (connections.erase(c) == 0) return;
    if (c->rejected())
        --rejectedConnections;
    else
        --activeConnections;
    connectionCount.store(activeConnections, std::memory_order_relaxed);
    if (notify) {
        try {
            handler.onConnectionClosed(c);
        } catch (...) {
            // The upper layer's problem; the network thread goes on.
        }
    }
}

void TcpServer::Impl::scheduleHousekeeping() {
    housekeepingTimer.expires_after(kHousekeeping);
    housekeepingTimer.async_wait([this](const asio::error_code& ec) {
        if (ec) return;
        housekeeping();
        scheduleHousekeeping();
    });
}

void TcpServer::Impl::housekeeping() {
    auto now = Clock::now();
    sweepList.assign(connections.begin(), connections.end());
    for (auto& c : sweepList) c->housekeeping(now);
    sweepList.clear();
}

void TcpServer::Impl::scheduleTick(std::uint64_t generation) {
    if (tickPeriod.count() <= 0 || !tickFn) return;
    tickTimer.expires_after(tickPeriod);
    tickTimer.async_wait([this, generation](const asio::error_code& ec) {
        if (ec || generation != tickGeneration) return;
        try {
            tickFn();
        } catch (...) {
        }
        if (generation == tickGeneration) scheduleTick(generation);
    });
}

void TcpServer::Impl::shutdownAll() {
    asio::error_code ignored;
    acceptor.close(ignored);
    housekeepingTimer.cancel();
    acceptRetryTimer.cancel();
    tickTimer.cancel();
    ++tickGeneration;
    sweepList.assign(connections.begin(), connections.end());
    for (auto& c : sweepList) c->shutdownNow();
    sweepList.clear();
    connections.clear();
    work.reset();
    // Handlers still queued (cancelled operations, sends posted by other threads) are
    // destroyed with the io_context; nothing of them needs to run.
    io.stop();
}

// =======================================================================================
TcpServer::TcpServer(ServerTransportConfig config, ServiceHandler& handler)
    : impl_(std::make_unique<Impl>(std::move(config), handler)) {}

TcpServer::~TcpServer() { stop(); }

void TcpServer::start() {
    auto& i = *impl_;
    if (i.running.load()) return;
    asio::error_code ec;
    tcp::resolver resolver(i.io);
    auto results = resolver.resolve(i.config.host, std::to_string(i.config.port),
                                    tcp::resolver::passive | tcp::resolver::numeric_service, ec);
    if (ec || results.empty()) {
        throw TransportError(
            status::BadCommunicationError,
            "cannot resolve listen address " + i.config.host + ": " + ec.message());
    }
    tcp::endpoint ep = *results.begin();
    i.acceptor.open(ep.protocol(), ec);
    if (!ec) i.acceptor.set_option(tcp::acceptor::reuse_address(true), ec);
    if (!ec) i.acceptor.bind(ep, ec);
    if (!ec) i.acceptor.listen(asio::socket_base::max_listen_connections, ec);
    if (ec) {
        asio::error_code ignored;
        i.acceptor.close(ignored);
        throw TransportError(status::BadCommunicationError,
                             "cannot listen on " + endpointString(ep) + ": " + ec.message());
    }
    i.boundPort = i.acceptor.local_endpoint().port();
    i.io.restart();
    i.work.emplace(asio::make_work_guard(i.io));
    i.accept();
    i.scheduleHousekeeping();
    i.scheduleTick(i.tickGeneration);
    i.running.store(true);
    i.thread = std::thread([&i] { i.io.run(); });
}

void TcpServer::stop() {
    auto& i = *impl_;
    if (!i.running.load()) return;
    if (isNetworkThread()) throw std::logic_error("TcpServer::stop() called on the network thread");
    asio::post(i.io, [&i] { i.shutdownAll(); });
    if (i.thread.joinable()) i.thread.join();
    i.running.store(false);
    i.connectionCount.store(0);
}

bool TcpServer::running() const { return impl_->running.load(); }
UInt16 TcpServer::port() const { return impl_->boundPort; }
const ServerTransportConfig& TcpServer::config() const { return impl_->config; }

std::size_t TcpServer::connectionCount() const {
    return impl_->connectionCount.load(std::memory_order_relaxed);
}

void TcpServer::post(std::function<void()> fn) { asio::post(impl_->io, std::move(fn)); }

bool TcpServer::isNetworkThread() const {
    return impl_->io.get_executor().running_in_this_thread();
}

void TcpServer::setTick(std::chrono::milliseconds period, std::function<void()> fn) {
    auto* i = impl_.get();
    auto apply = [i, period, fn = std::move(fn)]() mutable {
        ++i->tickGeneration;
        i->tickTimer.cancel();
        i->tickPeriod = period;
        i->tickFn = std::move(fn);
        if (i->running.load()) i->scheduleTick(i->tickGeneration);
    };
    if (!i->running.load())
        apply();
    else
        asio::post(i->io, std::move(apply));
}

}  // namespace pnp::ua::transport
