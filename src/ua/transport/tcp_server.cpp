#include "ua/transport/tcp_server.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <asio.hpp>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <future>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_set>
#include <vector>

#include "ua/transport/gather.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::transport {

namespace {

// After an ERR / close: how long a connection keeps reading (and discarding) while waiting
// for the peer to close, so that the kernel does not answer unread data with a reset that
// could destroy the ERR before the client read it.
constexpr std::chrono::milliseconds kLinger{2000};
// Period of the sweep over all connections (hello / idle timeouts, token expiry).
constexpr std::chrono::milliseconds kHousekeeping{100};
// A connection thread blocked in recv() / send() wakes at least this often to notice a
// close or stop requested by another thread and output queued by other threads.
constexpr std::chrono::milliseconds kConnectionPoll{100};
// Backpressure: while more than this many response bytes wait for the socket, the
// connection stops reading requests (a client that sends but never reads cannot make the
// server queue without bound).
constexpr std::size_t kMaxQueuedOutput = 4u << 20;
// Buffers handed to one sendmsg() call.
constexpr std::size_t kMaxIov = 64;

using asio::ip::tcp;

std::string endpointString(const tcp::endpoint& ep) {
    auto a = ep.address();
    std::string s = a.is_v6() ? "[" + a.to_string() + "]" : a.to_string();
    return s + ":" + std::to_string(ep.port());
}

void setReceiveTimeout(int fd, std::chrono::milliseconds period) {
    timeval tv{};
    tv.tv_sec = static_cast<time_t>(period.count() / 1000);
    tv.tv_usec = static_cast<suseconds_t>((period.count() % 1000) * 1000);
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
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
    void removeConnection(const std::shared_ptr<TcpServerConnection>& c, bool notify);
    void threadStarted();
    void threadFinished();
    UInt32 newChannelId() {
        UInt32 id = nextChannelId++;
        if (nextChannelId == 0) nextChannelId = 1;
        return id == 0 ? newChannelId() : id;
    }
    bool holdsNetworkLock() const;

    ServerTransportConfig config;
    ServiceHandler& handler;
    // The service thread: accepts, runs the timers and the functions post()ed to the
    // network thread. Connections do their own I/O on their own threads.
    asio::io_context io;
    // Declared before the connections' owners: every channel gives its bytes back first.
    MemoryBudget incompleteMessages{config.maxIncompleteMessageBytes};
    tcp::acceptor acceptor{io};
    asio::steady_timer housekeepingTimer{io};
    asio::steady_timer acceptRetryTimer{io};
    asio::steady_timer tickTimer{io};
    std::optional<asio::executor_work_guard<asio::io_context::executor_type>> work;
    std::thread serviceThread;
    std::atomic<bool> running{false};
    UInt16 boundPort = 0;

    // The network lock: held by whichever thread runs the protocol or the upper layer
    // (ServiceHandler, post(), ticks). "The network thread" is the thread holding it.
    std::mutex networkMutex;
    // Guarded by networkMutex.
    bool stopping = false;
    std::unordered_set<std::shared_ptr<TcpServerConnection>> connections;
    std::vector<std::shared_ptr<TcpServerConnection>> sweepList;
    // Connections that queued output while the lock was held: written when it is released.
    std::vector<std::shared_ptr<TcpServerConnection>> dirty;
    std::size_t activeConnections = 0;  // without the rejected ones lingering
    std::size_t rejectedConnections = 0;
    UInt32 nextChannelId = 1;
    std::chrono::milliseconds tickPeriod{0};
    std::function<void()> tickFn;
    std::uint64_t tickGeneration = 0;

    // Connection threads still running (stop() waits for 0).
    std::mutex threadsMutex;
    std::condition_variable threadsDone;
    std::size_t liveThreads = 0;

    std::atomic<std::size_t> connectionCount{0};
};

namespace {
thread_local const void* t_networkLockHolder = nullptr;  // the TcpServer::Impl
// afterResponsesWritten(): run by this thread when it releases the network lock.
thread_local std::vector<std::function<void()>> t_afterWrite;

// Runs a function of the upper layer; what escapes it is the caller's problem, the calling
// thread (network, service) goes on.
void runDropping(const std::function<void()>& fn) noexcept {
    try {
        fn();
    } catch (...) {
    }
}
}  // namespace

bool TcpServer::Impl::holdsNetworkLock() const { return t_networkLockHolder == this; }

// Holds the network lock; on release, writes what the connections queued meanwhile
// (without blocking: a connection thread finishes what the socket does not take at once).
class NetworkLock {
  public:
    explicit NetworkLock(TcpServer::Impl& s) : s_(s), lock_(s.networkMutex) {
        t_networkLockHolder = &s_;
    }
    // Takes the lock only if it is free at once (owns() tells).
    NetworkLock(TcpServer::Impl& s, std::try_to_lock_t)
        : s_(s), lock_(s.networkMutex, std::try_to_lock) {
        if (lock_.owns_lock()) t_networkLockHolder = &s_;
    }
    bool owns() const { return lock_.owns_lock(); }
    ~NetworkLock() { unlock(); }
    NetworkLock(const NetworkLock&) = delete;
    NetworkLock& operator=(const NetworkLock&) = delete;
    void unlock();

