// OPC UA client/server with our own stack (src/ua): SecurityPolicy None, anonymous session,
// opc.tcp binary. The server (pnp::ua::server::Server, full namespace 0) has a namespace
// "urn:pnp:bench" with the object Bench holding the method Echo(ByteString) -> ByteString,
// and the writable ByteString variable Ack.
//   echo: Call Bench.Echo (one CallRequest per request; the reply is the returned bytes);
//   ack:  Write Bench.Ack (one WriteRequest; the reply is one byte when the status is Good).
// The client is pnp::ua::client::Client's blocking call on the calling thread (no thread
// hop), as bench/bench_main.cpp measures it against raw TCP.
//
// Chain: node i is a server at port + 1 + i with the ByteString variable Bench.In; a Write
// to it hands the bytes to the node's worker thread, which writes them to node i + 1's In
// through a client connection of its own (or, last of its stream, to the In of the small
// server the chain client runs at --local:port + 1 + streams * hops; nodes reach it through
// setting sink-host, default 127.0.0.1).
//
// Ports: server at --port (default 4850) on --host.
#include <condition_variable>
#include <deque>
#include <iostream>
#include <map>
#include <mutex>
#include <thread>

#include "bench/driver/driver.hpp"
#include "ua/client/client.hpp"
#include "ua/server/server.hpp"
#include "ua/types/ns0_ids_data_types.hpp"
#include "ua/types/ns0_ids_object_types.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/ns0_ids_reference_types.hpp"
#include "ua/types/ns0_types_model.hpp"
#include "ua/types/ns0_types_parameters.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::bench::opcua {
namespace {

namespace ua = pnp::ua;
using driver::Bytes;
using driver::Clock;
using driver::Options;

constexpr int kDefaultPort = 4850;
constexpr const char* kNamespaceUri = "urn:pnp:bench";
// Messages up to the driver's largest payload (64 MiB) plus headers pass both sides.
constexpr ua::UInt32 kMaxMessage = (64u << 20) + 4096;

int basePort(const Options& o) { return o.port ? o.port : kDefaultPort; }
int sinkPort(const Options& o) { return basePort(o) + 1 + o.nodes(); }

std::string url(const std::string& host, int port) {
    return "opc.tcp://" + host + ":" + std::to_string(port);
}

// The node ids in the bench namespace (index ns). Numeric: the cheapest to encode and to
// look up, so that the measurement shows the services, not string ids.
struct Nodes {
    ua::NodeId object, echo, ack, in;
    explicit Nodes(ua::UInt16 ns) : object(ns, 1), echo(ns, 2), ack(ns, 3), in(ns, 4) {}
};

ua::ByteString toByteString(std::span<const std::byte> bytes) {
    return ua::ByteString(reinterpret_cast<const ua::Byte*>(bytes.data()), bytes.size());
}

void assign(Bytes& out, const ua::ByteString& b) {
    const auto* p = reinterpret_cast<const std::byte*>(b.data());
    out.assign(p, p + b.size());
}

ua::server::ServerConfig serverConfig(const std::string& host, int port) {
    ua::server::ServerConfig c;
    c.applicationUri = "urn:pnp:bench:server";
    c.applicationName = "pnp middleware bench";
    c.host = host;
    c.publicHost = host;
    c.port = static_cast<ua::UInt16>(port);
    c.transport.maxMessageSize = kMaxMessage;
    c.decodeLimits.maxStringLength = kMaxMessage;
    return c;
}

ua::client::ClientConfig clientConfig(const Options& o) {
    ua::client::ClientConfig c;
    c.applicationName = "pnp middleware bench client";
    c.requestTimeout = std::chrono::milliseconds(o.timeoutMs);
    c.connectTimeout = std::chrono::milliseconds(o.timeoutMs);
    c.transport.maxMessageSize = kMaxMessage;
    c.decodeLimits.maxStringLength = kMaxMessage;
    return c;
}

ua::Argument argument(const char* name) {
    ua::Argument a;
    a.name = name;
    a.dataType = ua::NodeId(0, ua::ns0::ByteString);
    a.valueRank = -1;
    return a;
}

ua::server::VariableAttributes byteStringVariable() {
    ua::server::VariableAttributes a;
    a.dataType = ua::NodeId(0, ua::ns0::ByteString);
    a.accessLevel = ua::server::access_level::CurrentRead | ua::server::access_level::CurrentWrite;
    a.value = ua::DataValue(ua::Variant(ua::ByteString()));
    return a;
}

// The bench namespace with the object Bench; returns its index.
Nodes addBenchObject(ua::server::Server& server) {
    Nodes n(server.addNamespace(kNamespaceUri));
    server.addressSpace().addObject(ua::NodeId(0, ua::ns0::ObjectsFolder), n.object,
                                    ua::QualifiedName{n.object.namespaceIndex(), "Bench"}, {},
                                    ua::NodeId(0, ua::ns0::BaseObjectType),
                                    ua::NodeId(0, ua::ns0::Organizes));
    return n;
}

// A variable Bench.In whose writes go to `deliver` (on the network thread: it must be
// quick). The value is not stored (a read gives an empty ByteString), so a written
// ByteString that shares the connection's receive buffer does not pin it.
void addInbox(ua::server::Server& server, const Nodes& n,
              std::function<void(const ua::ByteString&)> deliver) {
    auto& as = server.addressSpace();
    as.addVariable(n.object, n.in, ua::QualifiedName{n.in.namespaceIndex(), "In"},
                   byteStringVariable());
    ua::server::ValueCallbacks cb;
    cb.read = [](const ua::NodeId&) { return ua::DataValue(ua::Variant(ua::ByteString())); };
    cb.write = [deliver = std::move(deliver)](const ua::NodeId&, const ua::DataValue& v) {
        const auto* b = v.value ? v.value->scalar<ua::ByteString>() : nullptr;
        if (b == nullptr) return ua::StatusCode(ua::status::BadTypeMismatch);
        deliver(*b);  // a reference to the bytes, not a copy
        return ua::StatusCode(ua::status::Good);
    };
    as.setValueCallback(n.in, std::move(cb));
}

// Waits until stop is requested.
void waitForStop(const std::stop_token& stop) {
    std::mutex m;
    std::condition_variable_any cv;
    std::unique_lock lock(m);
    cv.wait(lock, stop, [] { return false; });
}

// A connected client and the bench namespace's node ids on its server.
struct Connection {
    ua::client::Client client;
    Nodes nodes;
    Connection(const Options& o, const std::string& host, int port)
        : client(clientConfig(o)), nodes(connect(client, url(host, port))) {}

