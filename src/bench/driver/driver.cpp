#include "bench/driver/driver.hpp"

#include <pthread.h>
#include <sched.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <random>
#include <thread>

namespace pnp::bench::driver {

std::string_view toString(Mode m) {
    switch (m) {
        case Mode::Ack:
            return "ack";
        case Mode::Echo:
            return "echo";
        case Mode::Resting:
            return "resting";
        case Mode::Chain:
            return "chain";
    }
    return "?";
}

Mode modeFromString(std::string_view s) {
    for (Mode m : {Mode::Ack, Mode::Echo, Mode::Resting, Mode::Chain})
        if (toString(m) == s) return m;
    throw std::invalid_argument("unknown mode '" + std::string(s) +
                                "' (ack, echo, resting or chain)");
}

std::string Options::setting(const std::string& key, const std::string& fallback) const {
    auto it = settings.find(key);
    return it == settings.end() ? fallback : it->second;
}

void fillPayload(Bytes& payload, std::size_t size, std::uint64_t seq) {
    payload.resize(size);
    // splitmix64 over (size, seq): cheap, and different for every request of a run.
    std::uint64_t x = (static_cast<std::uint64_t>(size) << 40) ^ (seq * 0x9E3779B97F4A7C15ULL);
    std::size_t i = 0;
    while (i < size) {
        x += 0x9E3779B97F4A7C15ULL;
        std::uint64_t z = x;
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
        z ^= z >> 31;
        const std::size_t n = std::min<std::size_t>(8, size - i);
        std::memcpy(payload.data() + i, &z, n);
        i += n;
    }
}

std::vector<std::size_t> defaultSizes() {
    std::vector<std::size_t> s;
    for (std::size_t n = 2; n <= 32768; n *= 2) s.push_back(n);
    return s;
}

Summary summarize(std::vector<std::int64_t> ns) {
    Summary s;
    s.n = ns.size();
    if (ns.empty()) return s;
    std::sort(ns.begin(), ns.end());
    // Linear interpolation between closest ranks (the usual "type 7" quantile).
    auto q = [&](double p) {
        const double pos = p * static_cast<double>(ns.size() - 1);
        const auto lo = static_cast<std::size_t>(std::floor(pos));
        const auto hi = std::min(lo + 1, ns.size() - 1);
        const double f = pos - static_cast<double>(lo);
        return (static_cast<double>(ns[lo]) * (1 - f) + static_cast<double>(ns[hi]) * f) / 1e3;
    };
    s.min = static_cast<double>(ns.front()) / 1e3;
    s.max = static_cast<double>(ns.back()) / 1e3;
    s.q1 = q(0.25);
    s.median = q(0.5);
    s.q3 = q(0.75);
    s.p99 = q(0.99);
    double sum = 0;
    for (auto v : ns) sum += static_cast<double>(v);
    s.mean = sum / static_cast<double>(ns.size()) / 1e3;
    return s;
}

namespace {

std::int64_t sinceNs(Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(b - a).count();
}

class Report {
  public:
    Report(const Adapter& a, const Options& o, Mode mode) : adapter_(a), options_(o), mode_(mode) {
        if (!o.csv.empty()) {
            csv_.open(o.csv, std::ios::trunc);
            if (!csv_) throw std::runtime_error("cannot write " + o.csv);
            csv_ << "adapter,variant,mode,payload,seq,rtt_ns\n";
        }
    }

    void sample(std::size_t payload, std::uint64_t seq, std::int64_t ns) {
        samples_.push_back(ns);
        if (csv_.is_open())
            csv_ << adapter_.name << ',' << options_.variant << ',' << toString(mode_) << ','
                 << payload << ',' << seq << ',' << ns << '\n';
    }