  private:
    TcpServer::Impl& s_;
    std::unique_lock<std::mutex> lock_;
};

// =======================================================================================
// One accepted connection and its thread. The thread blocks in recv() (no event loop
// between the socket and the protocol: a request costs the same two system calls as a
// plain blocking echo), runs the secure channel and the upper layer under the network
// lock and writes the responses itself.
class TcpServerConnection final : public ServerConnection, private ServerChannel::Hooks {
  public:
    TcpServerConnection(TcpServer::Impl& server, int fd, std::string peer, bool rejected)
        : server_(server),
          fd_(fd),
          peer_(std::move(peer)),
          channel_(server.config, *this, Clock::now(), &server.incompleteMessages),
          rejected_(rejected) {}
    ~TcpServerConnection() override {
        if (fd_ >= 0) ::close(fd_);
    }

    bool rejected() const { return rejected_; }

    // ---- ServerConnection -------------------------------------------------------------
    UInt32 channelId() const override { return channelId_.load(std::memory_order_acquire); }
    const std::string& endpointUrl() const override { return channel_.endpointUrl(); }
    const ChannelSecurity* security() const override { return channel_.security(); }
    std::string peerAddress() const override { return peer_; }
    bool isClosed() const override { return closedFlag_.load(std::memory_order_acquire); }
    void flush() override { (void)writeQueued(); }

    void send(UInt32 requestId, Buffer&& message) override {
        sendSpliced(requestId, std::move(message), Splices{}, nullptr);
    }

    void sendSpliced(UInt32 requestId, Buffer&& message, Splices&& splices,
                     std::shared_ptr<const void> keepAlive) override {
        if (message.size() < kSymmetricHeaderSize)
            throw std::invalid_argument("ServerConnection::send: buffer without header space");
        if (isClosed()) return;
        // Under the network lock: written here, unless sends of this connection still wait
        // in the service thread's queue (they were first: e.g. NotificationMessages with
        // lower sequence numbers) — then queued behind them.
        if (server_.holdsNetworkLock() && postedSends_.load(std::memory_order_acquire) == 0) {
            sendSplicedHere(requestId, std::move(message), std::move(splices),
                            std::move(keepAlive));
            return;
        }
        // Not under the network lock. When it is free and nothing of this connection waits
        // in the service thread's queue (order), written here at once: a value change on an
        // application thread reaches the client without a thread hop. Otherwise queued to
        // the service thread; never waiting for the lock, so that a caller holding locks of
        // its own cannot deadlock with a handler that takes them.
        if (!server_.holdsNetworkLock() && postedSends_.load(std::memory_order_acquire) == 0) {
            NetworkLock lock(server_, std::try_to_lock);
            if (lock.owns()) {
                sendSplicedHere(requestId, std::move(message), std::move(splices),
                                std::move(keepAlive));
                return;
            }
        }
        postedSends_.fetch_add(1, std::memory_order_acq_rel);
        asio::post(server_.io, [self = self(), requestId, m = std::move(message),
                                sp = std::move(splices), k = std::move(keepAlive)]() mutable {
            NetworkLock lock(self->server_);
            self->sendSplicedHere(requestId, std::move(m), std::move(sp), std::move(k));
            self->postedSends_.fetch_sub(1, std::memory_order_acq_rel);
        });
    }