  private:
    static ua::UInt16 connect(ua::client::Client& c, const std::string& endpoint) {
        try {
            c.connect(endpoint);
            return c.namespaceIndex(kNamespaceUri);
        } catch (const std::exception& e) {
            throw std::runtime_error("connect " + endpoint + ": " + e.what());
        }
    }
};

class OpcuaClient final : public driver::Client {
  public:
    explicit OpcuaClient(const Options& o)
        : echo_(o.mode == driver::Mode::Echo), c_(o, o.host, basePort(o)) {}

    void request(std::span<const std::byte> payload, Bytes& reply) override {
        if (echo_) {
            std::vector<ua::Variant> in;
            in.emplace_back(toByteString(payload));
            const ua::client::CallResult r =
                c_.client.call(c_.nodes.object, c_.nodes.echo, std::move(in));
            if (!r.ok()) throw std::runtime_error("Call Echo: " + r.status.toString());
            const auto* b = r.outputs.size() == 1 ? r.outputs[0].scalar<ua::ByteString>() : nullptr;
            if (b == nullptr)
                throw std::runtime_error("Call Echo: the output is not one ByteString");
            assign(reply, *b);
        } else {
            const ua::StatusCode st =
                c_.client.writeValue(c_.nodes.ack, ua::Variant(toByteString(payload)));
            if (!st.isGood()) throw std::runtime_error("Write Ack: " + st.toString());
            reply.assign(1, std::byte{1});
        }
    }

  private:
    bool echo_;
    Connection c_;
};

void runServer(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    ua::server::Server server(serverConfig(o.host, basePort(o)));
    const Nodes n = addBenchObject(server);
    auto& as = server.addressSpace();
    ua::server::MethodAttributes m;
    m.description = ua::LocalizedText("en", "returns its input");
    as.addMethod(n.object, n.echo, ua::QualifiedName{n.echo.namespaceIndex(), "Echo"},
                 {argument("Data")}, {argument("Data")},
                 ua::server::makeMethodHandler([](const ua::server::MethodCallContext&,
                                                  std::vector<ua::Variant>& in,
                                                  std::vector<ua::Variant>& out) {
                     if (in.size() != 1) return ua::StatusCode(ua::status::BadArgumentsMissing);
                     if (in[0].scalar<ua::ByteString>() == nullptr)
                         return ua::StatusCode(ua::status::BadTypeMismatch);
                     out.push_back(std::move(in[0]));  // the input is ours: no copy
                     return ua::StatusCode(ua::status::Good);
                 }),
                 m);
    as.addVariable(n.object, n.ack, ua::QualifiedName{n.ack.namespaceIndex(), "Ack"},
                   byteStringVariable());
    server.start();
    ctx.ready();
    waitForStop(ctx.stop);
    server.stop();
}

// Bytes waiting for a worker thread; bounded so that a flood cannot exhaust memory.
class Queue {
  public:
    bool push(ua::ByteString b) {
        {
            std::lock_guard lock(mutex_);
            if (items_.size() >= 10000) return false;
            items_.push_back(std::move(b));
        }
        ready_.notify_one();
        return true;
    }
    bool pop(ua::ByteString& out, const std::stop_token& stop, Clock::time_point deadline) {
        std::unique_lock lock(mutex_);
        const auto nonEmpty = [&] { return !items_.empty(); };
        if (deadline == Clock::time_point::max()
                ? !ready_.wait(lock, stop, nonEmpty)
                : !ready_.wait_until(lock, stop, deadline, nonEmpty))
            return false;
        out = std::move(items_.front());
        items_.pop_front();
        return true;
    }

