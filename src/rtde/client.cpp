#include "rtde/client.hpp"

#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace pnp::rtde {

std::string_view codeName(Code code) {
    switch (code) {
        case Code::ok:
            return "ok";
        case Code::timeout:
            return "timeout";
        case Code::notConnected:
            return "notConnected";
        case Code::closed:
            return "closed";
        case Code::io:
            return "io";
        case Code::protocol:
            return "protocol";
        case Code::rejected:
            return "rejected";
        case Code::invalidArgument:
            return "invalidArgument";
    }
    return "?";
}

namespace {

// Milliseconds left until the deadline, rounded up so poll() does not wake early; 0 if past.
int msLeft(Deadline deadline) {
    auto left = deadline - Clock::now();
    if (left <= Clock::duration::zero()) return 0;
    auto ms = std::chrono::ceil<std::chrono::milliseconds>(left).count();
    return static_cast<int>(std::min<long long>(ms, 60'000));
}

std::string errnoText(const char* what, int e) {
    return std::string(what) + ": " + std::strerror(e);
}

}  // namespace

Client::Client(ClientConfig config) : config_(config) {}

Client::~Client() { close(); }

void Client::close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    in_.clear();
    queue_.clear();
    outputRecipes_.clear();
    inputRecipes_.clear();
}

Status Client::failed(Code code, std::string message) {
    // After an I/O or protocol error, or a request without its reply, the byte stream cannot be
    // trusted any more.
    close();
    return {code, std::move(message)};
}

Status Client::connect(const std::string& host, std::uint16_t port, Deadline deadline) {
    close();
    addrinfo hints{};
    hints.ai_family = AF_INET;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* list = nullptr;
    // Name resolution is not bounded by the deadline; numeric addresses resolve at once.
    int rc = ::getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &list);
    if (rc != 0 || list == nullptr) {
        return {Code::io, "cannot resolve " + host + ": " + ::gai_strerror(rc)};
    }
    sockaddr_storage addr{};
    std::memcpy(&addr, list->ai_addr, list->ai_addrlen);
    socklen_t addrLen = list->ai_addrlen;
    ::freeaddrinfo(list);

    int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) return {Code::io, errnoText("socket", errno)};
    int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), addrLen) < 0) {
        if (errno != EINPROGRESS) {
            int e = errno;
            ::close(fd);
            return {e == ECONNREFUSED ? Code::closed : Code::io, errnoText("connect", e)};
        }
        while (true) {
            pollfd p{fd, POLLOUT, 0};
            int n = ::poll(&p, 1, msLeft(deadline));
            if (n < 0 && errno == EINTR) continue;
            if (n == 0) {
                ::close(fd);
                return {Code::timeout, "connect to " + host + " timed out"};
            }
            int err = 0;
            socklen_t len = sizeof err;
            ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &err, &len);
            if (n < 0 || err != 0) {
                ::close(fd);
                return {err == ECONNREFUSED ? Code::closed : Code::io,
                        errnoText("connect", n < 0 ? errno : err)};
            }
            break;
        }
    }
    fd_ = fd;
    return {};
}

Status Client::write(const Package& package, Deadline deadline) {
    if (fd_ < 0) return {Code::notConnected, "not connected"};
    std::vector<std::uint8_t> bytes;
    try {
        bytes = encode(package);
    } catch (const std::length_error& e) {
        return {Code::invalidArgument, e.what()};
    }
    std::size_t done = 0;
    while (done < bytes.size()) {
        ssize_t n = ::send(fd_, bytes.data() + done, bytes.size() - done, MSG_NOSIGNAL);
        if (n >= 0) {
            done += static_cast<std::size_t>(n);
            continue;
        }
        if (errno == EINTR) continue;
        if (errno != EAGAIN && errno != EWOULDBLOCK) {
            Code code = (errno == EPIPE || errno == ECONNRESET) ? Code::closed : Code::io;
            return failed(code, errnoText("send", errno));
        }
        pollfd p{fd_, POLLOUT, 0};
        int r = ::poll(&p, 1, msLeft(deadline));
        if (r == 0) {
            // A half-written package would corrupt the stream.
            if (done > 0) return failed(Code::timeout, "send timed out mid-package");
            return {Code::timeout, "send timed out"};
        }
    }
    return {};
}

Status Client::readPackage(Deadline deadline, Package& out) {
    if (fd_ < 0) return {Code::notConnected, "not connected"};
    while (true) {
        FrameResult f = decodeFrame(in_, Direction::toClient);
        if (f.kind == FrameResult::Kind::package) {
            in_.erase(in_.begin(), in_.begin() + static_cast<std::ptrdiff_t>(f.consumed));
            out = std::move(f.package);
            return {};
        }
        if (f.kind == FrameResult::Kind::error) {
            return failed(Code::protocol,
                          "malformed package from the controller: " + f.error.message);
        }
        pollfd p{fd_, POLLIN, 0};
        int n = ::poll(&p, 1, msLeft(deadline));
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) return failed(Code::io, errnoText("poll", errno));
        if (n == 0) return {Code::timeout, "no package before the deadline"};
        std::uint8_t chunk[4096];
        ssize_t got = ::recv(fd_, chunk, sizeof chunk, 0);
        if (got == 0) return failed(Code::closed, "the controller closed the connection");
        if (got < 0) {
            if (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) continue;
            return failed(errno == ECONNRESET ? Code::closed : Code::io, errnoText("recv", errno));
        }
        in_.insert(in_.end(), chunk, chunk + got);
    }
}