    void sendServiceFault(UInt32 requestId, UInt32 requestHandle, StatusCode status) override {
        if (isClosed()) return;
        if (server_.holdsNetworkLock()) {
            if (closing_ || finished_) return;
            channel_.sendServiceFault(requestId, requestHandle, status);
            noteClosed();
            return;
        }
        asio::post(server_.io, [self = self(), requestId, requestHandle, status] {
            NetworkLock lock(self->server_);
            self->sendServiceFault(requestId, requestHandle, status);
        });
    }

    void close() override {
        if (isClosed()) return;
        if (server_.holdsNetworkLock()) {
            channel_.close();
            noteClosed();
            return;
        }
        // Takes effect before anything this connection receives from now on (the thread
        // checks the flag before handling input), and at once for an idle connection.
        closeRequested_.store(true, std::memory_order_release);
        asio::post(server_.io, [self = self()] {
            NetworkLock lock(self->server_);
            self->applyCloseRequest();
        });
    }

    // ---- under the network lock ---------------------------------------------------------
    void housekeeping(TimePoint now) {
        if (closing_ || finished_) return;
        channel_.tick(now);
        noteClosed();
    }

    // Server stop: the thread leaves at once (no linger).
    void requestStop() {
        stopRequested_.store(true, std::memory_order_release);
        if (fd_ >= 0) ::shutdown(fd_, SHUT_RDWR);  // wakes recv() / send()
    }

    // ---- the connection's thread ----------------------------------------------------------
    void run() {
        // request() hands this to the upper layer without a shared_from_this() per request.
        const std::shared_ptr<ServerConnection> me = self();
        self_ = &me;
        setReceiveTimeout(fd_, kConnectionPoll);
        std::span<Byte> space;
        {
            NetworkLock lock(server_);
            if (rejected_) channel_.fail(status::BadTcpServerTooBusy, "too many connections");
            noteClosed();
            space = channel_.readSpace();
        }
        while (!stopRequested()) {
            WriteResult w = writeQueued();
            if (w == WriteResult::Error) break;  // the peer is gone
            if (closing_.load(std::memory_order_acquire)) {
                linger();
                break;
            }
            if (w == WriteResult::Stalled) {
                // The socket takes no more for now: wait for room, and for requests while
                // the backlog is small (backpressure on a client that does not read).
                short events = POLLOUT;
                if (queuedBytes() <= kMaxQueuedOutput) events |= POLLIN;
                pollfd p{fd_, events, 0};
                if (::poll(&p, 1, static_cast<int>(kConnectionPoll.count())) <= 0 ||
                    (p.revents & (POLLIN | POLLERR | POLLHUP)) == 0)
                    continue;
            }
            ssize_t n = ::recv(fd_, space.data(), space.size(), 0);
            if (n > 0) {
                NetworkLock lock(server_);
                applyCloseRequest();
                channel_.received(static_cast<std::size_t>(n), coarseNow());  // never throws
                noteClosed();
                space = channel_.readSpace();
            } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
                // the poll period passed: look at the flags and the queue again
            } else {
                break;  // closed or reset, possibly in the middle of a message
            }
        }
        finish();
    }

