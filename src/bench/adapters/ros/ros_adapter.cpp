// ROS 1 (roscpp 1.15, TCPROS) for the middleware evaluation; README.md beside this file says
// exactly what it does. In short:
//   topic    the client publishes /pnp/request, the server answers on /pnp/reply
//   service  the client calls the service /pnp/call over one persistent connection
//   chain    one ROS node per process (roscpp's ros::init is per process, and roscpp would
//            deliver between nodes of one process without TCP): `node --count C` forks C
//            children, child i subscribes /pnp/chain/<i> and publishes /pnp/chain/<i+1> or,
//            last of its stream, /pnp/chain/sink.
// Messages are the hand-written uint8[] types of ros_messages.hpp. Every subscriber asks for
// TCP_NODELAY (ros::TransportHints().tcpNoDelay()). The master (rosmaster --core) is started
// by the runner; its URI is the setting `master` (default: $ROS_MASTER_URI, else
// http://127.0.0.1:11311); --local is the address this node advertises (__ip / __hostname).
#include <arpa/inet.h>
#include <dirent.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <ros/ros.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <iostream>
#include <map>
#include <mutex>
#include <thread>

#include "bench/adapters/ros/ros_messages.hpp"
#include "bench/driver/driver.hpp"

namespace pnp::bench::ros {
namespace {

using driver::Clock;
using driver::Options;
using std::chrono::milliseconds;

const std::string kRequestTopic = "/pnp/request";
const std::string kReplyTopic = "/pnp/reply";
const std::string kService = "/pnp/call";
const std::string kChainSink = "/pnp/chain/sink";
constexpr std::uint32_t kQueue = 1000;  // messages a subscriber / publisher may hold

std::string chainTopic(int node) { return "/pnp/chain/" + std::to_string(node); }

std::string masterUri(const Options& o) {
    const char* env = std::getenv("ROS_MASTER_URI");
    return o.setting("master", env && *env ? env : "http://127.0.0.1:11311");
}

// A setting in milliseconds, 1 ms .. 1 h.
int msSetting(const Options& o, const std::string& key, int fallback) {
    const std::string v = o.setting(key, std::to_string(fallback));
    try {
        std::size_t used = 0;
        const int ms = std::stoi(v, &used);
        if (used == v.size() && ms >= 1 && ms <= 3600000) return ms;
    } catch (const std::exception&) {
    }
    throw std::invalid_argument("setting " + key + "=" + v + " is not 1 .. 3600000 ms");
}

// How long a process waits for the master and for its peers before it gives up.
milliseconds connectTimeout(const Options& o) {
    return milliseconds(msSetting(o, "connect-timeout-ms", o.timeoutMs));
}

bool isIpAddress(const std::string& s) {
    unsigned char buf[16];
    return inet_pton(AF_INET, s.c_str(), buf) == 1 || inet_pton(AF_INET6, s.c_str(), buf) == 1;
}

// This process's ROS node: ros::init with the master and the advertised address, quiet
// logging, then a bounded wait for the master (roscpp itself would retry registering
// forever). ros::shutdown() on destruction.
class RosNode {
  public:
    RosNode(const Options& o, const std::string& role) : master_(masterUri(o)) {
        ::ros::M_string remap;
        remap["__master"] = master_;
        remap[isIpAddress(o.local) ? "__ip" : "__hostname"] = o.local;
        const std::string name = "pnp_mw_ros_" + role + "_" + std::to_string(::getpid());
        // The driver handles SIGINT / SIGTERM; no /rosout publisher (it is not measured).
        ::ros::init(remap, name,
                    ::ros::init_options::NoSigintHandler | ::ros::init_options::NoRosout);
        // roscpp logs INFO on stdout, which carries READY and the JSON results.
        if (::ros::console::set_logger_level(ROSCONSOLE_ROOT_LOGGER_NAME,
                                             ::ros::console::levels::Warn))
            ::ros::console::notifyLoggerLevelsChanged();
        const auto timeout = connectTimeout(o);
        const auto deadline = Clock::now() + timeout;
        while (!::ros::master::check()) {
            if (Clock::now() >= deadline) {
                ::ros::shutdown();
                throw std::runtime_error("ROS master at " + master_ + " unreachable within " +
                                         std::to_string(timeout.count()) + " ms");
            }
            std::this_thread::sleep_for(milliseconds(100));
        }
        ::ros::master::setRetryTimeout(
            ::ros::WallDuration(static_cast<double>(timeout.count()) / 1e3));
        handle_ = std::make_unique<::ros::NodeHandle>();
    }
    ~RosNode() {
        handle_.reset();
        ::ros::shutdown();
    }
    RosNode(const RosNode&) = delete;
    RosNode& operator=(const RosNode&) = delete;

