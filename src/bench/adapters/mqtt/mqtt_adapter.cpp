// MQTT through a mosquitto broker (started by the runner, not here) with the Eclipse Paho C
// client's synchronous API (MQTTClient, libpaho-mqtt3c). See README.md in this folder.
//
// Request / reply over two topics, <prefix>/req and <prefix>/rep (setting topic-prefix,
// default "pnp/bench"): the server subscribes req and answers on rep (ACK: 1 byte; Echo: the
// payload). Every publish and subscription has the variant's QoS (qos0 / qos1). One client
// per prefix: two clients on the same prefix would see each other's replies.
//
// Receiving (setting receive) of the request/reply server and client: "sync" (default) - no
// callbacks, the waiting thread itself reads with MQTTClient_receive; "callback" - Paho's
// background thread calls messageArrived, which copies the message into an Inbox and wakes
// the waiting thread with a condition variable. Sync saves that hand-over and measured
// faster (README.md). Chain nodes always use callbacks (many connections in one process).
// Nothing is published from Paho's thread: MQTTClient_publish may wait there for the socket,
// and that thread is the one that would have to drain it.
//
// Chain: node i subscribes <prefix>/chain/<i> on a connection of its own and republishes to
// <prefix>/chain/<i+1>, or, for the last node of a stream, to <prefix>/chain/sink.
#include <MQTTClient.h>
#include <dirent.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <iostream>
#include <mutex>
#include <thread>

#include "bench/driver/driver.hpp"