    enum class WriteResult { Drained, Stalled, Error };

    // Writes queued output without blocking (any thread; under the network lock only by
    // flush(), which takes outMutex_ in the same order as write()).
    // One thread writes at a time (writing_): a caller that finds another one writing
    // leaves its bytes to it, which writes until the queue is empty. Stalled: the socket
    // took less than everything.
    WriteResult writeQueued() {
        if (!outPending_.load(std::memory_order_acquire)) return WriteResult::Drained;
        std::unique_lock q(outMutex_);
        if (writing_) return WriteResult::Drained;
        if (broken_) return WriteResult::Error;
        if (outHead_ == out_.size()) return WriteResult::Drained;
        writing_ = true;
        iovec iov[kMaxIov];
        for (;;) {
            std::size_t count = 0;
            for (std::size_t k = outHead_; k < out_.size() && count < kMaxIov; ++k) {
                forEachPiece(out_[k].bytes, out_[k].splices, k == outHead_ ? frontWritten_ : 0,
                             [&](const Byte* p, std::size_t n) {
                                 iov[count++] = iovec{const_cast<Byte*>(p), n};
                                 return count < kMaxIov;
                             });
            }
            q.unlock();  // others may append meanwhile; only the writer removes
            ssize_t n = sendPieces(fd_, iov, count, MSG_NOSIGNAL | MSG_DONTWAIT);
            int err = n < 0 ? errno : 0;
            q.lock();
            if (n < 0) {
                if (err == EINTR) continue;
                writing_ = false;
                writerDone_.notify_all();
                if (err == EAGAIN || err == EWOULDBLOCK) return WriteResult::Stalled;
                broken_ = true;
                return WriteResult::Error;
            }
            auto left = static_cast<std::size_t>(n);
            while (left > 0) {
                std::size_t rest = out_[outHead_].size - frontWritten_;
                if (left < rest) {
                    frontWritten_ += left;
                    break;
                }
                left -= rest;
                queued_ -= out_[outHead_].size;
                out_[outHead_++] = Outgoing();  // its memory goes now
                frontWritten_ = 0;
            }
            if (outHead_ == out_.size()) {
                out_.clear();
                outHead_ = 0;
                outPending_.store(false, std::memory_order_release);
                writing_ = false;
                writerDone_.notify_all();
                return WriteResult::Drained;
            }
        }
    }

  private:
    std::shared_ptr<TcpServerConnection> self() {
        return std::static_pointer_cast<TcpServerConnection>(shared_from_this());
    }

    bool stopRequested() const { return stopRequested_.load(std::memory_order_acquire); }

    // close() called without the network lock (under it).
    void applyCloseRequest() {
        if (closeRequested_.load(std::memory_order_acquire) && !channel_.isClosed()) {
            channel_.close();
            noteClosed();
        }
    }

    // After the channel may have closed (under the network lock).
    void noteClosed() {
        if (channel_.isClosed() && !closing_.load(std::memory_order_relaxed)) {
            closedFlag_.store(true, std::memory_order_release);
            closing_.store(true, std::memory_order_release);
            markDirty();  // FIN as soon as the output is written (afterNetworkLock())
        }
    }

    // Under the network lock: afterNetworkLock() runs when it is released.
    void markDirty() {
        if (!dirty_) {
            dirty_ = true;
            server_.dirty.push_back(self());
        }
    }

    // ---- ServerChannel::Hooks (under the network lock) ----------------------------------
    void write(Buffer&& bytes) override {
        if (finished_) return;
        {
            std::lock_guard q(outMutex_);
            queued_ += bytes.size();
            const std::size_t n = bytes.size();
            out_.push_back(Outgoing{std::move(bytes), {}, {}, n});
            outPending_.store(true, std::memory_order_release);
        }
        markDirty();
    }