  private:
    std::mutex mutex_;
    std::condition_variable_any ready_;
    std::deque<ua::ByteString> items_;
};

// One chain node: its server, and a worker that forwards what is written to In.
struct ChainNode {
    Queue queue;  // before the server, whose write callback uses it
    ua::server::Server server;
    std::jthread worker;
    explicit ChainNode(const std::string& host, int port) : server(serverConfig(host, port)) {
        const Nodes n = addBenchObject(server);
        addInbox(server, n, [this](const ua::ByteString& b) {
            if (!queue.push(b)) std::cerr << "pnp-mw-opcua: a chain node's queue is full\n";
        });
    }
};

void runChainNodes(driver::ServerContext& ctx) {
    const Options& o = ctx.options;
    const std::string sinkHost = o.setting("sink-host", "127.0.0.1");
    std::vector<std::unique_ptr<ChainNode>> nodes;
    for (int i = o.first; i < o.first + o.count; ++i)
        nodes.push_back(std::make_unique<ChainNode>(o.host, basePort(o) + 1 + i));
    for (auto& n : nodes) n->server.start();
    ctx.ready();
    for (int k = 0; k < o.count; ++k) {
        const int i = o.first + k;
        ChainNode& node = *nodes[static_cast<std::size_t>(k)];
        node.worker = std::jthread([&, i](std::stop_token stop) {
            const bool last = (i + 1) % o.hops == 0;
            std::unique_ptr<Connection> next;  // connected at the first message
            ua::ByteString b;
            while (!stop.stop_requested()) {
                if (!node.queue.pop(b, stop, Clock::time_point::max())) continue;
                try {
                    if (!next)
                        next = last ? std::make_unique<Connection>(o, sinkHost, sinkPort(o))
                                    : std::make_unique<Connection>(o, o.host, basePort(o) + 2 + i);
                    const ua::StatusCode st =
                        next->client.writeValue(next->nodes.in, ua::Variant(std::move(b)));
                    if (!st.isGood())
                        std::cerr << "pnp-mw-opcua: node " << i << ": Write In: " << st.toString()
                                  << std::endl;
                } catch (const std::exception& e) {
                    // The chain run that loses this message fails with a timeout.
                    std::cerr << "pnp-mw-opcua: node " << i << ": " << e.what() << std::endl;
                }
            }
        });
    }
    waitForStop(ctx.stop);
    for (auto& n : nodes) {
        n->worker.request_stop();
        if (n->worker.joinable()) n->worker.join();
    }
    for (auto& n : nodes) n->server.stop();
}

class OpcuaChainClient final : public driver::ChainClient {
  public:
    explicit OpcuaChainClient(const Options& o)
        : options_(o), sink_(serverConfig(o.local, sinkPort(o))) {
        const Nodes n = addBenchObject(sink_);
        addInbox(sink_, n, [this](const ua::ByteString& b) {
            if (!inbox_.push(b)) std::cerr << "pnp-mw-opcua: the sink's queue is full\n";
        });
        sink_.start();
    }
    ~OpcuaChainClient() override {
        firsts_.clear();
        sink_.stop();
    }

    void send(int node, std::span<const std::byte> message) override {
        auto it = firsts_.find(node);
        if (it == firsts_.end())
            it = firsts_
                     .emplace(node, std::make_unique<Connection>(options_, options_.host,
                                                                 basePort(options_) + 1 + node))
                     .first;
        Connection& c = *it->second;
        const ua::StatusCode st =
            c.client.writeValue(c.nodes.in, ua::Variant(toByteString(message)));
        if (!st.isGood())
            throw std::runtime_error("Write In of node " + std::to_string(node) + ": " +
                                     st.toString());
    }

    bool receive(Bytes& message, Clock::time_point deadline) override {
        ua::ByteString b;
        if (!inbox_.pop(b, stop_.get_token(), deadline)) return false;
        assign(message, b);
        return true;
    }

  private:
    const Options& options_;
    std::stop_source stop_;
    Queue inbox_;
    ua::server::Server sink_;
    std::map<int, std::unique_ptr<Connection>> firsts_;
};

}  // namespace
}  // namespace pnp::bench::opcua

int main(int argc, char** argv) {
    using namespace pnp::bench;
    driver::Adapter a;
    a.name = "opcua";
    a.variants = {"cs"};
    a.description =
        "OPC UA client/server, our stack (src/ua), SecurityPolicy None, anonymous; echo = Call, "
        "ack = Write";
    a.makeClient = [](const driver::Options& o) { return std::make_unique<opcua::OpcuaClient>(o); };
    a.runServer = opcua::runServer;
    a.runChainNodes = opcua::runChainNodes;
    a.makeChainClient = [](const driver::Options& o) {
        return std::make_unique<opcua::OpcuaChainClient>(o);
    };
    return driver::adapterMain(argc, argv, a);
}
