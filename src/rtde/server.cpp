#include "rtde/server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <system_error>
#include <thread>
#include <vector>

namespace pnp::rtde {

// ---- RegisterStore ----

RegisterStore::RegisterStore() {
    for (const Variable& v : catalogue()) values_.emplace(v.name, defaultValue(v.type));
}

Value RegisterStore::read(std::string_view name) {
    std::lock_guard lock(mutex_);
    auto it = values_.find(name);
    return it == values_.end() ? Value{false} : it->second;
}

void RegisterStore::write(std::string_view name, const Value& value) {
    std::lock_guard lock(mutex_);
    auto it = values_.find(name);
    if (it == values_.end()) return;
    it->second = value;
    ++writes_;
}

void RegisterStore::set(std::string_view name, const Value& value) {
    std::lock_guard lock(mutex_);
    auto it = values_.find(name);
    if (it != values_.end()) it->second = value;
}

std::optional<Value> RegisterStore::get(std::string_view name) const {
    std::lock_guard lock(mutex_);
    auto it = values_.find(name);
    if (it == values_.end()) return std::nullopt;
    return it->second;
}

std::uint64_t RegisterStore::writeCount() const {
    std::lock_guard lock(mutex_);
    return writes_;
}

// ---- Server ----

namespace {

using Clock = std::chrono::steady_clock;

struct OutputRecipe {
    std::vector<std::string> names;
    std::vector<Type> types;
    Clock::duration period{};
    Clock::time_point next{};
    // externalCycle: a sample every `every` control cycles; the cycle of the next one.
    std::uint64_t every = 1;
    std::uint64_t nextCycle = 0;
};

struct InputRecipe {
    std::vector<std::string> names;
    std::vector<Type> types;
};

struct Connection {
    std::uint64_t id = 0;
    int fd = -1;
    std::vector<std::uint8_t> in;
    std::vector<std::uint8_t> out;
    std::size_t outOffset = 0;  // bytes of `out` already sent
    bool negotiated = false;
    bool started = false;
    bool closed = false;
    std::uint8_t nextRecipeId = 1;  // shared by input and output recipes, 0 = failure
    std::map<std::uint8_t, OutputRecipe> outputs;
    std::map<std::uint8_t, InputRecipe> inputs;

    std::size_t queued() const { return out.size() - outOffset; }
};

void setNonBlocking(int fd) {
    int flags = ::fcntl(fd, F_GETFL, 0);
    if (flags < 0 || ::fcntl(fd, F_SETFL, flags | O_NONBLOCK) < 0) {
        throw std::system_error(errno, std::generic_category(), "rtde: fcntl(O_NONBLOCK)");
    }
}

}  // namespace

struct Server::Impl {
    ServerConfig config;
    ControllerState& state;
    int listenFd = -1;
    int wakeFd = -1;
    std::uint16_t boundPort = 0;
    std::thread thread;
    std::atomic<bool> stopping{false};

    std::mutex pendingMutex;
    std::vector<TextMessage> pendingTexts;

    std::atomic<std::uint64_t> cycles{0};  // Server::cycle() calls (externalCycle)
    // The connections, between the network thread (all but its ppoll) and cycle().
    std::mutex netMutex;
    std::atomic<bool> streaming{false};  // a started connection has an output recipe
    std::atomic<std::size_t> clientCount{0};
    std::atomic<std::uint64_t> sent{0};
    std::atomic<std::uint64_t> skipped{0};
    std::atomic<std::uint64_t> errorCloses{0};

    // Network thread only.
    std::map<std::uint64_t, Connection> connections;
    std::map<std::string, std::uint64_t, std::less<>> inputOwners;
    std::uint64_t nextConnectionId = 1;

    Impl(ServerConfig c, ControllerState& s) : config(std::move(c)), state(s) {}