    ::ros::NodeHandle& handle() { return *handle_; }
    const std::string& master() const { return master_; }

  private:
    std::string master_;
    std::unique_ptr<::ros::NodeHandle> handle_;
};

void waitForStop(const std::stop_token& stop) {
    std::mutex m;
    std::condition_variable_any cv;
    std::unique_lock lock(m);
    cv.wait(lock, stop, [] { return false; });
}

template <class M>
::ros::Subscriber subscribe(::ros::NodeHandle& nh, const std::string& topic,
                            const boost::function<void(const boost::shared_ptr<const M>&)>& cb) {
    ::ros::SubscribeOptions ops;
    ops.template init<M>(topic, kQueue, cb);
    ops.transport_hints = ::ros::TransportHints().tcpNoDelay();
    return nh.subscribe(ops);
}

// Polls `done` every 10 ms until it holds or the deadline passes.
template <class Pred>
bool waitUntil(Clock::time_point deadline, Pred done) {
    while (!done()) {
        if (Clock::now() >= deadline) return false;
        std::this_thread::sleep_for(milliseconds(10));
    }
    return true;
}

void toBytes(const std::vector<std::uint8_t>& in, driver::Bytes& out) {
    out.resize(in.size());
    if (!in.empty()) std::memcpy(out.data(), in.data(), in.size());
}

void fromBytes(std::span<const std::byte> in, std::vector<std::uint8_t>& out) {
    out.resize(in.size());
    if (!in.empty()) std::memcpy(out.data(), in.data(), in.size());
}

// ---- topic ---------------------------------------------------------------------------------

class TopicClient final : public driver::Client {
  public:
    explicit TopicClient(const Options& o)
        : timeout_(o.timeoutMs), node_(o, "client"), spinner_(1) {
        auto& nh = node_.handle();
        publisher_ = nh.advertise<Bytes>(kRequestTopic, kQueue);
        subscriber_ = subscribe<Bytes>(nh, kReplyTopic, [this](const Bytes::ConstPtr& m) {
            std::lock_guard lock(mutex_);
            reply_ = m;
            arrived_.notify_one();
        });
        spinner_.start();
        // Both connections up before the first request: the server subscribes our requests
        // and we receive its replies.
        const auto wait = connectTimeout(o);
        const auto deadline = Clock::now() + wait;
        if (!waitUntil(deadline, [&] {
                return publisher_.getNumSubscribers() > 0 && subscriber_.getNumPublishers() > 0;
            }))
            throw std::runtime_error(
                "no ROS topic server within " + std::to_string(wait.count()) + " ms (" +
                kRequestTopic + " subscribers: " + std::to_string(publisher_.getNumSubscribers()) +
                ", " + kReplyTopic +
                " publishers: " + std::to_string(subscriber_.getNumPublishers()) + ", master " +
                node_.master() + ")");
        // The counts say a connection exists, not that its header exchange is done on the
        // server's side: an empty probe until one is answered, then late answers are dropped.
        for (;;) {
            message_.data.clear();
            {
                std::lock_guard lock(mutex_);
                reply_.reset();
            }
            publisher_.publish(message_);
            std::unique_lock lock(mutex_);
            if (arrived_.wait_for(lock, milliseconds(500), [&] { return reply_ != nullptr; }))
                break;
            if (Clock::now() >= deadline)
                throw std::runtime_error("the ROS topic server does not answer within " +
                                         std::to_string(wait.count()) + " ms");
        }
        std::this_thread::sleep_for(milliseconds(50));
        std::lock_guard lock(mutex_);
        reply_.reset();
    }

    ~TopicClient() override { spinner_.stop(); }

    void request(std::span<const std::byte> payload, driver::Bytes& reply) override {
        fromBytes(payload, message_.data);
        {
            std::lock_guard lock(mutex_);
            reply_.reset();
        }
        publisher_.publish(message_);
        Bytes::ConstPtr got;
        {
            std::unique_lock lock(mutex_);
            if (!arrived_.wait_for(lock, timeout_, [&] { return reply_ != nullptr; }))
                throw std::runtime_error("no reply on " + kReplyTopic + " within " +
                                         std::to_string(timeout_.count()) + " ms");
            got = std::move(reply_);
        }
        toBytes(got->data, reply);
    }

