#include "ua/transport/tcp_server.hpp"

#include <fcntl.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
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
// An event loop wakes at least this often to finish lingering connections whose time is up.
constexpr std::chrono::milliseconds kLoopSweep{100};
// Events taken from epoll_wait() at once; with many busy clients one wake-up serves up to
// this many requests under one acquisition of the network lock.
constexpr int kMaxEvents = 64;
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

}  // namespace

class TcpServerConnection;

// One I/O thread: an epoll set of connections. Level-triggered: a connection is read once
// per wake-up (the rest, if any, wakes the loop again), so a request costs epoll_wait(),
// recv() and the response's sendmsg(); everything the loop read in one wake-up is handed to
// the protocol under one acquisition of the network lock.
class EventLoop {
  public:
    explicit EventLoop(TcpServer::Impl& server);
    ~EventLoop();
    EventLoop(const EventLoop&) = delete;
    EventLoop& operator=(const EventLoop&) = delete;

    // Any thread. The connection has been started (TcpServerConnection::start()). False when
    // epoll refuses it (resource limit).
    bool add(const std::shared_ptr<TcpServerConnection>& c);
    // Finishes every connection (onConnectionClosed for each) and joins the thread.
    void stop();
    std::size_t size() const { return count_.load(std::memory_order_relaxed); }
    // Any thread: the epoll set's interest in c's socket.
    void watch(int fd, TcpServerConnection* c, std::uint32_t events) const;
    // Any thread: a connection's channel closed; the loop starts its linger time.
    void nudge() const;

  private:
    void run();
    void takeAdded();
    // Finishes the connections that are done; returns how many linger.
    std::size_t sweep(TimePoint now);
    void finish(TcpServerConnection* c);