    void run();
    void acceptAll();
    void readFrom(Connection& c);
    void handle(Connection& c, Package&& package);
    void handleSetupOutputs(Connection& c, const SetupOutputs& request);
    void handleSetupInputs(Connection& c, const SetupInputs& request);
    void handleData(Connection& c, const DataPackage& data);
    void stream(Connection& c, Clock::time_point now);
    void enqueue(Connection& c, const Package& package);
    void flush(Connection& c);
    void fail(Connection& c, const std::string& why);
    void close(Connection& c);
    Value sample(const std::string& name, Type type);
};

Server::Server(ServerConfig config, ControllerState& state)
    : impl_(std::make_unique<Impl>(std::move(config), state)) {}

Server::~Server() { stop(); }

void Server::start() {
    Impl& d = *impl_;
    if (d.thread.joinable()) return;
    int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) throw std::system_error(errno, std::generic_category(), "rtde: socket");
    int one = 1;
    ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(d.config.port);
    if (::inet_pton(AF_INET, d.config.bindAddress.c_str(), &addr.sin_addr) != 1) {
        ::close(fd);
        throw std::system_error(EINVAL, std::generic_category(),
                                "rtde: bad bind address " + d.config.bindAddress);
    }
    if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0 || ::listen(fd, 16) < 0) {
        int e = errno;
        ::close(fd);
        throw std::system_error(e, std::generic_category(), "rtde: bind/listen");
    }
    socklen_t len = sizeof addr;
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
    d.boundPort = ntohs(addr.sin_port);
    setNonBlocking(fd);
    d.wakeFd = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
    if (d.wakeFd < 0) {
        int e = errno;
        ::close(fd);
        throw std::system_error(e, std::generic_category(), "rtde: eventfd");
    }
    d.listenFd = fd;
    d.stopping = false;
    d.thread = std::thread([&d] { d.run(); });
}

void Server::stop() {
    Impl& d = *impl_;
    if (!d.thread.joinable()) return;
    d.stopping = true;
    std::uint64_t one = 1;
    [[maybe_unused]] auto n = ::write(d.wakeFd, &one, sizeof one);
    d.thread.join();
    std::lock_guard lock(d.netMutex);
    d.streaming = false;
    for (auto& [id, c] : d.connections) ::close(c.fd);
    d.connections.clear();
    d.inputOwners.clear();
    d.clientCount = 0;
    ::close(d.listenFd);
    ::close(d.wakeFd);
    d.listenFd = d.wakeFd = -1;
}

std::uint16_t Server::port() const { return impl_->boundPort; }

void Server::sendText(const TextMessage& message) {
    Impl& d = *impl_;
    {
        std::lock_guard lock(d.pendingMutex);
        d.pendingTexts.push_back(message);
    }
    if (d.wakeFd >= 0) {
        std::uint64_t one = 1;
        [[maybe_unused]] auto n = ::write(d.wakeFd, &one, sizeof one);
    }
}

void Server::cycle() {
    Impl& d = *impl_;
    d.cycles.fetch_add(1);
    if (!d.streaming.load()) return;  // nobody to send to: no wake-up either
    // The caller (the controller's cycle) sends the samples itself when the network thread
    // is idle: no thread switch per cycle, which on a virtual machine costs more than the
    // sending. Busy (or a send that could not finish): the network thread does it.
    {
        std::unique_lock lock(d.netMutex, std::try_to_lock);
        if (lock.owns_lock()) {
            bool pending = false;
            const auto now = Clock::now();
            for (auto& [id, c] : d.connections) {
                if (!c.closed && c.started) d.stream(c, now);
                if (!c.closed && c.queued() > 0) d.flush(c);
                pending = pending || c.closed || c.queued() > 0;
            }
            if (!pending) return;
        }
    }
    if (d.wakeFd >= 0) {
        std::uint64_t one = 1;
        [[maybe_unused]] auto n = ::write(d.wakeFd, &one, sizeof one);
    }
}

ServerStats Server::stats() const {
    const Impl& d = *impl_;
    return {d.clientCount.load(), d.sent.load(), d.skipped.load(), d.errorCloses.load()};
}