  private:
    // What the subscriber callback touches is declared first: destroyed after the spinner
    // and the subscriber, also when the constructor throws.
    milliseconds timeout_;
    std::mutex mutex_;
    std::condition_variable arrived_;
    Bytes::ConstPtr reply_;
    Bytes message_;
    RosNode node_;
    ::ros::AsyncSpinner spinner_;
    ::ros::Publisher publisher_;
    ::ros::Subscriber subscriber_;
};

void runTopicServer(driver::ServerContext& ctx, RosNode& node) {
    const bool echo = ctx.options.mode == driver::Mode::Echo;
    auto& nh = node.handle();
    ::ros::Publisher reply = nh.advertise<Bytes>(kReplyTopic, kQueue);
    Bytes ack;
    ack.data = {1};
    // Runs on the spinner thread; publish() only serializes and queues / writes.
    ::ros::Subscriber sub = subscribe<Bytes>(
        nh, kRequestTopic, [&](const Bytes::ConstPtr& m) { reply.publish(echo ? *m : ack); });
    ::ros::AsyncSpinner spinner(1);
    spinner.start();
    ctx.ready();
    waitForStop(ctx.stop);
    spinner.stop();
}

// roscpp has no TCP_NODELAY hint for service connections. With setting service-nodelay=1
// (the default) it is set on every TCP socket of this process: on the server's listening
// sockets (accepted connections inherit it on Linux) and on the client's open connections.
bool serviceNoDelay(const Options& o) { return o.setting("service-nodelay", "1") != "0"; }

int noDelayOnAllTcpSockets() {
    DIR* dir = ::opendir("/proc/self/fd");
    if (!dir) return 0;
    int n = 0;
    while (const dirent* e = ::readdir(dir)) {
        const int fd = std::atoi(e->d_name);
        if (fd <= 2 || fd == ::dirfd(dir)) continue;
        int type = 0, domain = 0;
        socklen_t len = sizeof type;
        if (::getsockopt(fd, SOL_SOCKET, SO_TYPE, &type, &len) != 0 || type != SOCK_STREAM)
            continue;
        len = sizeof domain;
        if (::getsockopt(fd, SOL_SOCKET, SO_DOMAIN, &domain, &len) != 0 ||
            (domain != AF_INET && domain != AF_INET6))
            continue;
        int one = 1;
        if (::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one) == 0) ++n;
    }
    ::closedir(dir);
    return n;
}

// ---- service -------------------------------------------------------------------------------

class ServiceClient final : public driver::Client {
  public:
    explicit ServiceClient(const Options& o) : timeout_(o.timeoutMs), node_(o, "client") {
        const auto wait = connectTimeout(o);
        if (!::ros::service::waitForService(kService, static_cast<std::int32_t>(wait.count())))
            throw std::runtime_error("no ROS service " + kService + " within " +
                                     std::to_string(wait.count()) + " ms (master " +
                                     node_.master() + ")");
        // Persistent: one TCP connection for all calls (otherwise every call asks the master
        // and connects anew).
        client_ = node_.handle().serviceClient<ByteCallRequest, ByteCallResponse>(kService, true);
        // roscpp's call() has no timeout: a watchdog drops the connection of a call that is
        // overdue, which makes call() return false. It stays off the timed path.
        watchdog_ = std::jthread([this](std::stop_token stop) {
            std::mutex m;
            std::condition_variable_any cv;
            std::unique_lock lock(m);
            while (!stop.stop_requested()) {
                cv.wait_for(lock, stop, milliseconds(20), [] { return false; });
                const auto started = callStarted_.load();
                if (started != 0 && Clock::now().time_since_epoch().count() - started >
                                        std::chrono::nanoseconds(timeout_).count()) {
                    overdue_ = true;
                    client_.shutdown();
                    return;
                }
            }
        });
        // A first call opens the persistent connection (then TCP_NODELAY can be set on it).
        request_.data.clear();
        call();
        if (serviceNoDelay(o)) noDelayOnAllTcpSockets();
    }

    ~ServiceClient() override { watchdog_ = {}; }

    void request(std::span<const std::byte> payload, driver::Bytes& reply) override {
        fromBytes(payload, request_.data);
        call();
        toBytes(response_.data, reply);
    }