    void writeSpliced(Buffer&& bytes, Splices&& splices,
                      std::shared_ptr<const void> keepAlive) override {
        if (finished_) return;
        {
            std::lock_guard q(outMutex_);
            const std::size_t n = bytes.size() + splicedSize(splices);
            queued_ += n;
            out_.push_back(Outgoing{std::move(bytes), std::move(splices), std::move(keepAlive), n});
            outPending_.store(true, std::memory_order_release);
        }
        markDirty();
    }

    // Only on the connection's thread, inside run().
    void request(const IncomingRequest& r) override { server_.handler.onRequest(*self_, r); }

    UInt32 newChannelId() override {
        UInt32 id = server_.newChannelId();
        channelId_.store(id, std::memory_order_release);
        return id;
    }

    void sendSplicedHere(UInt32 requestId, Buffer&& message, Splices&& splices,
                         std::shared_ptr<const void> keepAlive) {
        if (closing_ || finished_) return;
        channel_.send(requestId, std::move(message), std::move(splices), std::move(keepAlive));
        noteClosed();
    }

  public:
    // Called by NetworkLock::unlock() for connections in `dirty`.
    void clearDirty() { dirty_ = false; }
    // After the network lock was released (any thread): writes what was queued; once a
    // closed channel's output is all written, sends FIN at once (the connection's thread,
    // maybe blocked in recv(), lingers when it next wakes).
    void afterNetworkLock() {
        if (writeQueued() != WriteResult::Drained || !closing_.load(std::memory_order_acquire))
            return;
        std::lock_guard q(outMutex_);
        if (!writing_ && !broken_ && outHead_ == out_.size()) ::shutdown(fd_, SHUT_WR);
    }

  private:
    std::size_t queuedBytes() {
        std::lock_guard q(outMutex_);
        return queued_;
    }

    // The channel is closed: write what is pending, send FIN, read and discard until the
    // peer closes (at most kLinger).
    void linger() {
        const TimePoint until = Clock::now() + kLinger;
        auto msLeft = [&] {
            auto d = std::chrono::duration_cast<std::chrono::milliseconds>(until - Clock::now());
            return static_cast<int>(
                std::clamp<std::int64_t>(d.count(), 0, kConnectionPoll.count()));
        };
        for (;;) {
            WriteResult w = writeQueued();
            if (w == WriteResult::Error || stopRequested() || Clock::now() >= until) return;
            if (w == WriteResult::Drained && queuedBytes() == 0) break;
            pollfd p{fd_, POLLOUT, 0};
            ::poll(&p, 1, msLeft());
        }
        ::shutdown(fd_, SHUT_WR);
        Byte sink[4096];
        while (!stopRequested() && Clock::now() < until) {
            ssize_t n = ::recv(fd_, sink, sizeof sink, 0);
            if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR))
                return;
        }
    }

    void finish() {
        {
            // No thread writes to fd_ from here on.
            std::unique_lock q(outMutex_);
            broken_ = true;
            writerDone_.wait(q, [this] { return !writing_; });
        }
        NetworkLock lock(server_);
        if (!channel_.isClosed()) channel_.close();
        finished_ = true;
        closedFlag_.store(true, std::memory_order_release);
        closing_.store(true, std::memory_order_release);
        channel_.leaveBudget();  // the server's budget may be gone before this connection
        {
            std::lock_guard q(outMutex_);
            out_.clear();
            outHead_ = 0;
            queued_ = 0;
            frontWritten_ = 0;
            outPending_.store(false, std::memory_order_release);
        }
        ::close(fd_);
        fd_ = -1;
        server_.removeConnection(self(), !rejected_);
    }

    TcpServer::Impl& server_;
    int fd_;  // closed (finish()) when no thread writes, under the network lock
    std::string peer_;
    ServerChannel channel_;  // under the network lock (readSpace: the connection's thread)
    bool rejected_;
    std::atomic<UInt32> channelId_{0};
    std::atomic<bool> closedFlag_{false};      // isClosed()
    std::atomic<std::size_t> postedSends_{0};  // sends queued to the service thread
    std::atomic<bool> closing_{false};         // the channel closed: linger, then finish
    std::atomic<bool> stopRequested_{false};   // server stop: finish at once
    std::atomic<bool> closeRequested_{false};  // close() from a thread without the lock
    bool finished_ = false;                    // under the network lock
    bool dirty_ = false;                       // in server_.dirty (network lock)
    const std::shared_ptr<ServerConnection>* self_ = nullptr;  // run()'s, while it runs

    std::mutex outMutex_;  // guards the output state below
    std::condition_variable writerDone_;
    bool writing_ = false;  // a thread is writing (outside outMutex_, during sendmsg)
    bool broken_ = false;   // socket error or finished: nobody writes any more
    // out_ has unwritten bytes (set and cleared under outMutex_; read without it so that
    // an idle check costs no lock).
    std::atomic<bool> outPending_{false};
    // A chunk to write: its bytes, with spliced runs held by keepAlive; size: of both.
    struct Outgoing {
        Buffer bytes;
        Splices splices;
        std::shared_ptr<const void> keepAlive;
        std::size_t size = 0;
    };
    // Queued output: out_[outHead_ ...] (a vector rather than a deque: no allocation per
    // response once it has grown; emptied when everything is written).
    std::vector<Outgoing> out_;
    std::size_t outHead_ = 0;
    std::size_t frontWritten_ = 0;  // bytes of out_[outHead_] already written
    std::size_t queued_ = 0;        // bytes in out_
};

