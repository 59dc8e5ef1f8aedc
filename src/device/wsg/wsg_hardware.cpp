#include "device/wsg/wsg_hardware.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <thread>

namespace pnp::device::wsg {

namespace w = pnp::wsg;
using gripper::Clock;
using gripper::Deadline;
using gripper::Done;
using gripper::Error;
using gripper::ErrorKind;
using gripper::Result;
using w::Status;

namespace {

constexpr auto kCancelPoll = std::chrono::milliseconds(20);
// After a STOP: how long the result of the stopped motion may take (the jaws brake).
constexpr auto kStopGrace = std::chrono::milliseconds(500);
constexpr std::size_t kMaxInbox = 64;

int remainingMs(Deadline deadline) {
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
    return static_cast<int>(std::clamp<long long>(left, 0, 60'000));
}

std::string mm(double metres) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.1f mm", metres * 1000.0);
    return buf;
}

}  // namespace

Eigen::Isometry3d defaultGripPointOffset() {
    return Eigen::Isometry3d(Eigen::Translation3d(0.0, 0.0, 0.19));
}

std::optional<std::pair<std::string, std::uint16_t>> parseAddress(std::string_view address) {
    std::string_view host = address;
    std::uint16_t port = w::kDefaultPort;
    if (const auto colon = address.rfind(':'); colon != std::string_view::npos) {
        host = address.substr(0, colon);
        const std::string_view digits = address.substr(colon + 1);
        unsigned value = 0;
        const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
        if (digits.empty() || ec != std::errc() || end != digits.data() + digits.size() ||
            value == 0 || value > 65535) {
            return std::nullopt;
        }
        port = static_cast<std::uint16_t>(value);
    }
    if (host.empty()) return std::nullopt;
    return std::pair{std::string(host), port};
}

WsgHardware::WsgHardware(WsgHardwareConfig config) : config_(std::move(config)) {}

WsgHardware::~WsgHardware() { disconnect(); }

std::string WsgHardware::where() const {
    return "the WSG at " + config_.host + ":" + std::to_string(config_.port);
}

std::string WsgHardware::endpoint() const {
    return "tcp://" + config_.host + ":" + std::to_string(config_.port);
}

std::string WsgHardware::modelName() const {
    std::lock_guard lock(info_);
    if (!information_) return "WSG 50";
    return std::string(w::deviceTypeName(information_->type));
}

std::string WsgHardware::serialNumber() const {
    std::lock_guard lock(info_);
    return information_ ? std::to_string(information_->serialNumber) : std::string();
}

std::string WsgHardware::firmwareVersion() const {
    std::lock_guard lock(info_);
    return information_ ? w::firmwareString(information_->firmware) : std::string();
}

gripper::GripPoint WsgHardware::gripPoint() const {
    gripper::GripPoint p;
    p.name = "Tip";
    p.kind = gripper::GripKind::kParallel;
    p.offset = config_.gripPointOffset;
    p.spanMin = 0.0;
    p.spanMax = config_.stroke;
    return p;
}

// ---------------------------------------------------------------- transport

void WsgHardware::closeSocket() {
    std::lock_guard lock(send_);
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    decoder_.reset();
    inbox_.clear();
}

Result<Done> WsgHardware::open(Deadline deadline) {
    addrinfo hints{};
    hints.ai_family = AF_INET;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* found = nullptr;
    const std::string service = std::to_string(config_.port);
    // Numeric addresses resolve at once; a name goes through the resolver (its own timeout).
    if (::getaddrinfo(config_.host.c_str(), service.c_str(), &hints, &found) != 0 || !found) {
        return Error{ErrorKind::kNoDevice, "cannot resolve " + where()};
    }
    sockaddr_in addr{};
    std::memcpy(&addr, found->ai_addr, std::min<std::size_t>(sizeof addr, found->ai_addrlen));
    ::freeaddrinfo(found);

    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) return Error{ErrorKind::kNoDevice, "socket: " + std::string(std::strerror(errno))};
    int rc = ::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
    if (rc != 0 && errno == EINPROGRESS) {
        pollfd p{fd, POLLOUT, 0};
        rc = ::poll(&p, 1, remainingMs(deadline));
        if (rc == 0) {
            ::close(fd);
            return Error{ErrorKind::kNoDevice,
                         "no answer from " + where() + " (connect timed out)"};
        }
        int error = 0;
        socklen_t len = sizeof error;
        ::getsockopt(fd, SOL_SOCKET, SO_ERROR, &error, &len);
        errno = error;
        rc = error == 0 ? 0 : -1;
    }
    if (rc != 0) {
        const std::string reason = std::strerror(errno);
        ::close(fd);
        return Error{ErrorKind::kNoDevice, "no answer from " + where() + ": " + reason};
    }
    const int one = 1;
    ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    {
        std::lock_guard lock(send_);
        fd_ = fd;
    }
    decoder_.reset();
    inbox_.clear();