  private:
    // request_ -> response_, bounded by the watchdog.
    void call() {
        callStarted_ = Clock::now().time_since_epoch().count();
        const bool ok = client_.call(request_, response_);
        callStarted_ = 0;
        if (overdue_)
            throw std::runtime_error("no answer from " + kService + " within " +
                                     std::to_string(timeout_.count()) + " ms");
        if (!ok) throw std::runtime_error("the call of " + kService + " failed");
    }

    milliseconds timeout_;
    RosNode node_;
    ::ros::ServiceClient client_;
    ByteCallRequest request_;
    ByteCallResponse response_;
    std::atomic<Clock::rep> callStarted_{0};
    std::atomic<bool> overdue_{false};
    std::jthread watchdog_;  // last: stopped first
};

void runServiceServer(driver::ServerContext& ctx, RosNode& node) {
    const bool echo = ctx.options.mode == driver::Mode::Echo;
    ::ros::AdvertiseServiceOptions ops;
    ops.init<ByteCallRequest, ByteCallResponse>(
        kService, [echo](ByteCallRequest& req, ByteCallResponse& res) {
            if (echo)
                res.data.swap(req.data);
            else
                res.data.assign(1, 1);
            return true;
        });
    ::ros::ServiceServer server = node.handle().advertiseService(ops);
    if (serviceNoDelay(ctx.options)) noDelayOnAllTcpSockets();
    ::ros::AsyncSpinner spinner(1);
    spinner.start();
    ctx.ready();
    waitForStop(ctx.stop);
    spinner.stop();
}

void runServer(driver::ServerContext& ctx) {
    RosNode node(ctx.options, "server");
    if (ctx.options.variant == "service")
        runServiceServer(ctx, node);
    else
        runTopicServer(ctx, node);
}

// ---- chain ---------------------------------------------------------------------------------

// Chain node i in this process (one ROS node per process).
void runOneChainNode(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const int i = o.first;
    RosNode node(o, "chain" + std::to_string(i));
    auto& nh = node.handle();
    ::ros::Publisher next =
        nh.advertise<Bytes>((i + 1) % o.hops == 0 ? kChainSink : chainTopic(i + 1), kQueue);
    ::ros::Subscriber in =
        subscribe<Bytes>(nh, chainTopic(i), [&](const Bytes::ConstPtr& m) { next.publish(*m); });
    ::ros::AsyncSpinner spinner(1);
    spinner.start();
    ctx.ready();
    waitForStop(ctx.stop);
    spinner.stop();
}

// This executable's path (children show as pnp-mw-ros in ps, not as "exe").
std::string selfPath() {
    char buf[4096];
    const ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
    if (n <= 0) throw std::runtime_error("cannot read /proc/self/exe");
    return std::string(buf, static_cast<std::size_t>(n));
}

// The command line of child node i: this executable, `node --count 1`, the same settings.
std::vector<std::string> childArgs(const Options& o, int i) {
    std::vector<std::string> a = {selfPath(),  "node",
                                  "--first",   std::to_string(i),
                                  "--count",   "1",
                                  "--variant", o.variant,
                                  "--host",    o.host,
                                  "--local",   o.local,
                                  "--streams", std::to_string(o.streams),
                                  "--hops",    std::to_string(o.hops)};
    if (o.port) a.insert(a.end(), {"--port", std::to_string(o.port)});
    for (const auto& [k, v] : o.settings) a.insert(a.end(), {"--set", k + "=" + v});
    return a;
}

struct Child {
    pid_t pid = -1;
    int out = -1;  // its stdout
    std::string pending;
    bool ready = false;
};

// SIGTERM to every child still running, up to 5 s, then SIGKILL; all reaped.
void stopChildren(std::vector<Child>& children) {
    for (auto& c : children)
        if (c.pid > 0) ::kill(c.pid, SIGTERM);
    const auto end = Clock::now() + std::chrono::seconds(5);
    for (auto& c : children) {
        while (c.pid > 0) {
            const pid_t r = ::waitpid(c.pid, nullptr, WNOHANG);
            if (r == c.pid || (r < 0 && errno != EINTR)) {
                c.pid = -1;
            } else if (Clock::now() >= end) {
                ::kill(c.pid, SIGKILL);
                ::waitpid(c.pid, nullptr, 0);
                c.pid = -1;
            } else {
                std::this_thread::sleep_for(milliseconds(10));
            }
        }
        if (c.out >= 0) ::close(c.out);
        c.out = -1;
    }
}

// Reads what a child printed; true when it printed READY.
bool readChild(Child& c) {
    char buf[512];
    for (;;) {
        const ssize_t r = ::read(c.out, buf, sizeof buf);
        if (r <= 0) break;
        c.pending.append(buf, static_cast<std::size_t>(r));
        if (c.pending.size() > 65536) c.pending.erase(0, c.pending.size() - 4096);
    }
    std::size_t nl;
    while ((nl = c.pending.find('\n')) != std::string::npos) {
        if (c.pending.compare(0, nl, "READY") == 0 && nl == 5) c.ready = true;
        c.pending.erase(0, nl + 1);
    }
    return c.ready;
}

void spawn(Child& c, const std::vector<std::string>& argv) {
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0)
        throw std::runtime_error("pipe: " + std::string(std::strerror(errno)));
    const pid_t parent = ::getpid();
    const pid_t pid = ::fork();
    if (pid < 0) {
        ::close(fds[0]);
        ::close(fds[1]);
        throw std::runtime_error("fork: " + std::string(std::strerror(errno)));
    }
    if (pid == 0) {
        // Only async-signal-safe calls until exec. The child ends when this process does.
        ::prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (::getppid() != parent) ::_exit(127);
        ::dup2(fds[1], STDOUT_FILENO);
        ::execv(args[0], args.data());
        ::_exit(127);
    }
    ::close(fds[1]);
    ::fcntl(fds[0], F_SETFL, O_NONBLOCK);
    c.pid = pid;
    c.out = fds[0];
}