void NetworkLock::unlock() {
    if (!lock_.owns_lock()) return;
    // Moved to a per-thread vector; both keep their capacity: no allocation per request.
    thread_local std::vector<std::shared_ptr<TcpServerConnection>> t_dirty;
    std::move(s_.dirty.begin(), s_.dirty.end(), std::back_inserter(t_dirty));
    s_.dirty.clear();
    for (auto& c : t_dirty) c->clearDirty();
    t_networkLockHolder = nullptr;
    lock_.unlock();
    for (auto& c : t_dirty) c->afterNetworkLock();
    t_dirty.clear();
    // Taken out first: a function that takes the network lock itself (sending a response
    // does) runs this again, which must not run the earlier functions a second time. The
    // buffer goes back afterwards: no allocation per request.
    if (t_afterWrite.empty()) return;
    std::vector<std::function<void()>> run;
    run.swap(t_afterWrite);
    for (auto& fn : run) runDropping(fn);
    run.clear();
    if (t_afterWrite.empty()) t_afterWrite.swap(run);
}

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
    accept();

    NetworkLock lock(*this);
    bool reject = activeConnections >= config.maxConnections;
    if (stopping ||
        (reject && rejectedConnections >= std::max<std::size_t>(config.maxConnections, 16))) {
        socket.close(ignored);  // flooded: not even an ERR
        return;
    }
    int fd = socket.release(ignored);
    if (fd < 0) return;
    ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK);  // the thread blocks in recv()
    auto c = std::make_shared<TcpServerConnection>(*this, fd, std::move(peer), reject);
    threadStarted();
    try {
        std::thread([c, this]() mutable {
            c->run();
            c.reset();  // before threadFinished(): stop() may destroy the server then
            threadFinished();
        }).detach();
    } catch (const std::system_error&) {
        threadFinished();  // no thread (resource limit): the connection is dropped
        return;
    }
    connections.insert(c);
    if (reject)
        ++rejectedConnections;
    else
        ++activeConnections;
    connectionCount.store(activeConnections, std::memory_order_relaxed);
}

void TcpServer::Impl::threadStarted() {
    std::lock_guard l(threadsMutex);
    ++liveThreads;
}