void Server::Impl::run() {
    if (config.realtimePriority > 0) {
        sched_param param{};
        param.sched_priority = std::min(config.realtimePriority, 99);
        // Not permitted (no CAP_SYS_NICE / RLIMIT_RTPRIO): normal scheduling, as before.
        [[maybe_unused]] int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
    }
    std::vector<pollfd> fds;
    std::vector<std::uint64_t> ids;
    std::unique_lock lock(netMutex);
    while (!stopping) {
        // Sleep until the earliest sample deadline of any started connection.
        std::optional<Clock::time_point> wake;
        for (auto& [id, c] : connections) {
            if (!c.started || config.externalCycle) continue;
            for (auto& [rid, r] : c.outputs) {
                if (!wake || r.next < *wake) wake = r.next;
            }
        }
        fds.clear();
        ids.clear();
        fds.push_back({wakeFd, POLLIN, 0});
        fds.push_back({listenFd, POLLIN, 0});
        for (auto& [id, c] : connections) {
            short events = POLLIN;
            if (c.queued() > 0) events |= POLLOUT;
            fds.push_back({c.fd, events, 0});
            ids.push_back(id);
        }
        timespec ts{};
        timespec* timeout = nullptr;
        if (wake) {
            auto left = std::max(Clock::duration::zero(), *wake - Clock::now());
            auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(left).count();
            ts.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
            ts.tv_nsec = static_cast<long>(ns % 1'000'000'000);
            timeout = &ts;
        }
        lock.unlock();
        int n = ::ppoll(fds.data(), fds.size(), timeout, nullptr);
        lock.lock();
        if (n < 0 && errno != EINTR) break;  // cannot happen with valid fds; do not spin
        if (stopping) break;

        if (fds[0].revents & POLLIN) {
            std::uint64_t count;
            [[maybe_unused]] auto r = ::read(wakeFd, &count, sizeof count);
            std::vector<TextMessage> texts;
            {
                std::lock_guard lock(pendingMutex);
                texts.swap(pendingTexts);
            }
            for (auto& [id, c] : connections) {
                if (!c.negotiated) continue;
                for (const TextMessage& t : texts) enqueue(c, t);
            }
        }
        if (fds[1].revents & POLLIN) acceptAll();
        for (std::size_t i = 0; i < ids.size(); ++i) {
            auto it = connections.find(ids[i]);
            if (it == connections.end()) continue;
            Connection& c = it->second;
            short rev = fds[i + 2].revents;
            if (rev & (POLLIN | POLLHUP | POLLERR)) readFrom(c);
            if (!c.closed && (rev & POLLOUT)) flush(c);
        }
        const auto now = Clock::now();
        for (auto& [id, c] : connections) {
            if (!c.closed && c.started) stream(c, now);
            if (!c.closed && c.queued() > 0) flush(c);
        }
        for (auto it = connections.begin(); it != connections.end();) {
            if (it->second.closed) {
                it = connections.erase(it);
            } else {
                ++it;
            }
        }
        clientCount = connections.size();
        bool any = false;
        for (auto& [id, c] : connections) any = any || (c.started && !c.outputs.empty());
        streaming = any;
    }
}

void Server::Impl::acceptAll() {
    while (true) {
        int fd = ::accept4(listenFd, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) return;  // EAGAIN, or a connection that vanished before accept
        if (connections.size() >= config.maxClients) {
            ::close(fd);
            continue;
        }
        int one = 1;
        ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        if (config.socketSendBuffer > 0) {
            ::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &config.socketSendBuffer,
                         sizeof config.socketSendBuffer);
        }
        Connection c;
        c.id = nextConnectionId++;
        c.fd = fd;
        connections.emplace(c.id, std::move(c));
    }
}

void Server::Impl::readFrom(Connection& c) {
    std::uint8_t chunk[4096];
    // A bounded number of reads per wake-up so one busy client cannot starve the others.
    for (int round = 0; round < 16 && !c.closed; ++round) {
        ssize_t n = ::recv(c.fd, chunk, sizeof chunk, 0);
        if (n == 0) {
            close(c);
            return;
        }
        if (n < 0) {
            if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) return;
            close(c);
            return;
        }
        c.in.insert(c.in.end(), chunk, chunk + n);
        std::size_t pos = 0;
        while (!c.closed) {
            FrameResult f = decodeFrame(std::span(c.in).subspan(pos), Direction::toController);
            if (f.kind == FrameResult::Kind::needMore) break;
            if (f.kind == FrameResult::Kind::error) {
                fail(c, f.error.message);
                return;
            }
            pos += f.consumed;
            handle(c, std::move(f.package));
        }
        if (c.closed) return;
        c.in.erase(c.in.begin(), c.in.begin() + static_cast<std::ptrdiff_t>(pos));
        // The buffer holds less than one whole package (<= kMaxPackageSize) after decoding.
    }
}