// Nodes first .. first+count-1 as child processes; READY once all are.
void runChainChildren(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    std::vector<Child> children(static_cast<std::size_t>(o.count));
    struct Reaper {
        std::vector<Child>& c;
        ~Reaper() { stopChildren(c); }
    } reaper{children};
    for (int k = 0; k < o.count; ++k)
        spawn(children[static_cast<std::size_t>(k)], childArgs(o, o.first + k));

    const milliseconds readyTimeout(msSetting(o, "ready-timeout-ms", 120000));
    const auto deadline = Clock::now() + readyTimeout;
    auto exited = [&]() -> const Child* {
        for (auto& c : children)
            if (c.pid > 0 && ::waitpid(c.pid, nullptr, WNOHANG) == c.pid) {
                c.pid = -1;
                return &c;
            }
        return nullptr;
    };
    auto name = [&](const Child& c) {
        return "chain node " + std::to_string(o.first + static_cast<int>(&c - children.data()));
    };
    for (;;) {
        std::size_t ready = 0;
        for (auto& c : children) ready += readChild(c) ? 1 : 0;
        if (ready == children.size()) break;
        if (const Child* dead = exited())
            throw std::runtime_error(name(*dead) + " exited before it was ready");
        if (ctx.stop.stop_requested()) return;
        if (Clock::now() >= deadline)
            throw std::runtime_error(
                std::to_string(ready) + " of " + std::to_string(children.size()) +
                " chain nodes ready within " + std::to_string(readyTimeout.count()) + " ms");
        std::vector<pollfd> fds;
        for (auto& c : children)
            if (!c.ready) fds.push_back({c.out, POLLIN, 0});
        ::poll(fds.data(), fds.size(), 100);
    }
    ctx.ready();
    while (!ctx.stop.stop_requested()) {
        for (auto& c : children) readChild(c);  // keeps their stdout from filling up
        if (const Child* dead = exited())
            throw std::runtime_error(name(*dead) + " exited; the chain is broken");
        std::this_thread::sleep_for(milliseconds(100));
    }
}

void runChainNodes(driver::ServerContext& ctx) {
    if (ctx.options.count == 1)
        runOneChainNode(ctx);
    else
        runChainChildren(ctx);
}

// A probe that finds out whether a stream's nodes are all connected: "PNPPROBE" + stream.
constexpr char kProbeMagic[8] = {'P', 'N', 'P', 'P', 'R', 'O', 'B', 'E'};

std::vector<std::uint8_t> probe(int stream) {
    std::vector<std::uint8_t> p(12);
    std::memcpy(p.data(), kProbeMagic, 8);
    const auto s = static_cast<std::uint32_t>(stream);
    std::memcpy(p.data() + 8, &s, 4);
    return p;
}

int probeStream(const std::vector<std::uint8_t>& m) {
    if (m.size() != 12 || std::memcmp(m.data(), kProbeMagic, 8) != 0) return -1;
    std::uint32_t s = 0;
    std::memcpy(&s, m.data() + 8, 4);
    return static_cast<int>(s);
}