void TcpServer::Impl::threadFinished() {
    std::lock_guard l(threadsMutex);
    if (--liveThreads == 0) threadsDone.notify_all();
}

// Under the network lock.
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
            // The upper layer's problem; the connection is gone anyway.
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
    NetworkLock lock(*this);
    auto now = Clock::now();
    sweepList.assign(connections.begin(), connections.end());
    for (auto& c : sweepList) c->housekeeping(now);
    sweepList.clear();
}

void TcpServer::Impl::scheduleTick(std::uint64_t generation) {
    if (tickPeriod.count() <= 0 || !tickFn) return;
    tickTimer.expires_after(tickPeriod);
    tickTimer.async_wait([this, generation](const asio::error_code& ec) {
        if (ec) return;
        NetworkLock lock(*this);
        if (generation != tickGeneration) return;
        runDropping(tickFn);
        if (generation == tickGeneration) scheduleTick(generation);
    });
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
    {
        std::lock_guard l(i.networkMutex);
        i.stopping = false;
    }
    i.io.restart();
    i.work.emplace(asio::make_work_guard(i.io));
    i.accept();
    i.scheduleHousekeeping();
    {
        std::lock_guard l(i.networkMutex);
        i.scheduleTick(i.tickGeneration);
    }
    i.running.store(true);
    i.serviceThread = std::thread([&i] { i.io.run(); });
}

void TcpServer::stop() {
    auto& i = *impl_;
    if (!i.running.load()) return;
    if (isNetworkThread()) throw std::logic_error("TcpServer::stop() called on the network thread");
    // 1. No new connections, no timers.
    std::promise<void> quiet;
    asio::post(i.io, [&i, &quiet] {
        asio::error_code ignored;
        i.acceptor.close(ignored);
        i.housekeepingTimer.cancel();
        i.acceptRetryTimer.cancel();
        i.tickTimer.cancel();
        quiet.set_value();
    });
    quiet.get_future().wait();
    // 2. Every connection closes at once (onConnectionClosed for each, under the lock).
    {
        NetworkLock lock(i);
        i.stopping = true;
        ++i.tickGeneration;
        for (auto& c : i.connections) c->requestStop();
    }
    {
        std::unique_lock l(i.threadsMutex);
        i.threadsDone.wait(l, [&i] { return i.liveThreads == 0; });
    }
    // 3. The service thread. Handlers still queued (sends posted by other threads) are
    // destroyed with the io_context; nothing of them needs to run.
    i.work.reset();
    i.io.stop();
    if (i.serviceThread.joinable()) i.serviceThread.join();
    {
        std::lock_guard l(i.networkMutex);
        i.connections.clear();
        i.dirty.clear();
    }
    i.running.store(false);
    i.connectionCount.store(0);
}

bool TcpServer::running() const { return impl_->running.load(); }
UInt16 TcpServer::port() const { return impl_->boundPort; }
const ServerTransportConfig& TcpServer::config() const { return impl_->config; }

std::size_t TcpServer::connectionCount() const {
    return impl_->connectionCount.load(std::memory_order_relaxed);
}

void TcpServer::post(std::function<void()> fn) {
    auto* i = impl_.get();
    asio::post(i->io, [i, fn = std::move(fn)] {
        NetworkLock lock(*i);
        runDropping(fn);
    });
}

bool TcpServer::isNetworkThread() const { return impl_->holdsNetworkLock(); }

void TcpServer::afterResponsesWritten(std::function<void()> fn) {
    if (impl_->holdsNetworkLock())
        t_afterWrite.push_back(std::move(fn));
    else
        runDropping(fn);
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
    if (!i->running.load()) {
        std::lock_guard l(i->networkMutex);
        apply();
    } else {
        asio::post(i->io, [i, apply = std::move(apply)]() mutable {
            NetworkLock lock(*i);
            apply();
        });
    }
}

}  // namespace pnp::ua::transport
