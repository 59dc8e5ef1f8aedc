// RTDE client: the adapter side of the protocol. Blocking calls, each with an absolute deadline,
// on one non-blocking socket; no thread of its own. Not thread-safe: use it from one thread at a
// time. Data packages and text messages that arrive while a call waits for its reply are kept
// (bounded) for receive().
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "rtde/codec.hpp"

namespace pnp::rtde {

using Clock = std::chrono::steady_clock;
using Deadline = Clock::time_point;
inline Deadline deadlineIn(std::chrono::milliseconds timeout) { return Clock::now() + timeout; }

enum class Code {
    ok,
    timeout,          // the deadline passed
    notConnected,     // connect() first, or the connection was closed after an error
    closed,           // the controller closed the connection
    io,               // a socket error (errno in the message)
    protocol,         // the controller sent something malformed or unexpected
    rejected,         // the controller answered "not accepted"
    invalidArgument,  // a request that cannot be encoded or does not match the recipe
};

std::string_view codeName(Code code);

struct Status {
    Code code = Code::ok;
    std::string message;
    bool ok() const { return code == Code::ok; }
};

template <class T>
class Result {
  public:
    Result(T value) : value_(std::move(value)) {}  // NOLINT: implicit by design
    Result(Status status) : status_(std::move(status)) {}
    bool ok() const { return status_.ok(); }
    const Status& status() const { return status_; }
    T& value() { return *value_; }
    const T& value() const { return *value_; }
    T* operator->() { return &*value_; }

  private:
    Status status_;
    std::optional<T> value_;
};

// A recipe as the controller answered it. id 0 = not set up; types then name the culprits
// ("NOT_FOUND", "IN_USE") among the valid type names.
struct Recipe {
    std::uint8_t id = 0;
    std::vector<std::string> names;
    std::vector<std::string> typeNames;  // as sent by the controller
    std::vector<Type> types;             // parsed, when id != 0
    bool valid() const { return id != 0; }
};

struct DataSample {
    std::uint8_t recipeId = 0;
    std::vector<Value> values;  // in the recipe's order
};

using Received = std::variant<DataSample, TextMessage>;

struct ClientConfig {
    // Received packages kept while a call waits for a reply; the oldest go first beyond this.
    std::size_t maxQueued = 4096;
};

class Client {
  public:
    explicit Client(ClientConfig config = {});
    ~Client();
    Client(const Client&) = delete;
    Client& operator=(const Client&) = delete;

    Status connect(const std::string& host, std::uint16_t port, Deadline deadline);
    void close();
    bool connected() const { return fd_ >= 0; }

    // Requests `version` (2 by default); Code::rejected when the controller refuses it.
    Status negotiateProtocolVersion(Deadline deadline, std::uint16_t version = kProtocolVersion);
    Result<ControllerVersion> getControllerVersion(Deadline deadline);
    // ok with !recipe.valid() when the controller refused the recipe (see typeNames).
    Result<Recipe> setupOutputs(double frequency, std::vector<std::string> names,
                                Deadline deadline);
    Result<Recipe> setupInputs(std::vector<std::string> names, Deadline deadline);
    Status start(Deadline deadline);
    Status pause(Deadline deadline);

    // The next data sample or text message from the controller.
    Result<Received> receive(Deadline deadline);
    // Writes an input recipe's values (checked against the recipe's types).
    Status send(std::uint8_t recipeId, std::span<const Value> values, Deadline deadline);
    Status sendText(const TextMessage& message, Deadline deadline);

    std::uint64_t droppedPackages() const { return dropped_; }

  private:
    Status write(const Package& package, Deadline deadline);
    Status readPackage(Deadline deadline, Package& out);
    template <class Reply>
    Result<Reply> request(const Package& package, Deadline deadline);
    Status keep(Package&& package);
    Status failed(Code code, std::string message);

    ClientConfig config_;
    int fd_ = -1;
    std::vector<std::uint8_t> in_;
    std::deque<Received> queue_;
    std::map<std::uint8_t, std::vector<Type>> outputRecipes_;
    std::map<std::uint8_t, std::vector<Type>> inputRecipes_;
    std::uint64_t dropped_ = 0;
};

}  // namespace pnp::rtde