class ChainClient final : public driver::ChainClient {
  public:
    explicit ChainClient(const Options& o) : node_(o, "chainclient"), spinner_(1) {
        auto& nh = node_.handle();
        confirmed_.assign(static_cast<std::size_t>(o.streams), false);
        sink_ = subscribe<Bytes>(nh, kChainSink, [this](const Bytes::ConstPtr& m) {
            std::lock_guard lock(mutex_);
            const int s = probeStream(m->data);
            if (s >= 0) {
                if (s < static_cast<int>(confirmed_.size()))
                    confirmed_[static_cast<std::size_t>(s)] = true;
                return;  // probes (also late ones) never reach the driver
            }
            inbox_.push_back(m);
            arrived_.notify_one();
        });
        for (int s = 0; s < o.streams; ++s)
            firsts_.emplace(s * o.hops, nh.advertise<Bytes>(chainTopic(s * o.hops), kQueue));
        spinner_.start();
        // Every link of every stream connected: a probe per stream until it reaches the sink.
        const auto wait = connectTimeout(o);
        const auto deadline = Clock::now() + wait;
        for (;;) {
            std::vector<int> missing;
            {
                std::lock_guard lock(mutex_);
                for (int s = 0; s < o.streams; ++s)
                    if (!confirmed_[static_cast<std::size_t>(s)]) missing.push_back(s);
            }
            if (missing.empty()) break;
            if (Clock::now() >= deadline) {
                std::string list;
                for (std::size_t k = 0; k < missing.size() && k < 10; ++k)
                    list += (k ? ", " : "") + std::to_string(missing[k] * o.hops);
                throw std::runtime_error(
                    std::to_string(missing.size()) + " of " + std::to_string(o.streams) +
                    " ROS chain streams not connected end to end within " +
                    std::to_string(wait.count()) + " ms (first nodes: " + list + "; master " +
                    node_.master() + ")");
            }
            for (int s : missing) {
                Bytes p;
                p.data = probe(s);
                firsts_.at(s * o.hops).publish(p);
            }
            std::this_thread::sleep_for(milliseconds(200));
        }
    }

    ~ChainClient() override { spinner_.stop(); }

    void send(int node, std::span<const std::byte> message) override {
        auto it = firsts_.find(node);
        if (it == firsts_.end())
            throw std::runtime_error("chain node " + std::to_string(node) +
                                     " is not the first of a stream");
        fromBytes(message, message_.data);
        it->second.publish(message_);
    }

    bool receive(driver::Bytes& message, Clock::time_point deadline) override {
        Bytes::ConstPtr m;
        {
            std::unique_lock lock(mutex_);
            if (!arrived_.wait_until(lock, deadline, [&] { return !inbox_.empty(); })) return false;
            m = std::move(inbox_.front());
            inbox_.pop_front();
        }
        toBytes(m->data, message);
        return true;
    }

  private:
    // What the sink callback touches is declared first (see TopicClient).
    std::mutex mutex_;
    std::condition_variable arrived_;
    std::deque<Bytes::ConstPtr> inbox_;
    std::vector<bool> confirmed_;
    Bytes message_;
    RosNode node_;
    ::ros::AsyncSpinner spinner_;
    ::ros::Subscriber sink_;
    std::map<int, ::ros::Publisher> firsts_;
};

}  // namespace
}  // namespace pnp::bench::ros

int main(int argc, char** argv) {
    namespace driver = pnp::bench::driver;
    namespace rosmw = pnp::bench::ros;
    driver::Adapter a;
    a.name = "ros";
    a.variants = {"topic", "service"};
    a.description =
        "ROS 1 roscpp 1.15 (TCPROS, TCP_NODELAY, rosmaster): topic = request/reply topics, "
        "service = persistent service call; uint8[] messages; chain: one node per process";
    a.makeClient = [](const driver::Options& o) -> std::unique_ptr<driver::Client> {
        if (o.variant == "service") return std::make_unique<rosmw::ServiceClient>(o);
        return std::make_unique<rosmw::TopicClient>(o);
    };
    a.runServer = rosmw::runServer;
    a.runChainNodes = rosmw::runChainNodes;
    a.makeChainClient = [](const driver::Options& o) {
        return std::make_unique<rosmw::ChainClient>(o);
    };
    return driver::adapterMain(argc, argv, a);
}