    auto info = request(Command::kGetSystemInformation, {}, deadline, "system information");
    if (!info.ok()) {
        closeSocket();
        if (info.error().kind == ErrorKind::kTimeout) {
            return Error{ErrorKind::kNoDevice,
                         "no answer from " + where() + " (connected, but no WSG answers)"};
        }
        return info.error();
    }
    const auto parsed = w::parseSystemInformation(info->values);
    if (!parsed) {
        closeSocket();
        return Error{ErrorKind::kProtocol, "short system information from " + where()};
    }
    std::lock_guard lock(info_);
    information_ = *parsed;
    return Done{};
}

Result<Done> WsgHardware::ensureConnected(Deadline deadline) {
    if (fd_ >= 0) return Done{};
    return open(deadline);
}

Result<Done> WsgHardware::send(Command command, const std::vector<std::uint8_t>& payload,
                               Deadline deadline) {
    const std::vector<std::uint8_t> frame = w::encodeCommand(command, payload);
    std::unique_lock lock(send_);
    if (fd_ < 0) return Error{ErrorKind::kNoDevice, "not connected to " + where()};
    std::size_t sent = 0;
    while (sent < frame.size()) {
        const ssize_t n = ::send(fd_, frame.data() + sent, frame.size() - sent, MSG_NOSIGNAL);
        if (n > 0) {
            sent += static_cast<std::size_t>(n);
            continue;
        }
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
            pollfd p{fd_, POLLOUT, 0};
            if (::poll(&p, 1, remainingMs(deadline)) <= 0) {
                return Error{ErrorKind::kTimeout, "sending to " + where() + " timed out"};
            }
            continue;
        }
        const std::string reason = n < 0 ? std::strerror(errno) : "closed";
        lock.unlock();
        closeSocket();
        return Error{ErrorKind::kNoDevice, "connection to " + where() + " lost: " + reason};
    }
    return Done{};
}

Result<w::Response> WsgHardware::await(Command command, Deadline deadline,
                                       const std::atomic<bool>* cancel) {
    const auto id = static_cast<std::uint8_t>(command);
    // Bounded: every pass either returns, consumes a frame, or waits ≥ one poll slice.
    for (int pass = 0; pass < 1'000'000; ++pass) {
        while (!inbox_.empty()) {
            w::Frame f = std::move(inbox_.front());
            inbox_.pop_front();
            if (f.error != w::FrameError::kNone) {
                return Error{ErrorKind::kProtocol,
                             "a corrupt frame from " + where() + " (" +
                                 std::string(f.error == w::FrameError::kChecksum ? "bad checksum"
                                                                                 : "oversized") +
                                 ")"};
            }
            if (f.id != id) continue;  // a late answer to an earlier call
            auto r = w::parseResponse(f);
            if (!r) {
                return Error{ErrorKind::kProtocol, "an answer without status from " + where()};
            }
            return std::move(*r);
        }
        if (cancel && cancel->load()) return Error{ErrorKind::kCancelled, "cancelled"};
        const auto now = Clock::now();
        if (now >= deadline) {
            return Error{ErrorKind::kTimeout, "no answer to " + std::string(w::commandName(id)) +
                                                  " from " + where() + " within the deadline"};
        }
        if (fd_ < 0) return Error{ErrorKind::kNoDevice, "not connected to " + where()};
        auto slice = deadline;
        if (cancel) slice = std::min(deadline, now + kCancelPoll);
        pollfd p{fd_, POLLIN, 0};
        const int rc = ::poll(&p, 1, std::max(1, remainingMs(slice)));
        if (rc < 0 && errno != EINTR) {
            closeSocket();
            return Error{ErrorKind::kNoDevice, "poll: " + std::string(std::strerror(errno))};
        }
        if (rc <= 0) continue;
        std::uint8_t buf[2048];
        const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
        if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
            closeSocket();
            return Error{ErrorKind::kNoDevice, "connection to " + where() + " closed"};
        }
        if (n < 0) continue;
        for (w::Frame& f : decoder_.feed(std::span(buf, static_cast<std::size_t>(n)))) {
            if (inbox_.size() >= kMaxInbox) inbox_.pop_front();
            inbox_.push_back(std::move(f));
        }
    }
    return Error{ErrorKind::kTimeout, "no answer from " + where()};
}