    TcpServer::Impl& server_;
    int epoll_ = -1;
    int wake_ = -1;  // eventfd: stop(), nudge()
    std::thread thread_;
    std::atomic<bool> stop_{false};
    std::atomic<std::size_t> count_{0};
    std::mutex addedMutex_;
    std::vector<std::shared_ptr<TcpServerConnection>> added_;  // not yet in conns_
    std::atomic<bool> hasAdded_{false};
    // The loop thread's only.
    std::vector<std::shared_ptr<TcpServerConnection>> conns_;
};

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
    void startLoops();
    // The automatic loop count (eventLoops 0): one per core, and up to one more per core,
    // started once every loop serves kConnectionsPerLoop connections. On a machine that the
    // server shares with busy processes (its clients on loopback, the cell's other servers)
    // a loop that waits for a CPU keeps collecting requests instead of sleeping and being
    // woken for each: larger batches, fewer context switches per request (measured:
    // bench/README.md, "Load"). With few connections extra loops would only split batches.
    static constexpr std::size_t kConnectionsPerLoop = 8;
    std::size_t loopsWanted(std::size_t connections) const;
    std::size_t baseLoops = 1;
    std::size_t maxLoops = 1;
    void stopLoops();
    UInt32 newChannelId() {
        UInt32 id = nextChannelId++;
        if (nextChannelId == 0) nextChannelId = 1;
        return id == 0 ? newChannelId() : id;
    }
    bool holdsNetworkLock() const;

    ServerTransportConfig config;
    ServiceHandler& handler;
    // The service thread: accepts, runs the timers and the functions post()ed to the
    // network thread. Connections do their I/O on the event loops.
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

    // The event loops that do the connections' I/O: baseLoops started by start(), more
    // (up to maxLoops) by onAccepted() under the network lock; all joined by stop().
    std::vector<std::unique_ptr<EventLoop>> loops;

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
// (without blocking: the connection's loop finishes what the socket does not take at once).
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
// One accepted connection on its event loop. The loop reads it (onEvents()), runs the
// secure channel and the upper layer under the network lock (receivedInput()), writes what
// the socket did not take at once (EPOLLOUT) and finishes it (finish()).
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

    // ---- the event loop's thread -----------------------------------------------------------
    // Before the connection joins its loop (the service thread, under the network lock).
    void start(EventLoop* loop) {
        loop_ = loop;
        me_ = self();
        if (rejected_) channel_.fail(status::BadTcpServerTooBusy, "too many connections");
        noteClosed();
        space_ = channel_.readSpace();
    }
    int fd() const { return fd_; }
    // Instead of joining a loop (under the network lock): the socket closes with the object.
    void abandon() {
        me_.reset();
        loop_ = nullptr;
        closedFlag_.store(true, std::memory_order_release);
        finished_ = true;
    }

    // What happened on the socket; returns true when input waits for the protocol
    // (receivedInput(), under the network lock). Outside the network lock.
    bool onEvents(std::uint32_t events, Byte* sink, std::size_t sinkSize) {
        if (events & EPOLLOUT) {
            if (writeQueued() == WriteResult::Error) return false;
            finIfDone();
        }
        if ((events & (EPOLLIN | EPOLLERR | EPOLLHUP)) == 0) return false;
        if (closing_.load(std::memory_order_acquire)) {
            // Lingering: read and discard until the peer closes.
            ssize_t n = ::recv(fd_, sink, sinkSize, 0);
            if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR))
                eof_ = true;
            return false;
        }
        ssize_t n = ::recv(fd_, space_.data(), space_.size(), 0);
        if (n > 0) {
            received_ = static_cast<std::size_t>(n);
            return true;
        }
        if (n == 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) eof_ = true;
        return false;  // closed or reset, possibly in the middle of a message
    }

    // Under the network lock, after onEvents() returned true.
    void receivedInput(TimePoint now) {
        applyCloseRequest();
        if (!closing_.load(std::memory_order_relaxed))
            channel_.received(received_, now);  // never throws
        received_ = 0;
        noteClosed();
        space_ = channel_.readSpace();
    }

    // True when the loop should finish this connection: the peer is gone, the socket broke
    // or the linger time is over. Sets the linger deadline when the channel has closed.
    bool done(TimePoint now) {
        if (eof_ || broken_.load(std::memory_order_acquire)) return true;
        if (!closing_.load(std::memory_order_acquire)) return false;
        if (lingerUntil_ == TimePoint{}) lingerUntil_ = now + kLinger;
        return now >= lingerUntil_;
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
                if (err == EAGAIN || err == EWOULDBLOCK) {
                    // The loop writes the rest when the socket has room; while the backlog
                    // is large it reads no requests (backpressure).
                    watch(EPOLLOUT | (queued_ <= kMaxQueuedOutput ? EPOLLIN : 0u));
                    return WriteResult::Stalled;
                }
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
                watch(EPOLLIN);
                return WriteResult::Drained;
            }
        }
    }

  private:
    std::shared_ptr<TcpServerConnection> self() {
        return std::static_pointer_cast<TcpServerConnection>(shared_from_this());
    }

    // Under outMutex_: the loop's interest in the socket, changed only when it differs.
    void watch(std::uint32_t events) {
        if (events == watched_ || broken_ || loop_ == nullptr) return;
        watched_ = events;
        loop_->watch(fd_, this, events);
    }

    // After writing (any thread): once a closed channel's output is all written, FIN at once.
    void finIfDone() {
        if (!closing_.load(std::memory_order_acquire)) return;
        std::lock_guard q(outMutex_);
        if (!writing_ && !broken_ && !finSent_ && outHead_ == out_.size()) {
            ::shutdown(fd_, SHUT_WR);
            finSent_ = true;
        }
    }

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
            if (loop_ != nullptr) loop_->nudge();  // the linger time starts
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

    // Under the network lock, from receivedInput().
    void request(const IncomingRequest& r) override { server_.handler.onRequest(me_, r); }

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
    // closed channel's output is all written, sends FIN at once (the loop lingers).
    void afterNetworkLock() {
        if (writeQueued() == WriteResult::Drained) finIfDone();
    }

  private:
  public:
    // On the loop's thread, once: the connection leaves its loop and the server.
    void finish(int epoll) {
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
        ::epoll_ctl(epoll, EPOLL_CTL_DEL, fd_, nullptr);
        ::close(fd_);
        fd_ = -1;
        auto me = self();
        me_.reset();
        server_.removeConnection(me, !rejected_);
    }

  private:
    TcpServer::Impl& server_;
    int fd_;  // closed (finish()) when no thread writes, under the network lock
    std::string peer_;
    ServerChannel channel_;  // under the network lock (readSpace: the loop's thread)
    bool rejected_;
    std::atomic<UInt32> channelId_{0};
    std::atomic<bool> closedFlag_{false};      // isClosed()
    std::atomic<std::size_t> postedSends_{0};  // sends queued to the service thread
    std::atomic<bool> closing_{false};         // the channel closed: linger, then finish
    std::atomic<bool> closeRequested_{false};  // close() from a thread without the lock
    bool finished_ = false;                    // under the network lock
    bool dirty_ = false;                       // in server_.dirty (network lock)
    // Handed to the upper layer with each request (no shared_from_this() per request);
    // from start() to finish().
    std::shared_ptr<ServerConnection> me_;
    EventLoop* loop_ = nullptr;  // set by start()

  public:
    // Where this connection is in its loop's list (the loop's thread only).
    std::size_t loopIndex = 0;

  private:
    // The loop's thread only.
    std::span<Byte> space_;     // where the next recv() goes (channel_.readSpace())
    std::size_t received_ = 0;  // bytes in space_ for receivedInput()
    bool eof_ = false;          // the peer closed or the socket failed
    TimePoint lingerUntil_{};   // set when the loop first sees the channel closed

    std::mutex outMutex_;  // guards the output state below
    std::condition_variable writerDone_;
    bool writing_ = false;  // a thread is writing (outside outMutex_, during sendmsg)
    // Socket error or finished: nobody writes any more (read by the loop without outMutex_).
    std::atomic<bool> broken_{false};
    bool finSent_ = false;             // shutdown(SHUT_WR) done
    std::uint32_t watched_ = EPOLLIN;  // the epoll interest (EventLoop::add's)
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
    ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) | O_NONBLOCK);  // the loop never blocks on it
    // Another loop when every loop serves kConnectionsPerLoop (up to maxLoops; if its thread
    // cannot start, the existing loops serve), then the loop with the fewest connections
    // among the ones wanted now: after a burst of connections the extra loops keep theirs
    // but get no new ones, so few connections are not spread thin again.
    const std::size_t wanted = loopsWanted(activeConnections + 1);
    while (loops.size() < wanted) {
        try {
            loops.push_back(std::make_unique<EventLoop>(*this));
        } catch (const std::exception&) {
            break;
        }
    }
    const std::size_t inUse = std::min(wanted, loops.size());
    EventLoop* loop = loops.front().get();
    for (std::size_t k = 1; k < inUse; ++k)
        if (loops[k]->size() < loop->size()) loop = loops[k].get();
    auto c = std::make_shared<TcpServerConnection>(*this, fd, std::move(peer), reject);
    c->start(loop);
    if (!loop->add(c)) {
        c->abandon();  // epoll refused it (resource limit): the connection is dropped
        return;
    }
    connections.insert(c);
    if (reject)
        ++rejectedConnections;
    else
        ++activeConnections;
    connectionCount.store(activeConnections, std::memory_order_relaxed);
}