    // One JSON line for the samples since the last flush.
    void flush(std::size_t payload, std::int64_t elapsedNs) {
        const Summary s = summarize(samples_);
        nlohmann::json j = {{"adapter", adapter_.name},
                            {"variant", options_.variant},
                            {"mode", toString(mode_)},
                            {"payload", payload},
                            {"n", s.n},
                            {"min_us", s.min},
                            {"q1_us", s.q1},
                            {"median_us", s.median},
                            {"q3_us", s.q3},
                            {"mean_us", s.mean},
                            {"p99_us", s.p99},
                            {"max_us", s.max},
                            {"msgs_per_s", elapsedNs > 0 ? static_cast<double>(s.n) * 1e9 /
                                                               static_cast<double>(elapsedNs)
                                                         : 0.0}};
        std::cout << j.dump() << std::endl;
        samples_.clear();
        if (csv_.is_open()) csv_.flush();
    }

  private:
    const Adapter& adapter_;
    const Options& options_;
    Mode mode_;
    std::ofstream csv_;
    std::vector<std::int64_t> samples_;
};

void checkReply(Mode mode, const Bytes& payload, const Bytes& reply) {
    if (mode == Mode::Echo) {
        if (reply.size() != payload.size() ||
            (!payload.empty() && std::memcmp(reply.data(), payload.data(), payload.size()) != 0))
            throw IntegrityError("echo of " + std::to_string(payload.size()) +
                                 " bytes came back as " + std::to_string(reply.size()) + " bytes" +
                                 (reply.size() == payload.size() ? " with other content" : ""));
    } else if (reply.size() != 1) {
        throw IntegrityError("ack of a " + std::to_string(payload.size()) + "-byte request was " +
                             std::to_string(reply.size()) + " bytes, not 1");
    }
}

void runRequestReply(const Adapter& a, const Options& o) {
    auto client = a.makeClient(o);
    Client& c = *client;
    Report report(a, o, o.mode);
    Bytes payload, reply;
    std::uint64_t seq = 0;
    for (std::size_t size : o.sizes) {
        for (int i = 0; i < o.warmup; ++i) {
            fillPayload(payload, size, seq++);
            c.request(payload, reply);
            checkReply(o.mode, payload, reply);
        }
        const auto start = Clock::now();
        for (int i = 0; i < o.reps; ++i) {
            fillPayload(payload, size, seq);
            const auto t0 = Clock::now();
            c.request(payload, reply);
            const auto t1 = Clock::now();
            checkReply(o.mode, payload, reply);
            report.sample(size, seq++, sinceNs(t0, t1));
        }
        report.flush(size, sinceNs(start, Clock::now()));
    }
}

void runResting(const Adapter& a, Options o) {
    Options ack = o;
    ack.mode = Mode::Ack;
    auto client = a.makeClient(ack);
    Report report(a, o, Mode::Resting);
    std::mt19937_64 rng(std::random_device{}());
    std::uniform_real_distribution<double> pause(0.0, o.restingMaxPause);
    Bytes payload, reply;
    fillPayload(payload, 4, 0);
    client->request(payload, reply);  // connected and warm before the first pause
    const auto end = Clock::now() + std::chrono::duration<double>(o.restingSeconds);
    std::uint64_t seq = 1;
    const auto start = Clock::now();
    // Bounded: at least one request, then as many as fit in the time.
    for (int i = 0; i < 1000000; ++i) {
        const auto wake = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(pause(rng)));
        if (i > 0 && wake >= end) break;
        std::this_thread::sleep_until(wake);
        fillPayload(payload, 4, seq);
        const auto t0 = Clock::now();
        client->request(payload, reply);
        const auto t1 = Clock::now();
        checkReply(Mode::Ack, payload, reply);
        report.sample(4, seq++, sinceNs(t0, t1));
    }
    report.flush(4, sinceNs(start, Clock::now()));
}

void runChain(const Adapter& a, const Options& o) {
    if (!a.makeChainClient) throw std::runtime_error(a.name + " has no chain test");
    auto client = a.makeChainClient(o);
    Report report(a, o, Mode::Chain);
    std::vector<Bytes> sent(static_cast<std::size_t>(o.streams));
    Bytes got;
    const auto start = Clock::now();
    const int warm = std::min(2, o.runs);
    for (int run = 0; run < warm + o.runs; ++run) {
        for (int s = 0; s < o.streams; ++s)
            fillPayload(sent[static_cast<std::size_t>(s)], o.chainPayload,
                        static_cast<std::uint64_t>(run * o.streams + s));
        std::vector<bool> arrived(sent.size(), false);
        const auto t0 = Clock::now();
        for (int s = 0; s < o.streams; ++s)
            client->send(s * o.hops, sent[static_cast<std::size_t>(s)]);
        const auto deadline = t0 + std::chrono::milliseconds(o.timeoutMs);
        for (int k = 0; k < o.streams; ++k) {
            if (!client->receive(got, deadline))
                throw std::runtime_error("chain run " + std::to_string(run) + ": " +
                                         std::to_string(k) + " of " + std::to_string(o.streams) +
                                         " messages arrived within " + std::to_string(o.timeoutMs) +
                                         " ms");
            auto it = std::find(sent.begin(), sent.end(), got);
            if (it == sent.end())
                throw IntegrityError("chain: a delivered message of " + std::to_string(got.size()) +
                                     " bytes matches none sent in this run");
            arrived[static_cast<std::size_t>(it - sent.begin())] = true;
        }
        if (std::count(arrived.begin(), arrived.end(), true) != o.streams)
            throw IntegrityError("chain: a stream's message arrived twice");
        const auto t1 = Clock::now();
        if (run >= warm)
            report.sample(o.chainPayload, static_cast<std::uint64_t>(run - warm), sinceNs(t0, t1));
    }
    report.flush(o.chainPayload, sinceNs(start, Clock::now()));
}

void pin(int cpu) {
    if (cpu < 0) return;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0)
        throw std::runtime_error("cannot pin to CPU " + std::to_string(cpu));
}

