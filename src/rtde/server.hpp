// RTDE server: the controller side of the protocol, for the robot simulator. One network thread
// serves every client (poll on non-blocking sockets); output recipes are streamed from absolute
// steady-clock deadlines. See README.md for the design and the limits.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "rtde/catalogue.hpp"
#include "rtde/codec.hpp"

namespace pnp::rtde {

// The controller's variables as the server sees them; the simulator implements it. Called on the
// server's network thread only: read() for each variable of an output recipe at every sample,
// write() for each value of an input data package. Implementations lock their own data. A value
// of the wrong type from read() is replaced by the type's zero (the wire stays well-formed).
class ControllerState {
  public:
    virtual ~ControllerState() = default;
    virtual Value read(std::string_view name) = 0;
    virtual void write(std::string_view name, const Value& value) = 0;
    // After the write()s of one input data package: a controller that takes a stream of
    // packages (a simulator's servo) can tell them apart. Network thread.
    virtual void endInputPackage() {}
};

// A thread-safe map of every catalogue variable (zero at first): enough for tests and a simple
// simulator, which sets outputs with set() and sees the inputs with get().
class RegisterStore : public ControllerState {
  public:
    RegisterStore();
    Value read(std::string_view name) override;
    void write(std::string_view name, const Value& value) override;
    // For the owner of the store; unknown names are ignored / yield std::nullopt.
    void set(std::string_view name, const Value& value);
    std::optional<Value> get(std::string_view name) const;
    std::uint64_t writeCount() const;  // input values written by clients so far

  private:
    mutable std::mutex mutex_;
    std::map<std::string, Value, std::less<>> values_;
    std::uint64_t writes_ = 0;
};

struct ServerConfig {
    std::string bindAddress = "0.0.0.0";  // IPv4
    std::uint16_t port = kDefaultPort;    // 0 = an ephemeral port, see Server::port()
    ControllerVersion controllerVersion{5, 15, 0, 0};
    double maxFrequency = 500.0;  // Hz, e-Series control loop
    std::size_t maxClients = 32;  // further connections are accepted and closed at once
    // Bytes queued for one client before data packages are skipped for it; replies and text
    // messages are still queued up to hardQueueLimit, beyond that the client is dropped.
    std::size_t softQueueLimit = 16 * 1024;
    std::size_t hardQueueLimit = 256 * 1024;
    // SO_SNDBUF of each connection (0 = the kernel's default, which grows to megabytes): small,
    // so that a lagging client is noticed soon and gets fresh samples instead of stale ones.
    int socketSendBuffer = 32 * 1024;
    // Samples go out on cycle() (the controller's control cycle: a simulator's step loop,
    // at maxFrequency), as a real controller publishes its state once per cycle, instead of
    // on the server's own clock. A recipe at maxFrequency / N gets every Nth cycle.
    bool externalCycle = false;
    // SCHED_FIFO priority of the network thread (1..99; 0 = normal scheduling), as a
    // controller's real-time communication; kept at normal scheduling where not permitted.
    int realtimePriority = 0;
    // Told why a connection was dropped (malformed package, overflow); network thread.
    std::function<void(std::string_view)> log;
};

struct ServerStats {
    std::size_t clients = 0;
    std::uint64_t dataPackagesSent = 0;
    std::uint64_t dataPackagesSkipped = 0;  // a client's send queue was full
    std::uint64_t connectionsClosedForErrors = 0;
};

class Server {
  public:
    // `state` must outlive the server.
    Server(ServerConfig config, ControllerState& state);
    ~Server();  // stop()
    Server(const Server&) = delete;
    Server& operator=(const Server&) = delete;

    // Binds, listens and starts the network thread; throws std::system_error.
    void start();
    // Closes every connection and joins the thread; start() may be called again.
    void stop();
    std::uint16_t port() const;  // the bound port (after start())

    // Sends a text message to every client that negotiated the protocol version. Any thread,
    // but not concurrently with start() / stop().
    void sendText(const TextMessage& message);
    // externalCycle: one control cycle has passed (its state is ready to read). Any thread;
    // never blocks (the network thread sends).
    void cycle();
    ServerStats stats() const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::rtde