Result<w::Response> WsgHardware::request(Command command, const std::vector<std::uint8_t>& payload,
                                         Deadline deadline, std::string_view what) {
    if (auto s = send(command, payload, deadline); !s.ok()) return s.error();
    auto r = await(command, deadline, nullptr);
    if (!r.ok()) return r.error();
    if (!r->ok()) return deviceError(what, r->status);
    return r;
}

Result<std::uint16_t> WsgHardware::motion(Command command, const std::vector<std::uint8_t>& payload,
                                          Deadline deadline, const std::atomic<bool>& cancel,
                                          std::string_view what) {
    if (cancel) return Error{ErrorKind::kCancelled, std::string(what) + " cancelled"};
    if (auto s = send(command, payload, deadline); !s.ok()) return s.error();
    bool accepted = false;
    for (int answer = 0; answer < 2; ++answer) {
        auto r = await(command, deadline, &cancel);
        if (!r.ok()) {
            if (r.error().kind == ErrorKind::kCancelled || r.error().kind == ErrorKind::kTimeout) {
                if (accepted || r.error().kind == ErrorKind::kCancelled) {
                    stopMotion(command, std::max(deadline, Clock::now() + kStopGrace));
                }
                if (r.error().kind == ErrorKind::kCancelled) {
                    return Error{ErrorKind::kCancelled,
                                 std::string(what) + " cancelled: the gripper was stopped"};
                }
                return Error{ErrorKind::kTimeout, std::string(what) +
                                                      " did not finish within the deadline; "
                                                      "the gripper was stopped"};
            }
            return r.error();
        }
        if (!r->pending()) return r->status;
        accepted = true;
    }
    return Error{ErrorKind::kProtocol, "two E_CMD_PENDING answers from " + where()};
}

void WsgHardware::stopMotion(Command running, Deadline deadline) {
    const Deadline grace = std::min(deadline, Clock::now() + kStopGrace);
    if (!send(Command::kStop, {}, grace).ok()) return;
    // The STOP is answered, and so (E_CMD_ABORTED) is the motion: both consumed here so
    // that no stale answer meets the next call.
    [[maybe_unused]] auto stopped = await(Command::kStop, grace, nullptr);
    [[maybe_unused]] auto result = await(running, grace, nullptr);
}

Error WsgHardware::deviceError(std::string_view what, std::uint16_t status) const {
    const std::string name(w::statusName(status));
    const std::string text = std::string(what) + ": " + name;
    switch (static_cast<Status>(status)) {
        case Status::kRangeError:
        case Status::kInvalidParameter:
        case Status::kAlreadyRunning:
            return {ErrorKind::kRefused, text};
        case Status::kNotInitialized:
            return {ErrorKind::kRefused, text + " (not homed: activate first)"};
        case Status::kAccessDenied:
            return {ErrorKind::kRefused, text + " (a fast stop to acknowledge, or a part held)"};
        case Status::kCmdUnknown:
        case Status::kCmdFormatError:
        case Status::kChecksumError:
        case Status::kNoParamExpected:
        case Status::kNotEnoughParams:
        case Status::kInsufficientResources:
            return {ErrorKind::kProtocol, text + " from " + where()};
        case Status::kCmdAborted:
            return {ErrorKind::kFault, text + " (stopped at the gripper: stop or fast stop)"};
        default:
            return {ErrorKind::kFault, text};
    }
}