// =======================================================================================
EventLoop::EventLoop(TcpServer::Impl& server) : server_(server) {
    epoll_ = ::epoll_create1(EPOLL_CLOEXEC);
    wake_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (epoll_ < 0 || wake_ < 0) {
        if (epoll_ >= 0) ::close(epoll_);
        if (wake_ >= 0) ::close(wake_);
        throw TransportError(status::BadResourceUnavailable, "cannot create an event loop");
    }
    epoll_event ev{};
    ev.events = EPOLLIN;
    ev.data.ptr = nullptr;  // the wake-up
    ::epoll_ctl(epoll_, EPOLL_CTL_ADD, wake_, &ev);
    thread_ = std::thread([this] { run(); });
}

EventLoop::~EventLoop() {
    stop();
    ::close(epoll_);
    ::close(wake_);
}

bool EventLoop::add(const std::shared_ptr<TcpServerConnection>& c) {
    {
        // Before the socket is watched: its first event finds it in added_.
        std::lock_guard l(addedMutex_);
        added_.push_back(c);
        hasAdded_.store(true, std::memory_order_release);
    }
    epoll_event ev{};
    ev.events = EPOLLIN;
    ev.data.ptr = c.get();
    if (::epoll_ctl(epoll_, EPOLL_CTL_ADD, c->fd(), &ev) != 0) {
        std::lock_guard l(addedMutex_);
        added_.erase(std::find(added_.begin(), added_.end(), c));
        return false;
    }
    count_.fetch_add(1, std::memory_order_relaxed);
    return true;
}

void EventLoop::watch(int fd, TcpServerConnection* c, std::uint32_t events) const {
    epoll_event ev{};
    ev.events = events;
    ev.data.ptr = c;
    ::epoll_ctl(epoll_, EPOLL_CTL_MOD, fd, &ev);
}

void EventLoop::nudge() const {
    std::uint64_t one = 1;
    [[maybe_unused]] auto n = ::write(wake_, &one, sizeof one);
}

void EventLoop::stop() {
    if (!thread_.joinable()) return;
    stop_.store(true, std::memory_order_release);
    nudge();
    thread_.join();
}

void EventLoop::takeAdded() {
    if (!hasAdded_.load(std::memory_order_acquire)) return;
    std::lock_guard l(addedMutex_);
    for (auto& c : added_) {
        c->loopIndex = conns_.size();
        conns_.push_back(std::move(c));
    }
    added_.clear();
    hasAdded_.store(false, std::memory_order_relaxed);
}