Status Client::keep(Package&& package) {
    if (auto* text = std::get_if<TextMessage>(&package)) {
        queue_.emplace_back(std::move(*text));
    } else if (auto* data = std::get_if<DataPackage>(&package)) {
        auto it = outputRecipes_.find(data->recipeId);
        if (it == outputRecipes_.end()) {
            return failed(Code::protocol, "data package for unknown output recipe " +
                                              std::to_string(data->recipeId));
        }
        auto values = decodeValues(it->second, data->payload);
        if (auto* error = std::get_if<DecodeError>(&values)) {
            return failed(Code::protocol, error->message);
        }
        queue_.emplace_back(
            DataSample{data->recipeId, std::move(std::get<std::vector<Value>>(values))});
    } else {
        return failed(Code::protocol,
                      "unexpected reply package '" +
                          std::string(1, static_cast<char>(packageTypeOf(package))) + "'");
    }
    while (queue_.size() > config_.maxQueued) {
        queue_.pop_front();
        ++dropped_;
    }
    return {};
}

template <class Reply>
Result<Reply> Client::request(const Package& package, Deadline deadline) {
    if (Status s = write(package, deadline); !s.ok()) return s;
    while (true) {
        Package reply;
        if (Status s = readPackage(deadline, reply); !s.ok()) {
            if (s.code == Code::timeout) {
                // A late reply would be taken for the answer to the next request.
                return failed(Code::timeout, "no reply before the deadline");
            }
            return s;
        }
        if (auto* r = std::get_if<Reply>(&reply)) return std::move(*r);
        if (Status s = keep(std::move(reply)); !s.ok()) return s;
    }
}

Status Client::negotiateProtocolVersion(Deadline deadline, std::uint16_t version) {
    auto r = request<ProtocolVersionReply>(RequestProtocolVersion{version}, deadline);
    if (!r.ok()) return r.status();
    if (!r.value().accepted) {
        return {Code::rejected, "protocol version " + std::to_string(version) + " not accepted"};
    }
    return {};
}

Result<ControllerVersion> Client::getControllerVersion(Deadline deadline) {
    return request<ControllerVersion>(GetControllerVersion{}, deadline);
}

namespace {

Result<Recipe> toRecipe(const SetupReply& reply, std::vector<std::string> names) {
    Recipe recipe;
    recipe.id = reply.recipeId;
    recipe.names = std::move(names);
    recipe.typeNames = reply.types;
    if (recipe.typeNames.size() != recipe.names.size()) {
        return Status{Code::protocol, "setup reply has " + std::to_string(reply.types.size()) +
                                          " types for " + std::to_string(recipe.names.size()) +
                                          " names"};
    }
    if (!recipe.valid()) return recipe;
    for (const std::string& t : recipe.typeNames) {
        auto type = parseTypeName(t);
        if (!type)
            return Status{Code::protocol,
                          "recipe " + std::to_string(recipe.id) + " has unknown type " + t};
        recipe.types.push_back(*type);
    }
    return recipe;
}

}  // namespace

Result<Recipe> Client::setupOutputs(double frequency, std::vector<std::string> names,
                                    Deadline deadline) {
    auto r = request<SetupOutputsReply>(SetupOutputs{frequency, names}, deadline);
    if (!r.ok()) return r.status();
    auto recipe = toRecipe(r.value(), std::move(names));
    if (!recipe.ok()) return failed(recipe.status().code, recipe.status().message);
    if (recipe->valid()) outputRecipes_[recipe->id] = recipe->types;
    return recipe;
}

Result<Recipe> Client::setupInputs(std::vector<std::string> names, Deadline deadline) {
    auto r = request<SetupInputsReply>(SetupInputs{names}, deadline);
    if (!r.ok()) return r.status();
    auto recipe = toRecipe(r.value(), std::move(names));
    if (!recipe.ok()) return failed(recipe.status().code, recipe.status().message);
    if (recipe->valid()) inputRecipes_[recipe->id] = recipe->types;
    return recipe;
}

Status Client::start(Deadline deadline) {
    auto r = request<StartReply>(Start{}, deadline);
    if (!r.ok()) return r.status();
    if (!r.value().accepted) return {Code::rejected, "start not accepted"};
    return {};
}

Status Client::pause(Deadline deadline) {
    auto r = request<PauseReply>(Pause{}, deadline);
    if (!r.ok()) return r.status();
    if (!r.value().accepted) return {Code::rejected, "pause not accepted"};
    return {};
}

Result<Received> Client::receive(Deadline deadline) {
    while (queue_.empty()) {
        Package p;
        if (Status s = readPackage(deadline, p); !s.ok()) return s;
        if (Status s = keep(std::move(p)); !s.ok()) return s;
    }
    Received r = std::move(queue_.front());
    queue_.pop_front();
    return r;
}

Status Client::send(std::uint8_t recipeId, std::span<const Value> values, Deadline deadline) {
    if (fd_ < 0) return {Code::notConnected, "not connected"};
    auto it = inputRecipes_.find(recipeId);
    if (it == inputRecipes_.end()) {
        return {Code::invalidArgument, "no input recipe " + std::to_string(recipeId)};
    }
    const auto& types = it->second;
    if (values.size() != types.size()) {
        return {Code::invalidArgument, "recipe " + std::to_string(recipeId) + " has " +
                                           std::to_string(types.size()) + " variables, got " +
                                           std::to_string(values.size()) + " values"};
    }
    for (std::size_t i = 0; i < values.size(); ++i) {
        if (typeOf(values[i]) != types[i]) {
            return {Code::invalidArgument, "value " + std::to_string(i) + " is " +
                                               std::string(typeName(typeOf(values[i]))) +
                                               ", the recipe wants " +
                                               std::string(typeName(types[i]))};
        }
    }
    return write(DataPackage{recipeId, encodeValues(values)}, deadline);
}

Status Client::sendText(const TextMessage& message, Deadline deadline) {
    return write(message, deadline);
}

}  // namespace pnp::rtde