// ---------------------------------------------------------------- GripperHardware

Result<Done> WsgHardware::connect(Deadline deadline) {
    std::lock_guard lock(io_);
    if (fd_ >= 0) return Done{};
    return open(deadline);
}

void WsgHardware::disconnect() {
    std::lock_guard lock(io_);
    if (fd_ < 0) return;
    const Deadline deadline = Clock::now() + std::chrono::milliseconds(200);
    if (send(Command::kDisconnect, {}, deadline).ok()) {
        [[maybe_unused]] auto r = await(Command::kDisconnect, deadline, nullptr);
    }
    closeSocket();
}

Result<gripper::Status> WsgHardware::readStatus(Deadline deadline) {
    auto flags = request(Command::kGetSystemState, w::queryPayload(), deadline, "system state");
    if (!flags.ok()) return flags.error();
    auto state = request(Command::kGetGraspingState, w::queryPayload(), deadline, "grasping state");
    if (!state.ok()) return state.error();
    auto width = request(Command::kGetOpeningWidth, w::queryPayload(), deadline, "opening width");
    if (!width.ok()) return width.error();
    const auto f = w::getU32(flags->values, 0);
    const auto mmWidth = w::getFloat(width->values, 0);
    if (!f || state->values.empty() || !mmWidth || !std::isfinite(*mmWidth)) {
        return Error{ErrorKind::kProtocol, "a short state answer from " + where()};
    }
    gripper::Status s;
    const std::uint8_t g = state->values[0];
    const bool fastStop = (*f & w::system_flag::kFastStop) != 0;
    s.ready = (*f & w::system_flag::kReferenced) != 0 && !fastStop;
    s.moving = (*f & w::system_flag::kMoving) != 0;
    s.holding = g == static_cast<std::uint8_t>(w::GraspingState::kHolding);
    s.width = *mmWidth / 1000.0;
    if (fastStop) {
        s.fault = "fast stop (acknowledge it: activate)";
    } else if (g == static_cast<std::uint8_t>(w::GraspingState::kError)) {
        s.fault = "grasping state ERROR";
    }
    return s;
}

Result<gripper::Status> WsgHardware::status(Deadline deadline) {
    std::lock_guard lock(io_);
    if (auto c = ensureConnected(deadline); !c.ok()) return c.error();
    return readStatus(deadline);
}

Result<Done> WsgHardware::activate(Deadline deadline, const std::atomic<bool>& cancel) {
    std::lock_guard lock(io_);
    if (auto c = ensureConnected(deadline); !c.ok()) return c.error();
    auto flags = request(Command::kGetSystemState, w::queryPayload(), deadline, "system state");
    if (!flags.ok()) return flags.error();
    const std::uint32_t f = w::getU32(flags->values, 0).value_or(0);
    if (f & w::system_flag::kFastStop) {
        auto ack = request(Command::kAcknowledgeFastStop, w::acknowledgeFastStopPayload(), deadline,
                           "acknowledge fast stop");
        if (!ack.ok()) return ack.error();
    }
    if (f & w::system_flag::kReferenced) return Done{};
    auto r = motion(Command::kHoming, w::homingPayload(0), deadline, cancel, "homing");
    if (!r.ok()) return r.error();
    if (*r != static_cast<std::uint16_t>(Status::kSuccess)) return deviceError("homing", *r);
    return Done{};
}