void Server::Impl::handle(Connection& c, Package&& package) {
    if (auto* p = std::get_if<RequestProtocolVersion>(&package)) {
        const bool accepted = p->version == kProtocolVersion;
        if (accepted) c.negotiated = true;
        enqueue(c, ProtocolVersionReply{accepted});
        return;
    }
    if (std::holds_alternative<GetControllerVersion>(package)) {
        enqueue(c, config.controllerVersion);
        return;
    }
    if (!c.negotiated) {
        // Without version 2 the client may speak the version 1 layouts: refuse to guess.
        enqueue(c, TextMessage{"protocol version 2 must be negotiated first", "rtde",
                               WarningLevel::error});
        flush(c);
        close(c);
        return;
    }
    if (auto* p = std::get_if<SetupOutputs>(&package)) {
        handleSetupOutputs(c, *p);
    } else if (auto* p = std::get_if<SetupInputs>(&package)) {
        handleSetupInputs(c, *p);
    } else if (std::holds_alternative<Start>(package)) {
        c.started = true;
        enqueue(c, StartReply{true});
        // The first sample goes out at once, later ones on the recipe's grid.
        const auto now = Clock::now();
        const auto cycle = cycles.load() + 1;
        for (auto& [id, r] : c.outputs) {
            r.next = now;
            r.nextCycle = cycle;
        }
    } else if (std::holds_alternative<Pause>(package)) {
        c.started = false;
        enqueue(c, PauseReply{true});
    } else if (auto* p = std::get_if<DataPackage>(&package)) {
        handleData(c, *p);
    }
    // Text messages from clients are accepted and dropped (a controller would log them).
}

void Server::Impl::handleSetupOutputs(Connection& c, const SetupOutputs& request) {
    SetupOutputsReply reply;
    OutputRecipe recipe;
    bool ok = !request.names.empty();
    for (const std::string& name : request.names) {
        auto v = findVariable(name, VariableKind::output);
        if (!v) {
            reply.types.emplace_back("NOT_FOUND");
            ok = false;
            continue;
        }
        reply.types.emplace_back(typeName(v->type));
        recipe.names.push_back(name);
        recipe.types.push_back(v->type);
    }
    std::string problem;
    if (!(request.frequency >= 1.0 && request.frequency <= config.maxFrequency)) {
        problem = "output frequency must be within 1.." + std::to_string(config.maxFrequency);
    } else if (c.started) {
        problem = "recipes can only be set up while paused";
    } else if (c.nextRecipeId == 0) {
        problem = "no recipe ids left";
    }
    if (ok && problem.empty()) {
        recipe.period = std::chrono::duration_cast<Clock::duration>(
            std::chrono::duration<double>(1.0 / request.frequency));
        recipe.every = std::max<std::uint64_t>(
            1, static_cast<std::uint64_t>(std::llround(config.maxFrequency / request.frequency)));
        reply.recipeId = c.nextRecipeId++;  // wraps to 0 after 255: no further recipes
        c.outputs.emplace(reply.recipeId, std::move(recipe));
    }
    if (!problem.empty()) enqueue(c, TextMessage{problem, "rtde", WarningLevel::warning});
    enqueue(c, reply);
}

void Server::Impl::handleSetupInputs(Connection& c, const SetupInputs& request) {
    SetupInputsReply reply;
    InputRecipe recipe;
    bool ok = !request.names.empty() && !c.started && c.nextRecipeId != 0;
    for (const std::string& name : request.names) {
        auto v = findVariable(name, VariableKind::input);
        if (!v) {
            reply.types.emplace_back("NOT_FOUND");
            ok = false;
            continue;
        }
        auto owner = inputOwners.find(name);
        if (owner != inputOwners.end() && owner->second != c.id) {
            reply.types.emplace_back("IN_USE");
            ok = false;
            continue;
        }
        reply.types.emplace_back(typeName(v->type));
        recipe.names.push_back(name);
        recipe.types.push_back(v->type);
    }
    if (ok) {
        for (const std::string& name : recipe.names) inputOwners[name] = c.id;
        reply.recipeId = c.nextRecipeId++;
        c.inputs.emplace(reply.recipeId, std::move(recipe));
    }
    enqueue(c, reply);
}

