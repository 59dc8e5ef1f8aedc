// The middleware evaluation's test driver (thesis chapter 4.5), shared by every adapter.
//
// An adapter is a small executable per middleware (src/bench/adapters/<name>, built as
// <build>/mw/pnp-mw-<name>) that links only its own middleware and this driver. Its main()
// is `return adapterMain(argc, argv, adapter)`; the driver parses the command line, runs
// the server / chain nodes / client loop, times every request with the steady clock in
// nanoseconds, checks every reply and writes one CSV row per request. The orchestration
// (processes, load, /proc metrics, report) is `pnp bench middleware` (src/bench/runner).
//
// Command line of every adapter executable (docs/middleware_bench.md):
//   pnp-mw-NAME info                        one JSON line: name, variants, description
//   pnp-mw-NAME server --mode ack|echo [common]          serves until SIGTERM / SIGINT
//   pnp-mw-NAME node --first K --count C --hops H [common]    chain nodes K .. K+C-1
//   pnp-mw-NAME client --mode ack|echo|resting|chain [common] [client options]
// common:  --variant V  --host ADDR (the server's address; default 127.0.0.1)
//          --local ADDR (this process's own address; default 127.0.0.1)  --port P (base
//          port, 0: the adapter's default)  --cpu N (pin to a CPU)  --set KEY=VALUE ...
// client:  --sizes 2,4,...  --reps N  --warmup N  --csv FILE  --resting-seconds S
//          --resting-max-pause S  --streams N  --hops H  --runs N  --timeout-ms MS
// A server or node prints the line "READY" on stdout once it serves (the runner waits for
// it); a client prints one JSON summary line per payload size on stdout and exits 0, or
// prints the reason on stderr and exits 1 (failure) / 4 (a reply that is not what was sent).
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <span>
#include <stdexcept>
#include <stop_token>
#include <string>
#include <vector>

namespace pnp::bench::driver {

using Clock = std::chrono::steady_clock;
using Bytes = std::vector<std::byte>;

// ACK: payload out, 1-byte answer. Echo: payload back. Resting: one 4-byte ACK request after
// a random 0..max pause, for a given time. Chain: payload through `hops` forwarding nodes.
enum class Mode { Ack, Echo, Resting, Chain };
std::string_view toString(Mode m);
Mode modeFromString(std::string_view s);  // throws std::invalid_argument

// A reply that is not what the mode asks for (wrong size, changed bytes): exit code 4.
struct IntegrityError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

struct Options {
    Mode mode = Mode::Echo;
    std::string variant;                          // empty: the adapter's first variant
    std::string host = "127.0.0.1";               // the server (or first chain node's) address
    std::string local = "127.0.0.1";              // this process's own address (bind / interface)
    int port = 0;                                 // base port; 0: the adapter's default
    int cpu = -1;                                 // pin the process to this CPU; -1: no pinning
    std::map<std::string, std::string> settings;  // --set KEY=VALUE (adapter-specific)

    // client
    std::vector<std::size_t> sizes;  // default 2, 4, ..., 32768
    int reps = 5000;
    int warmup = 100;            // untimed requests before each payload size
    std::string csv;             // one row per timed request; empty: none
    double restingSeconds = 30;  // Resting: duration
    double restingMaxPause = 3;  // Resting: pause drawn from [0, max] s
    int timeoutMs = 10000;       // per request / per chain run

    // chain: nodes first .. first+count-1 of streams*hops; node i forwards to i+1, and
    // node i with (i+1) % hops == 0 delivers to the client's sink.
    int first = 0;
    int count = 1;
    int streams = 10;
    int hops = 50;
    int runs = 100;
    std::size_t chainPayload = 10240;

    std::string setting(const std::string& key, const std::string& fallback) const;
    int nodes() const { return streams * hops; }
};

// The client side of one connection to a server: one request, blocking until its answer.
class Client {
  public:
    virtual ~Client() = default;
    // Sends `payload` and waits for the answer (Ack: 1 byte; Echo: the payload), which it
    // stores in `reply`. Throws std::runtime_error on failure or when the answer does not
    // arrive within the options' timeout.
    virtual void request(std::span<const std::byte> payload, Bytes& reply) = 0;
};

// The client side of the chain test: injects into the first node of a stream and receives
// what the last nodes deliver to its sink.
class ChainClient {
  public:
    virtual ~ChainClient() = default;
    // Sends `message` to chain node `node` (the first node of a stream).
    virtual void send(int node, std::span<const std::byte> message) = 0;
    // Waits for the next message delivered to the sink; false on timeout.
    virtual bool receive(Bytes& message, Clock::time_point deadline) = 0;
};

// Given to servers and chain nodes: call ready() once serving (prints READY); serve until
// stop is requested (SIGTERM / SIGINT).
struct ServerContext {
    const Options& options;
    std::stop_token stop;
    std::function<void()> ready;
};

struct Adapter {
    std::string name;                   // "tcp", "opcua", "mqtt", ...
    std::vector<std::string> variants;  // first = default, e.g. {"qos0", "qos1"}
    std::string description;            // one line, for the report
    std::function<std::unique_ptr<Client>(const Options&)> makeClient;
    std::function<void(ServerContext&)> runServer;
    // Optional (chain test): run nodes first..first+count-1, and a sink client.
    std::function<void(ServerContext&)> runChainNodes;
    std::function<std::unique_ptr<ChainClient>(const Options&)> makeChainClient;
};

int adapterMain(int argc, char** argv, const Adapter& adapter);

// ---- shared by adapters and the runner ---------------------------------------------------

// Payload of `size` bytes whose content depends on (size, seq): a reply that carries another
// request's bytes is caught.
void fillPayload(Bytes& payload, std::size_t size, std::uint64_t seq);
std::vector<std::size_t> defaultSizes();  // 2, 4, ..., 32768

struct Summary {
    std::size_t n = 0;
    double min = 0, q1 = 0, median = 0, q3 = 0, mean = 0, p99 = 0, max = 0;  // µs
};
Summary summarize(std::vector<std::int64_t> samplesNs);

}  // namespace pnp::bench::driver