Result<gripper::Status> WsgHardware::grasp(const gripper::GraspRequest& request, Deadline deadline,
                                           const std::atomic<bool>& cancel) {
    if (!(request.width >= 0.0 && request.width <= config_.stroke)) {
        return Error{ErrorKind::kRefused,
                     "grasp width " + mm(request.width) + " outside 0.." + mm(config_.stroke)};
    }
    if (!(request.speed >= config_.minSpeed && request.speed <= config_.maxSpeed)) {
        return Error{ErrorKind::kRefused, "grasp speed outside the gripper's range"};
    }
    if (!(request.force >= config_.minForce && request.force <= config_.maxForce)) {
        return Error{ErrorKind::kRefused, "grasp force outside the gripper's range"};
    }
    std::lock_guard lock(io_);
    if (auto c = ensureConnected(deadline); !c.ok()) return c.error();
    auto force =
        this->request(Command::kSetForceLimit, w::floatPayload(static_cast<float>(request.force)),
                      deadline, "set force limit");
    if (!force.ok()) return force.error();
    auto r = motion(Command::kGrasp,
                    w::graspPayload(static_cast<float>(request.width * 1000.0),
                                    static_cast<float>(request.speed * 1000.0)),
                    deadline, cancel, "grasp");
    if (!r.ok()) return r.error();
    auto s = readStatus(deadline);
    if (!s.ok()) return s.error();
    if (*r == static_cast<std::uint16_t>(Status::kSuccess) && s->holding) return s;
    auto state =
        this->request(Command::kGetGraspingState, w::queryPayload(), deadline, "grasping state");
    const bool noPart =
        state.ok() && !state->values.empty() &&
        state->values[0] == static_cast<std::uint8_t>(w::GraspingState::kNoPartFound);
    if (noPart) return Error{ErrorKind::kRefused, "no object between the fingers"};
    if (*r != static_cast<std::uint16_t>(Status::kSuccess)) return deviceError("grasp", *r);
    return Error{ErrorKind::kFault, "grasp finished but the gripper does not report HOLDING"};
}

Result<gripper::Status> WsgHardware::release(Deadline deadline, const std::atomic<bool>& cancel) {
    std::lock_guard lock(io_);
    if (auto c = ensureConnected(deadline); !c.ok()) return c.error();
    auto r = motion(Command::kRelease,
                    w::graspPayload(static_cast<float>(config_.stroke * 1000.0),
                                    static_cast<float>(config_.releaseSpeed * 1000.0)),
                    deadline, cancel, "release");
    if (!r.ok()) return r.error();
    if (*r != static_cast<std::uint16_t>(Status::kSuccess)) return deviceError("release", *r);
    return readStatus(deadline);
}

Result<gripper::Status> WsgHardware::move(const gripper::MoveRequest& request, Deadline deadline,
                                          const std::atomic<bool>& cancel) {
    if (!(request.width >= 0.0 && request.width <= config_.stroke)) {
        return Error{ErrorKind::kRefused,
                     "width " + mm(request.width) + " outside 0.." + mm(config_.stroke)};
    }
    if (!(request.speed >= config_.minSpeed && request.speed <= config_.maxSpeed)) {
        return Error{ErrorKind::kRefused, "speed outside the gripper's range"};
    }
    std::lock_guard lock(io_);
    if (auto c = ensureConnected(deadline); !c.ok()) return c.error();
    auto r = motion(Command::kPrePosition,
                    w::prePositionPayload(w::move_flag::kStopOnBlock,
                                          static_cast<float>(request.width * 1000.0),
                                          static_cast<float>(request.speed * 1000.0)),
                    deadline, cancel, "move");
    if (!r.ok()) return r.error();
    if (*r == static_cast<std::uint16_t>(Status::kAxisBlocked)) {
        auto s = readStatus(deadline);
        return Error{ErrorKind::kFault, "move: E_AXIS_BLOCKED: the jaws stopped at " +
                                            (s.ok() ? mm(s->width) : std::string("?")) +
                                            " (an object between them?)"};
    }
    if (*r != static_cast<std::uint16_t>(Status::kSuccess)) return deviceError("move", *r);
    return readStatus(deadline);
}

void WsgHardware::stop(Deadline deadline) {
    std::unique_lock lock(io_, std::try_to_lock);
    if (!lock.owns_lock()) {
        // A call is running (its cancel flag does the rest): just send the STOP.
        [[maybe_unused]] auto s = send(Command::kStop, {}, deadline);
        return;
    }
    if (fd_ < 0) return;
    [[maybe_unused]] auto r = request(Command::kStop, {}, deadline, "stop");
}

}  // namespace pnp::device::wsg