// O(1): the last connection takes c's place.
void EventLoop::finish(TcpServerConnection* c) {
    const std::size_t k = c->loopIndex;
    if (k >= conns_.size() || conns_[k].get() != c) return;  // finished already
    std::shared_ptr<TcpServerConnection> keep = std::move(conns_[k]);
    if (k + 1 != conns_.size()) {
        conns_[k] = std::move(conns_.back());
        conns_[k]->loopIndex = k;
    }
    conns_.pop_back();
    count_.fetch_sub(1, std::memory_order_relaxed);
    keep->finish(epoll_);
}

std::size_t EventLoop::sweep(TimePoint now) {
    std::size_t lingering = 0;
    for (std::size_t k = 0; k < conns_.size();) {
        if (conns_[k]->done(now)) {
            finish(conns_[k].get());  // conns_[k] is now another connection
        } else {
            lingering += conns_[k]->isClosed() ? 1 : 0;
            ++k;
        }
    }
    return lingering;
}

void EventLoop::run() {
    epoll_event events[kMaxEvents];
    TcpServerConnection* ready[kMaxEvents];
    TcpServerConnection* ended[kMaxEvents];
    Byte sink[4096];  // what lingering connections read is discarded here
    TimePoint nextSweep = Clock::now() + kLoopSweep;
    // Connections whose channel closed and that wait for their peer to close. Without them
    // the loop sleeps without a timeout: no timer is armed per wait (that costs a request
    // on a VM as much as a system call).
    std::size_t lingering = 0;
    while (!stop_.load(std::memory_order_acquire)) {
        int n = ::epoll_wait(epoll_, events, kMaxEvents,
                             lingering > 0 ? static_cast<int>(kLoopSweep.count()) : -1);
        if (stop_.load(std::memory_order_acquire)) break;
        takeAdded();
        std::size_t nReady = 0, nEnded = 0;
        for (int k = 0; k < n; ++k) {
            auto* c = static_cast<TcpServerConnection*>(events[k].data.ptr);
            if (c == nullptr) {  // nudge(): sweep now
                std::uint64_t count;
                [[maybe_unused]] auto r = ::read(wake_, &count, sizeof count);
                nextSweep = TimePoint{};
                continue;
            }
            if (c->onEvents(events[k].events, sink, sizeof sink))
                ready[nReady++] = c;
            else if (c->done(coarseNow()))
                ended[nEnded++] = c;
        }
        if (nReady > 0) {
            // Everything read in this wake-up, under one acquisition of the network lock; the
            // responses are written when it is released.
            const TimePoint now = coarseNow();
            NetworkLock lock(server_);
            for (std::size_t k = 0; k < nReady; ++k) ready[k]->receivedInput(now);
        }
        for (std::size_t k = 0; k < nEnded; ++k) finish(ended[k]);
        if (lingering > 0 || nextSweep == TimePoint{}) {
            const TimePoint now = Clock::now();
            if (now >= nextSweep) {
                lingering = sweep(now);
                nextSweep = now + kLoopSweep;
            }
        }
    }
    // Server stop: every connection ends at once (no linger).
    takeAdded();
    while (!conns_.empty()) finish(conns_.back().get());
}

void TcpServer::Impl::startLoops() {
    baseLoops = config.eventLoops;
    maxLoops = config.eventLoops;
    if (baseLoops == 0) {
        baseLoops = std::clamp<std::size_t>(std::thread::hardware_concurrency(), 1, 4);
        maxLoops = 2 * baseLoops;
    }
    for (std::size_t k = 0; k < baseLoops; ++k) loops.push_back(std::make_unique<EventLoop>(*this));
}

std::size_t TcpServer::Impl::loopsWanted(std::size_t connections) const {
    const std::size_t wanted = (connections + kConnectionsPerLoop - 1) / kConnectionsPerLoop;
    return std::clamp(wanted, baseLoops, maxLoops);
}

// Every connection ends (onConnectionClosed for each); not under the network lock.
void TcpServer::Impl::stopLoops() {
    for (auto& l : loops) l->stop();
    loops.clear();
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
    try {
        i.startLoops();
    } catch (...) {
        asio::error_code ignored;
        i.acceptor.close(ignored);
        i.stopLoops();
        throw;
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
    }
    i.stopLoops();
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

std::size_t TcpServer::runPosted() {
    auto& i = *impl_;
    if (i.running.load()) return 0;
    i.io.restart();
    return i.io.poll();
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