// Serves with SIGTERM / SIGINT turned into a stop request (signals blocked in every thread,
// taken by sigwait here).
int serve(const std::function<void(ServerContext&)>& run, const Options& o) {
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGINT);
    pthread_sigmask(SIG_BLOCK, &set, nullptr);
    std::stop_source stop;
    std::thread waiter([&] {
        int sig = 0;
        sigwait(&set, &sig);
        stop.request_stop();
    });
    ServerContext ctx{o, stop.get_token(), [] { std::cout << "READY" << std::endl; }};
    int rc = 0;
    try {
        run(ctx);
    } catch (const std::exception& e) {
        std::cerr << "server: " << e.what() << std::endl;
        rc = 1;
    }
    if (!stop.stop_requested()) pthread_kill(waiter.native_handle(), SIGTERM);
    waiter.join();
    return rc;
}

std::vector<std::size_t> parseSizes(const std::string& text) {
    std::vector<std::size_t> out;
    std::size_t pos = 0;
    while (pos <= text.size()) {
        const auto comma = text.find(',', pos);
        const std::string item =
            text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
        if (!item.empty()) {
            const unsigned long long v = std::stoull(item);
            if (v > (64u << 20)) throw std::invalid_argument("payload size above 64 MiB: " + item);
            out.push_back(static_cast<std::size_t>(v));
        }
        if (comma == std::string::npos) break;
        pos = comma + 1;
    }
    if (out.empty()) throw std::invalid_argument("no payload sizes in '" + text + "'");
    return out;
}

}  // namespace