namespace pnp::bench::mqtt {
namespace {

using driver::Bytes;
using driver::Clock;
using driver::Options;

constexpr int kDefaultPort = 1883;
constexpr std::size_t kMaxPayload = 64u << 20;
constexpr auto kPoll = std::chrono::milliseconds(100);  // how often a server checks for stop

int qosOf(const Options& o) { return o.variant == "qos1" ? 1 : 0; }

std::string brokerUri(const Options& o) {
    return "tcp://" + o.host + ":" + std::to_string(o.port ? o.port : kDefaultPort);
}

std::string prefixOf(const Options& o) {
    const std::string p = o.setting("topic-prefix", "pnp/bench");
    if (p.empty() || p.size() > 1000 || p.find_first_of("+#") != std::string::npos ||
        p.find('\0') != std::string::npos)
        throw std::invalid_argument("topic-prefix must be a non-empty topic without + or #: " + p);
    return p;
}

bool syncReceive(const Options& o) {
    const std::string r = o.setting("receive", "sync");
    if (r != "callback" && r != "sync")
        throw std::invalid_argument("setting receive is callback or sync, not " + r);
    return r == "sync";
}

bool noDelay(const Options& o) {
    const std::string v = o.setting("nodelay", "1");
    if (v != "0" && v != "1") throw std::invalid_argument("setting nodelay is 0 or 1, not " + v);
    return v == "1";
}

// Paho C has no option for TCP_NODELAY and does not expose its socket. Without it, a QoS 1
// PUBACK followed by the next PUBLISH waits for the peer's delayed ACK (Nagle): about 40 ms
// per direction. So every TCP socket of this process connected to the broker's port gets it
// (idempotent; called after each connect).
void setNoDelayTowards(int port) {
    DIR* dir = ::opendir("/proc/self/fd");
    if (!dir) return;
    while (const dirent* e = ::readdir(dir)) {
        char* end = nullptr;
        const long fd = std::strtol(e->d_name, &end, 10);
        if (end == e->d_name || *end != '\0' || fd == ::dirfd(dir)) continue;
        const int f = static_cast<int>(fd);
        int type = 0;
        socklen_t len = sizeof type;
        if (::getsockopt(f, SOL_SOCKET, SO_TYPE, &type, &len) != 0 || type != SOCK_STREAM) continue;
        sockaddr_storage peer{};
        len = sizeof peer;
        if (::getpeername(f, reinterpret_cast<sockaddr*>(&peer), &len) != 0) continue;
        int peerPort = -1;
        if (peer.ss_family == AF_INET)
            peerPort = ntohs(reinterpret_cast<const sockaddr_in*>(&peer)->sin_port);
        else if (peer.ss_family == AF_INET6)
            peerPort = ntohs(reinterpret_cast<const sockaddr_in6*>(&peer)->sin6_port);
        if (peerPort != port) continue;
        int one = 1;
        ::setsockopt(f, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    }
    ::closedir(dir);
}

std::string chainTopic(const std::string& prefix, int node) {
    return prefix + "/chain/" + std::to_string(node);
}

// A unique client id per connection: the broker drops an older session with the same id.
std::string clientId(const std::string& role) {
    static std::atomic<int> counter{0};
    return "pnpmw-" + role + "-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
}

std::string pahoError(int rc) {
    const char* s = MQTTClient_strerror(rc);
    return s ? std::string(s) + " (" + std::to_string(rc) + ")" : "error " + std::to_string(rc);
}

struct Message {
    int tag = 0;  // which connection received it (the chain node)
    Bytes payload;
};

// Messages handed over from Paho's thread to the thread that waits for them.
class Inbox {
  public:
    enum class Result { Got, Timeout, Failed };

    void push(int tag, const void* data, std::size_t size) {
        Message m{tag, Bytes(size)};
        if (size) std::memcpy(m.payload.data(), data, size);
        {
            std::lock_guard lock(mutex_);
            queue_.push_back(std::move(m));
        }
        ready_.notify_one();
    }

    void fail(const std::string& reason) {
        {
            std::lock_guard lock(mutex_);
            if (failure_.empty()) failure_ = reason;
        }
        ready_.notify_all();
    }

    // Queued messages come first, then a failure, then the timeout.
    Result pop(Message& out, Clock::time_point deadline, std::string& failure) {
        std::unique_lock lock(mutex_);
        ready_.wait_until(lock, deadline, [&] { return !queue_.empty() || !failure_.empty(); });
        if (!queue_.empty()) {
            out = std::move(queue_.front());
            queue_.pop_front();
            return Result::Got;
        }
        if (!failure_.empty()) {
            failure = failure_;
            return Result::Failed;
        }
        return Result::Timeout;
    }

  private:
    std::mutex mutex_;
    std::condition_variable ready_;
    std::deque<Message> queue_;
    std::string failure_;
};

// One MQTT connection (one Paho client handle). With an inbox, messages arrive by callback
// on Paho's thread; without, they are read with receive().
class Connection {
  public:
    Connection(const Options& o, const std::string& role, Inbox* inbox, int tag = 0)
        : uri_(brokerUri(o)), inbox_(inbox), tag_(tag) {
        int rc = MQTTClient_create(&handle_, uri_.c_str(), clientId(role).c_str(),
                                   MQTTCLIENT_PERSISTENCE_NONE, nullptr);
        if (rc != MQTTCLIENT_SUCCESS) {
            handle_ = nullptr;
            throw std::runtime_error("cannot create an MQTT client for " + uri_ + ": " +
                                     pahoError(rc));
        }
        if (inbox_) {
            rc = MQTTClient_setCallbacks(handle_, this, &Connection::onLost, &Connection::onMessage,
                                         nullptr);
            if (rc != MQTTCLIENT_SUCCESS) fail("cannot set the MQTT callbacks", rc);
        }
        MQTTClient_connectOptions c = MQTTClient_connectOptions_initializer;
        // Sync receive answers the broker's keepalive only while waiting: a resting client's
        // pause must stay well inside it (the broker drops a client after 1.5 intervals).
        c.keepAliveInterval =
            static_cast<int>(std::min(3600.0, std::max(60.0, 2 * o.restingMaxPause + 10)));
        c.cleansession = 1;
        // The initializer's reliable = 1 allows one unacknowledged QoS 1 publish; the next
        // publish then waits in MQTTClient_yield, which always takes 100 ms.
        c.reliable = 0;
        c.maxInflightMessages = 1000;
        c.MQTTVersion = MQTTVERSION_3_1_1;  // no silent retry with 3.1 on failure
        c.connectTimeout = std::max(1, o.timeoutMs / 1000);
        rc = MQTTClient_connect(handle_, &c);
        if (rc != MQTTCLIENT_SUCCESS) fail("cannot connect to the MQTT broker at " + uri_, rc);
        if (noDelay(o)) setNoDelayTowards(o.port ? o.port : kDefaultPort);
    }

    Connection(const Connection&) = delete;
    Connection& operator=(const Connection&) = delete;

    ~Connection() {
        if (!handle_) return;
        if (MQTTClient_isConnected(handle_)) {
            MQTTClient_disconnect(handle_, 100);
        } else if (inbox_) {
            // Paho calls connectionLost on a thread of its own that reads the handle: let it
            // finish before the handle is freed (bounded: it may never come).
            for (int i = 0; i < 50 && !lostCalled_; ++i)
                std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
        MQTTClient_destroy(&handle_);
    }

    // Returns once the broker acknowledged the subscription (SUBACK).
    void subscribe(const std::string& topic, int qos) {
        const int rc = MQTTClient_subscribe(handle_, topic.c_str(), qos);
        if (rc != MQTTCLIENT_SUCCESS)
            throw std::runtime_error(
                "subscribing " + topic + " at " + uri_ + " failed: " +
                (rc == MQTT_BAD_SUBSCRIBE ? std::string("refused by the broker") : pahoError(rc)));
    }

    void publish(const std::string& topic, std::span<const std::byte> payload, int qos) {
        if (payload.size() > kMaxPayload)
            throw std::runtime_error("payload of " + std::to_string(payload.size()) +
                                     " bytes above the 64 MiB bound");
        static const std::byte none{};
        const int rc =
            MQTTClient_publish(handle_, topic.c_str(), static_cast<int>(payload.size()),
                               payload.empty() ? &none : payload.data(), qos, 0, nullptr);
        // Paho reports a socket error on a QoS 1 publish as success (it would resend after a
        // reconnect): the loss then shows as the failure of the wait for the answer.
        if (rc != MQTTCLIENT_SUCCESS)
            throw std::runtime_error(lostMessage("publishing to " + topic + ": " + pahoError(rc)));
    }

    // Without callbacks: the next message, read on this thread; Timeout when the deadline
    // passed, Failed (with the reason) when the connection is gone.
    Inbox::Result receive(Bytes& out, Clock::time_point deadline, std::string& failure) {
        for (;;) {
            const auto left =
                std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
            if (left.count() <= 0) return Inbox::Result::Timeout;
            char* topic = nullptr;
            int topicLen = 0;
            MQTTClient_message* m = nullptr;
            const int rc = MQTTClient_receive(handle_, &topic, &topicLen, &m,
                                              static_cast<unsigned long>(left.count()));
            if (rc != MQTTCLIENT_SUCCESS && rc != MQTTCLIENT_TOPICNAME_TRUNCATED) {
                failure = lostMessage("MQTTClient_receive: " + pahoError(rc));
                return Inbox::Result::Failed;
            }
            if (!m) {
                if (!MQTTClient_isConnected(handle_)) {
                    failure = lostMessage("disconnected");
                    return Inbox::Result::Failed;
                }
                continue;  // timed out inside Paho: the loop checks the deadline
            }
            const std::size_t size =
                m->payloadlen > 0 ? static_cast<std::size_t>(m->payloadlen) : 0;
            const bool tooLarge = size > kMaxPayload;
            if (!tooLarge) {
                out.resize(size);
                if (size) std::memcpy(out.data(), m->payload, size);
            }
            MQTTClient_freeMessage(&m);
            MQTTClient_free(topic);
            if (tooLarge) {
                failure = "a message of " + std::to_string(size) + " bytes (above 64 MiB)";
                return Inbox::Result::Failed;
            }
            return Inbox::Result::Got;
        }
    }

    const std::string& uri() const { return uri_; }

  private:
    [[noreturn]] void fail(const std::string& what, int rc) {
        MQTTClient_destroy(&handle_);
        handle_ = nullptr;
        throw std::runtime_error(what + ": " + pahoError(rc));
    }

    std::string lostMessage(const std::string& cause) const {
        return "lost the connection to the MQTT broker at " + uri_ + " (" + cause + ")";
    }

    // On Paho's thread: copy and hand over, nothing else (no publish here).
    static int onMessage(void* context, char* topic, int, MQTTClient_message* m) {
        auto* self = static_cast<Connection*>(context);
        const std::size_t size = m->payloadlen > 0 ? static_cast<std::size_t>(m->payloadlen) : 0;
        if (size > kMaxPayload)
            self->inbox_->fail("a message of " + std::to_string(size) + " bytes (above 64 MiB)");
        else
            self->inbox_->push(self->tag_, m->payload, size);
        MQTTClient_freeMessage(&m);
        MQTTClient_free(topic);
        return 1;
    }

    static void onLost(void* context, char* cause) {
        auto* self = static_cast<Connection*>(context);
        self->inbox_->fail(self->lostMessage(cause ? cause : "connection closed"));
        self->lostCalled_ = true;
    }

    std::string uri_;
    Inbox* inbox_;
    int tag_;
    std::atomic<bool> lostCalled_{false};
    MQTTClient handle_ = nullptr;
};

// Waits for the next message of `connection`, by inbox (callback) or by receive (sync).
class Receiver {
  public:
    Receiver(const Options& o, const std::string& role)
        : connection_(o, role, syncReceive(o) ? nullptr : &inbox_), sync_(syncReceive(o)) {}

    Connection& connection() { return connection_; }

    Inbox::Result next(Bytes& out, Clock::time_point deadline, std::string& failure) {
        if (sync_) return connection_.receive(out, deadline, failure);
        const auto r = inbox_.pop(message_, deadline, failure);
        if (r == Inbox::Result::Got) out = std::move(message_.payload);
        return r;
    }

  private:
    Inbox inbox_;  // before the connection: Paho's thread may use it until the handle is gone
    Connection connection_;
    bool sync_;
    Message message_;
};

class MqttClient final : public driver::Client {
  public:
    explicit MqttClient(const Options& o)
        : qos_(qosOf(o)),
          timeout_(o.timeoutMs),
          request_(prefixOf(o) + "/req"),
          receiver_(o, "client") {
        receiver_.connection().subscribe(prefixOf(o) + "/rep", qos_);
    }

    void request(std::span<const std::byte> payload, Bytes& reply) override {
        receiver_.connection().publish(request_, payload, qos_);
        std::string failure;
        switch (
            receiver_.next(reply, Clock::now() + std::chrono::milliseconds(timeout_), failure)) {
            case Inbox::Result::Got:
                return;
            case Inbox::Result::Timeout:
                throw std::runtime_error("no answer on the reply topic within " +
                                         std::to_string(timeout_) + " ms (broker " +
                                         receiver_.connection().uri() + ")");
            case Inbox::Result::Failed:
                throw std::runtime_error(failure);
        }
    }

  private:
    int qos_;
    int timeout_;
    std::string request_;
    Receiver receiver_;
};

void runServer(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const int qos = qosOf(o);
    const std::string prefix = prefixOf(o);
    const std::string reply = prefix + "/rep";
    const bool echo = o.mode == driver::Mode::Echo;
    Receiver receiver(o, "server");
    receiver.connection().subscribe(prefix + "/req", qos);
    ctx.ready();
    const std::byte ack[1] = {std::byte{1}};
    Bytes request;
    std::string failure;
    while (!ctx.stop.stop_requested()) {
        switch (receiver.next(request, Clock::now() + kPoll, failure)) {
            case Inbox::Result::Got:
                if (echo)
                    receiver.connection().publish(reply, request, qos);
                else
                    receiver.connection().publish(reply, ack, qos);
                break;
            case Inbox::Result::Timeout:
                break;
            case Inbox::Result::Failed:
                throw std::runtime_error(failure);
        }
    }
}

// Nodes first .. first+count-1, each on a connection of its own; Paho's thread only queues
// what arrives, and this thread republishes it.
void runChainNodes(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const int qos = qosOf(o);
    const std::string prefix = prefixOf(o);
    Inbox inbox;  // before the connections: they deliver into it until destroyed
    std::vector<std::unique_ptr<Connection>> nodes;
    std::vector<std::string> next;
    for (int k = 0; k < o.count; ++k) {
        const int i = o.first + k;
        std::string role = "n";  // not "n" + to_string(i): GCC 12 -O3 warns (-Wrestrict)
        role += std::to_string(i);
        nodes.push_back(std::make_unique<Connection>(o, role, &inbox, k));
        nodes.back()->subscribe(chainTopic(prefix, i), qos);
        next.push_back((i + 1) % o.hops == 0 ? prefix + "/chain/sink" : chainTopic(prefix, i + 1));
    }
    ctx.ready();
    Message m;
    std::string failure;
    while (!ctx.stop.stop_requested()) {
        switch (inbox.pop(m, Clock::now() + kPoll, failure)) {
            case Inbox::Result::Got: {
                const auto k = static_cast<std::size_t>(m.tag);
                nodes[k]->publish(next[k], m.payload, qos);
                break;
            }
            case Inbox::Result::Timeout:
                break;
            case Inbox::Result::Failed:
                throw std::runtime_error(failure);
        }
    }
}

class MqttChainClient final : public driver::ChainClient {
  public:
    explicit MqttChainClient(const Options& o)
        : qos_(qosOf(o)), prefix_(prefixOf(o)), connection_(o, "chain", &inbox_) {
        connection_.subscribe(prefix_ + "/chain/sink", qos_);
    }

    void send(int node, std::span<const std::byte> message) override {
        connection_.publish(chainTopic(prefix_, node), message, qos_);
    }

    bool receive(Bytes& message, Clock::time_point deadline) override {
        std::string failure;
        switch (inbox_.pop(message_, deadline, failure)) {
            case Inbox::Result::Got:
                message = std::move(message_.payload);
                return true;
            case Inbox::Result::Timeout:
                return false;
            case Inbox::Result::Failed:
                break;
        }
        throw std::runtime_error(failure);
    }

  private:
    int qos_;
    std::string prefix_;
    Inbox inbox_;
    Connection connection_;
    Message message_;
};

}  // namespace
}  // namespace pnp::bench::mqtt

int main(int argc, char** argv) {
    using namespace pnp::bench;
    driver::Adapter a;
    a.name = "mqtt";
    a.variants = {"qos0", "qos1"};
    a.description =
        "MQTT 3.1.1 via a mosquitto broker, Eclipse Paho C (MQTTClient), request/reply over two "
        "topics";
    a.makeClient = [](const driver::Options& o) { return std::make_unique<mqtt::MqttClient>(o); };
    a.runServer = mqtt::runServer;
    a.runChainNodes = mqtt::runChainNodes;
    a.makeChainClient = [](const driver::Options& o) {
        return std::make_unique<mqtt::MqttChainClient>(o);
    };
    return driver::adapterMain(argc, argv, a);
}