void Server::Impl::handleData(Connection& c, const DataPackage& data) {
    auto it = c.inputs.find(data.recipeId);
    if (it == c.inputs.end()) {
        enqueue(
            c, TextMessage{"data package for unknown input recipe " + std::to_string(data.recipeId),
                           "rtde", WarningLevel::warning});
        return;
    }
    auto values = decodeValues(it->second.types, data.payload);
    if (auto* error = std::get_if<DecodeError>(&values)) {
        fail(c, error->message);
        return;
    }
    auto& list = std::get<std::vector<Value>>(values);
    for (std::size_t i = 0; i < list.size(); ++i) state.write(it->second.names[i], list[i]);
    state.endInputPackage();
}

Value Server::Impl::sample(const std::string& name, Type type) {
    try {
        Value v = state.read(name);
        if (typeOf(v) == type) return v;
    } catch (...) {
        // A failing state must not take the network thread down; the zero is sent instead.
    }
    return defaultValue(type);
}

void Server::Impl::stream(Connection& c, Clock::time_point now) {
    const std::uint64_t cycle = cycles.load();
    for (auto& [id, r] : c.outputs) {
        if (config.externalCycle) {
            if (cycle < r.nextCycle) continue;
            // One sample of the newest state however many cycles passed since the last.
            r.nextCycle += r.every * ((cycle - r.nextCycle) / r.every + 1);
        } else if (now < r.next) {
            continue;
        }
        if (c.queued() > config.softQueueLimit) {
            ++skipped;  // the client does not keep up: it gets the newest sample later
        } else {
            std::vector<Value> values;
            values.reserve(r.names.size());
            for (std::size_t i = 0; i < r.names.size(); ++i) {
                values.push_back(sample(r.names[i], r.types[i]));
            }
            enqueue(c, DataPackage{id, encodeValues(values)});
            ++sent;
        }
        if (config.externalCycle) continue;
        // Absolute deadlines on the recipe's grid: no drift; missed slots are skipped.
        r.next += r.period;
        if (r.next <= now) {
            auto behind = (now - r.next) / r.period + 1;
            r.next += behind * r.period;
        }
    }
}

void Server::Impl::enqueue(Connection& c, const Package& package) {
    if (c.closed) return;
    auto bytes = encode(package);
    if (c.queued() + bytes.size() > config.hardQueueLimit) {
        fail(c, "send queue overflow");
        return;
    }
    if (c.outOffset > 0 && c.outOffset >= c.out.size() / 2) {
        c.out.erase(c.out.begin(), c.out.begin() + static_cast<std::ptrdiff_t>(c.outOffset));
        c.outOffset = 0;
    }
    c.out.insert(c.out.end(), bytes.begin(), bytes.end());
}

void Server::Impl::flush(Connection& c) {
    while (!c.closed && c.queued() > 0) {
        ssize_t n = ::send(c.fd, c.out.data() + c.outOffset, c.queued(), MSG_NOSIGNAL);
        if (n < 0) {
            if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) return;
            close(c);
            return;
        }
        c.outOffset += static_cast<std::size_t>(n);
    }
    if (c.queued() == 0) {
        c.out.clear();
        c.outOffset = 0;
    }
}

void Server::Impl::fail(Connection& c, const std::string& why) {
    ++errorCloses;
    if (config.log) config.log("rtde: closing connection " + std::to_string(c.id) + ": " + why);
    close(c);
}

void Server::Impl::close(Connection& c) {
    if (c.closed) return;
    c.closed = true;
    ::close(c.fd);
    c.fd = -1;
    for (auto it = inputOwners.begin(); it != inputOwners.end();) {
        if (it->second == c.id) {
            it = inputOwners.erase(it);
        } else {
            ++it;
        }
    }
}

}  // namespace pnp::rtde