int adapterMain(int argc, char** argv, const Adapter& a) {
    CLI::App app("pnp middleware-evaluation adapter: " + a.name + " (" + a.description + ")",
                 "pnp-mw-" + a.name);
    app.require_subcommand(1);
    Options o;
    std::string mode = "echo", sizes;
    std::vector<std::string> sets;
    auto common = [&](CLI::App* c) {
        c->add_option("--variant", o.variant, "variant of the middleware");
        c->add_option("--host", o.host, "the server's address");
        c->add_option("--local", o.local, "this process's own address");
        c->add_option("--port", o.port, "base port (0: the adapter's default)");
        c->add_option("--cpu", o.cpu, "pin to this CPU");
        c->add_option("--set", sets, "adapter setting KEY=VALUE");
        c->add_option("--streams", o.streams, "chain: parallel streams");
        c->add_option("--hops", o.hops, "chain: nodes per stream");
    };
    CLI::App* info = app.add_subcommand("info", "print name and variants as JSON");
    CLI::App* server = app.add_subcommand("server", "serve until SIGTERM");
    server->add_option("--mode", mode, "ack or echo");
    common(server);
    CLI::App* node = app.add_subcommand("node", "run chain nodes until SIGTERM");
    node->add_option("--first", o.first, "first node index");
    node->add_option("--count", o.count, "number of nodes in this process");
    common(node);
    CLI::App* client = app.add_subcommand("client", "run the test and print the results");
    client->add_option("--mode", mode, "ack, echo, resting or chain");
    client->add_option("--sizes", sizes, "payload sizes, comma-separated (default 2..32768)");
    client->add_option("--reps", o.reps, "timed requests per payload size");
    client->add_option("--warmup", o.warmup, "untimed requests per payload size");
    client->add_option("--csv", o.csv, "write one row per request");
    client->add_option("--resting-seconds", o.restingSeconds, "resting: duration");
    client->add_option("--resting-max-pause", o.restingMaxPause, "resting: longest pause (s)");
    client->add_option("--timeout-ms", o.timeoutMs, "per request / chain run");
    client->add_option("--runs", o.runs, "chain: timed runs");
    client->add_option("--chain-payload", o.chainPayload, "chain: bytes per message");
    common(client);
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        return app.exit(e);
    }
    if (info->parsed()) {
        nlohmann::json j = {{"name", a.name},
                            {"variants", a.variants},
                            {"description", a.description},
                            {"chain", static_cast<bool>(a.runChainNodes && a.makeChainClient)}};
        std::cout << j.dump() << std::endl;
        return 0;
    }
    try {
        for (const auto& kv : sets) {
            const auto eq = kv.find('=');
            if (eq == std::string::npos)
                throw std::invalid_argument("--set needs KEY=VALUE: " + kv);
            o.settings[kv.substr(0, eq)] = kv.substr(eq + 1);
        }
        if (o.variant.empty() && !a.variants.empty()) o.variant = a.variants.front();
        if (!a.variants.empty() &&
            std::find(a.variants.begin(), a.variants.end(), o.variant) == a.variants.end())
            throw std::invalid_argument("unknown variant '" + o.variant + "' of " + a.name);
        o.mode = modeFromString(mode);
        o.sizes = sizes.empty() ? defaultSizes() : parseSizes(sizes);
        if (o.reps < 0 || o.reps > 10000000 || o.warmup < 0 || o.warmup > 1000000 ||
            o.streams < 1 || o.streams > 1000 || o.hops < 1 || o.hops > 100000 || o.runs < 0 ||
            o.runs > 1000000 || o.count < 1 || o.first < 0 || o.timeoutMs < 1)
            throw std::invalid_argument("a count is out of range");
        // Chain messages are told apart by their content: they need a few bytes.
        if (o.chainPayload < 8 || o.chainPayload > (64u << 20))
            throw std::invalid_argument("--chain-payload must be 8 B .. 64 MiB");
        pin(o.cpu);
    } catch (const std::exception& e) {
        std::cerr << "pnp-mw-" << a.name << ": " << e.what() << std::endl;
        return 2;
    }
    if (server->parsed()) {
        if (o.mode != Mode::Ack && o.mode != Mode::Echo) {
            std::cerr << "pnp-mw-" << a.name << ": a server's mode is ack or echo" << std::endl;
            return 2;
        }
        return serve(a.runServer, o);
    }
    if (node->parsed()) {
        if (!a.runChainNodes) {
            std::cerr << "pnp-mw-" << a.name << ": no chain test" << std::endl;
            return 2;
        }
        o.mode = Mode::Chain;
        return serve(a.runChainNodes, o);
    }
    try {
        switch (o.mode) {
            case Mode::Ack:
            case Mode::Echo:
                runRequestReply(a, o);
                break;
            case Mode::Resting:
                runResting(a, o);
                break;
            case Mode::Chain:
                runChain(a, o);
                break;
        }
    } catch (const IntegrityError& e) {
        std::cerr << "pnp-mw-" << a.name << ": " << e.what() << std::endl;
        return 4;
    } catch (const std::exception& e) {
        std::cerr << "pnp-mw-" << a.name << ": " << e.what() << std::endl;
        return 1;
    }
    return 0;
}

}  // namespace pnp::bench::driver
