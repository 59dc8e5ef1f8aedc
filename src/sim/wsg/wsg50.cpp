#include "sim/wsg/wsg50.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <stdexcept>

namespace pnp::sim::wsg {

namespace w = pnp::wsg;
using w::Command;
using w::GraspingState;
using w::Status;

namespace {

constexpr std::size_t kReadChunk = 4096;
// A client that does not read its answers is dropped rather than buffered without end.
constexpr std::size_t kMaxOutbox = 64 * 1024;
constexpr int kPollMs = 20;  // bounds how late a power change or shutdown is seen

int bindSocket(const std::string& address, std::uint16_t port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0) return -1;
    const int one = 1;
    ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(port);
    if (::inet_pton(AF_INET, address.c_str(), &addr.sin_addr) != 1 ||
        ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
        ::close(fd);
        return -1;
    }
    return fd;
}

bool in(double v, double lo, double hi) { return v >= lo && v <= hi; }  // false for NaN

}  // namespace

Wsg50::Wsg50(world::World& world, std::size_t tool, Wsg50Config config)
    : world_(world), tool_(tool), config_(std::move(config)) {
    const world::ToolDescription& t = world_.description().tools.at(tool_);
    if (config_.stroke <= 0.0) config_.stroke = t.stroke > 0.0 ? t.stroke * 1000.0 : 110.0;
    const auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
    if (!positive(config_.minSpeed) || !positive(config_.maxSpeed) ||
        config_.minSpeed > config_.maxSpeed || !positive(config_.minForce) ||
        !positive(config_.maxForce) || config_.minForce > config_.maxForce ||
        !positive(config_.minAcceleration) || config_.minAcceleration > config_.maxAcceleration ||
        !in(config_.acceleration, config_.minAcceleration, config_.maxAcceleration) ||
        !in(config_.forceLimit, config_.minForce, config_.maxForce) ||
        !positive(config_.homingSpeed) || !std::isfinite(config_.clampingTravel) ||
        config_.clampingTravel < 0.0 || !std::isfinite(config_.stroke) ||
        config_.maxConnections == 0) {
        throw std::invalid_argument("Wsg50: inconsistent limits in the configuration");
    }
    width_ = config_.initialWidth < 0.0 ? config_.stroke
                                        : std::clamp(config_.initialWidth, 0.0, config_.stroke);
    acceleration_ = config_.acceleration;
    forceLimit_ = config_.forceLimit;

    listener_ = bindSocket(config_.bindAddress, config_.port);
    if (listener_ < 0) {
        throw std::runtime_error("Wsg50: cannot bind " + config_.bindAddress + ":" +
                                 std::to_string(config_.port) + ": " + std::strerror(errno));
    }
    sockaddr_in bound{};
    socklen_t len = sizeof bound;
    ::getsockname(listener_, reinterpret_cast<sockaddr*>(&bound), &len);
    port_ = ntohs(bound.sin_port);

    int fds[2];
    if (::pipe2(fds, O_NONBLOCK | O_CLOEXEC) != 0) {
        ::close(listener_);
        throw std::runtime_error("Wsg50: pipe: " + std::string(std::strerror(errno)));
    }
    wakeRead_ = fds[0];
    wakeWrite_ = fds[1];
    thread_ = std::thread([this] { run(); });
}

Wsg50::~Wsg50() {
    stop_ = true;
    wake();
    if (thread_.joinable()) thread_.join();
    for (auto& [id, c] : connections_) ::close(c.fd);
    if (listener_ >= 0) ::close(listener_);
    ::close(wakeRead_);
    ::close(wakeWrite_);
}

void Wsg50::wake() {
    const char b = 1;
    [[maybe_unused]] const auto n = ::write(wakeWrite_, &b, 1);  // full pipe: a wake is pending
}

Wsg50State Wsg50::state() const {
    std::lock_guard lock(mutex_);
    Wsg50State s;
    s.powered = powered_;
    s.listening = listening_;
    s.referenced = referenced_;
    s.fastStop = fastStop_;
    s.moving = motion_.has_value();
    s.width = width_;
    s.grasping = grasping_;
    s.systemFlags = systemFlags();
    s.connections = connections_.size();
    s.checksumErrors = checksumErrors_;
    return s;
}

std::uint32_t Wsg50::systemFlags() const {
    std::uint32_t f = eventFlags_;
    if (referenced_) f |= w::system_flag::kReferenced;
    if (motion_) f |= w::system_flag::kMoving;
    if (fastStop_) f |= w::system_flag::kFastStop;
    if (grasping_ == GraspingState::kHolding) f |= w::system_flag::kForceControlMode;
    return f;
}

// ---------------------------------------------------------------- network thread

void Wsg50::run() {
    std::vector<pollfd> fds;
    std::vector<std::uint64_t> ids;
    while (!stop_) {
        fds.clear();
        ids.clear();
        fds.push_back({wakeRead_, POLLIN, 0});
        bool pollingListener = false;
        {
            std::lock_guard lock(mutex_);
            updateListener();
            pollingListener = listening_;
            if (listening_) fds.push_back({listener_, POLLIN, 0});
            for (auto& [id, c] : connections_) {
                const short events = static_cast<short>(POLLIN | (c.outbox.empty() ? 0 : POLLOUT));
                fds.push_back({c.fd, events, 0});
                ids.push_back(id);
            }
        }
        if (::poll(fds.data(), fds.size(), kPollMs) < 0 && errno != EINTR) break;
        if (fds[0].revents & POLLIN) {
            char buf[64];
            while (::read(wakeRead_, buf, sizeof buf) > 0) {
            }
        }
        std::lock_guard lock(mutex_);
        // Only this thread changes listening_ and the listener, so fds[1] is still it.
        const std::size_t first = pollingListener ? 2 : 1;
        if (pollingListener && (fds[1].revents & POLLIN)) acceptAll();
        for (std::size_t i = first; i < fds.size(); ++i) {
            const std::uint64_t id = ids[i - first];
            auto it = connections_.find(id);
            if (it == connections_.end()) continue;  // dropped meanwhile (power off)
            if (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) serve(id, it->second);
        }
        // Answers queued by serve() or by step() go out now.
        for (auto it = connections_.begin(); it != connections_.end();) {
            flush(it->second);
            if (it->second.closing) {
                const std::uint64_t id = it->first;
                ++it;
                closeConnection(id);
            } else {
                ++it;
            }
        }
    }
}

void Wsg50::updateListener() {
    if (powered_ && !listening_) {
        if (listener_ < 0) listener_ = bindSocket(config_.bindAddress, port_);
        if (listener_ >= 0 && ::listen(listener_, 8) == 0) listening_ = true;
    } else if (!powered_ && listening_) {
        // A device without power accepts nothing: drop everyone, stop listening, and keep the
        // port bound (not listening) so that it is still ours at the next power-on.
        while (!connections_.empty()) closeConnection(connections_.begin()->first);
        ::close(listener_);
        listener_ = bindSocket(config_.bindAddress, port_);
        listening_ = false;
    } else if (!powered_) {
        while (!connections_.empty()) closeConnection(connections_.begin()->first);
        if (listener_ < 0) listener_ = bindSocket(config_.bindAddress, port_);
    }
}

void Wsg50::acceptAll() {
    for (int i = 0; i < 16; ++i) {
        const int fd = ::accept4(listener_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) return;
        if (connections_.size() >= config_.maxConnections) {
            ::close(fd);
            continue;
        }
        const int one = 1;
        ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        Connection c;
        c.fd = fd;
        connections_.emplace(nextConnection_++, std::move(c));
    }
}

void Wsg50::serve(std::uint64_t id, Connection& c) {
    std::uint8_t buf[kReadChunk];
    // Bounded: at most 16 reads per wake, so one busy client cannot starve the others.
    for (int i = 0; i < 16; ++i) {
        const ssize_t n = ::recv(c.fd, buf, sizeof buf, 0);
        if (n == 0) {
            c.closing = true;
            return;
        }
        if (n < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) c.closing = true;
            return;
        }
        const std::uint64_t before = c.decoder.checksumErrors();
        for (const w::Frame& f : c.decoder.feed(std::span(buf, static_cast<std::size_t>(n)))) {
            handle(id, c, f);
        }
        checksumErrors_ += c.decoder.checksumErrors() - before;
    }
}

void Wsg50::flush(Connection& c) {
    while (!c.outbox.empty()) {
        const ssize_t n = ::send(c.fd, c.outbox.data(), c.outbox.size(), MSG_NOSIGNAL);
        if (n < 0) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) c.closing = true;
            break;
        }
        c.outbox.erase(c.outbox.begin(), c.outbox.begin() + n);
    }
    if (c.outbox.size() > kMaxOutbox) c.closing = true;
}

void Wsg50::closeConnection(std::uint64_t id) {
    auto it = connections_.find(id);
    if (it == connections_.end()) return;
    const bool announced = it->second.announced;
    ::close(it->second.fd);
    connections_.erase(it);
    if (powered_ && config_.fastStopOnDisconnect && !announced) {
        abortMotion();
        fastStop_ = true;
        grasping_ = GraspingState::kError;
    }
}

void Wsg50::reply(Connection& c, std::uint8_t id, Status status,
                  const std::vector<std::uint8_t>& values) {
    const auto frame = w::encodeResponse(id, status, values);
    c.outbox.insert(c.outbox.end(), frame.begin(), frame.end());
}

void Wsg50::replyTo(std::uint64_t id, std::uint8_t command, Status status) {
    auto it = connections_.find(id);
    if (it == connections_.end()) return;  // the client went away: the result is lost
    reply(it->second, command, status);
    wake();
}

void Wsg50::handle(std::uint64_t id, Connection& c, const w::Frame& frame) {
    const std::uint8_t cmd = frame.id;
    if (frame.error == w::FrameError::kChecksum) return reply(c, cmd, Status::kChecksumError);
    if (frame.error == w::FrameError::kTooLarge) {
        return reply(c, cmd, Status::kInsufficientResources);
    }
    const std::vector<std::uint8_t>& p = frame.payload;
    const auto size = [&](std::initializer_list<std::size_t> allowed) {
        return std::find(allowed.begin(), allowed.end(), p.size()) != allowed.end();
    };
    const auto floatAt = [&](std::size_t offset) {
        return static_cast<double>(*w::getFloat(p, offset));
    };
    const auto speedOk = [&](double v) { return in(v, config_.minSpeed, config_.maxSpeed); };
    const auto widthOk = [&](double v) { return in(v, 0.0, config_.stroke); };
    // The value queries take 0 or 3 bytes (auto-update flags + period); automatic updates
    // are not simulated.
    const auto query = [&](std::vector<std::uint8_t> values) {
        if (!size({0, 3})) return reply(c, cmd, Status::kCmdFormatError);
        if (p.size() == 3 && (p[0] & 0x01u)) return reply(c, cmd, Status::kFeatureNotSupported);
        reply(c, cmd, Status::kSuccess, values);
    };
    const auto floatValue = [](double v) { return w::floatPayload(static_cast<float>(v)); };

    switch (static_cast<Command>(cmd)) {
        case Command::kLoop:
            return reply(c, cmd, Status::kSuccess, p);
        case Command::kDisconnect:
            if (!size({0})) return reply(c, cmd, Status::kCmdFormatError);
            c.announced = true;
            return reply(c, cmd, Status::kSuccess);
        case Command::kHoming: {
            if (!size({0, 1})) return reply(c, cmd, Status::kCmdFormatError);
            const std::uint8_t direction = p.empty() ? 0 : p[0];
            if (direction > 2) return reply(c, cmd, Status::kInvalidParameter);
            const double target = direction == 2 ? 0.0 : config_.stroke;
            return reply(c, cmd, startMotion(id, MotionKind::kHoming, target, config_.homingSpeed));
        }
        case Command::kPrePosition: {
            if (!size({9})) return reply(c, cmd, Status::kCmdFormatError);
            double target = floatAt(1);
            if (p[0] & w::move_flag::kRelative) target += width_;
            if (!widthOk(target) || !speedOk(floatAt(5))) {
                return reply(c, cmd, Status::kRangeError);
            }
            return reply(c, cmd, startMotion(id, MotionKind::kPosition, target, floatAt(5)));
        }
        case Command::kGrasp: {
            if (!size({8})) return reply(c, cmd, Status::kCmdFormatError);
            if (!widthOk(floatAt(0)) || !speedOk(floatAt(4))) {
                return reply(c, cmd, Status::kRangeError);
            }
            const double target = std::max(0.0, floatAt(0) - config_.clampingTravel);
            return reply(c, cmd, startMotion(id, MotionKind::kGrasp, target, floatAt(4)));
        }
        case Command::kRelease: {
            if (!size({8})) return reply(c, cmd, Status::kCmdFormatError);
            // Release opens: a width below the current opening would squeeze the part.
            if (!widthOk(floatAt(0)) || !speedOk(floatAt(4)) || floatAt(0) < width_ - 1e-3) {
                return reply(c, cmd, Status::kRangeError);
            }
            return reply(c, cmd, startMotion(id, MotionKind::kRelease, floatAt(0), floatAt(4)));
        }
        case Command::kStop:
            if (!size({0})) return reply(c, cmd, Status::kCmdFormatError);
            if (motion_) {
                abortMotion();
                eventFlags_ |= w::system_flag::kAxisStopped;
                if (grasping_ != GraspingState::kError) {
                    grasping_ = held_ ? GraspingState::kHolding : GraspingState::kIdle;
                }
            }
            return reply(c, cmd, Status::kSuccess);
        case Command::kFastStop:
            if (!size({0})) return reply(c, cmd, Status::kCmdFormatError);
            abortMotion();
            fastStop_ = true;
            grasping_ = GraspingState::kError;
            return reply(c, cmd, Status::kSuccess);
        case Command::kAcknowledgeFastStop:
            if (!size({3})) return reply(c, cmd, Status::kCmdFormatError);
            if (p != w::acknowledgeFastStopPayload()) {
                return reply(c, cmd, Status::kInvalidParameter);
            }
            if (fastStop_) {
                fastStop_ = false;
                grasping_ = held_ ? GraspingState::kHolding : GraspingState::kIdle;
            }
            return reply(c, cmd, Status::kSuccess);
        case Command::kSetAcceleration:
            if (!size({4})) return reply(c, cmd, Status::kCmdFormatError);
            if (!in(floatAt(0), config_.minAcceleration, config_.maxAcceleration)) {
                return reply(c, cmd, Status::kRangeError);
            }
            acceleration_ = floatAt(0);
            return reply(c, cmd, Status::kSuccess);
        case Command::kGetAcceleration:
            if (!size({0})) return reply(c, cmd, Status::kCmdFormatError);
            return reply(c, cmd, Status::kSuccess, floatValue(acceleration_));
        case Command::kSetForceLimit:
            if (!size({4})) return reply(c, cmd, Status::kCmdFormatError);
            if (!in(floatAt(0), config_.minForce, config_.maxForce)) {
                return reply(c, cmd, Status::kRangeError);
            }
            forceLimit_ = floatAt(0);
            return reply(c, cmd, Status::kSuccess);
        case Command::kGetForceLimit:
            if (!size({0})) return reply(c, cmd, Status::kCmdFormatError);
            return reply(c, cmd, Status::kSuccess, floatValue(forceLimit_));
        case Command::kGetSystemState: {
            std::vector<std::uint8_t> v;
            w::putU32(v, systemFlags());
            return query(v);
        }
        case Command::kGetGraspingState:
            return query({static_cast<std::uint8_t>(grasping_)});
        case Command::kGetGraspingStatistics: {
            if (!size({0, 1})) return reply(c, cmd, Status::kCmdFormatError);
            reply(c, cmd, Status::kSuccess, w::encodeGraspingStatistics(statistics_));
            if (!p.empty() && (p[0] & 0x01u)) statistics_ = {};
            return;
        }
        case Command::kGetOpeningWidth:
            return query(floatValue(width_));
        case Command::kGetSpeed:
            return query(floatValue(std::abs(velocity_)));
        case Command::kGetForce:
            return query(floatValue(grasping_ == GraspingState::kHolding ? forceLimit_ : 0.0));
        case Command::kGetSystemInformation:
            if (!size({0})) return reply(c, cmd, Status::kCmdFormatError);
            return reply(c, cmd, Status::kSuccess,
                         w::encodeSystemInformation({1, config_.hardwareRevision, config_.firmware,
                                                     config_.serialNumber}));
    }
    reply(c, cmd, Status::kCmdUnknown);
}

Status Wsg50::startMotion(std::uint64_t owner, MotionKind kind, double target, double speed) {
    if (fastStop_) return Status::kAccessDenied;  // until the fast stop is acknowledged
    if (kind != MotionKind::kHoming && !referenced_) return Status::kNotInitialized;
    if (motion_) return Status::kAlreadyRunning;
    if (held_ && (kind == MotionKind::kPosition || kind == MotionKind::kGrasp)) {
        return Status::kAccessDenied;  // release the part first
    }
    motion_ = Motion{kind, target, speed, owner, false};
    eventFlags_ &= ~(w::system_flag::kAxisStopped | w::system_flag::kTargetPositionReached |
                     w::system_flag::kBlockedMinus | w::system_flag::kBlockedPlus |
                     w::system_flag::kCommandFailure);
    switch (kind) {
        case MotionKind::kHoming:
            referenced_ = false;
            break;
        case MotionKind::kPosition:
            grasping_ = GraspingState::kPositioning;
            break;
        case MotionKind::kGrasp:
            grasping_ = GraspingState::kGrasping;
            break;
        case MotionKind::kRelease:
            grasping_ = GraspingState::kReleasing;
            break;
    }
    if (held_ && (kind == MotionKind::kHoming || kind == MotionKind::kRelease)) {
        releaseHeld_ = true;  // the jaws open: step() tells the world
    }
    return Status::kCmdPending;
}

void Wsg50::finishMotion(Status status) {
    if (!motion_) return;
    const auto command = [&] {
        switch (motion_->kind) {
            case MotionKind::kHoming:
                return Command::kHoming;
            case MotionKind::kPosition:
                return Command::kPrePosition;
            case MotionKind::kGrasp:
                return Command::kGrasp;
            case MotionKind::kRelease:
                return Command::kRelease;
        }
        return Command::kStop;
    }();
    const std::uint64_t owner = motion_->owner;
    motion_.reset();
    velocity_ = 0.0;
    if (status != Status::kSuccess) eventFlags_ |= w::system_flag::kCommandFailure;
    replyTo(owner, static_cast<std::uint8_t>(command), status);
}

void Wsg50::abortMotion() { finishMotion(Status::kCmdAborted); }

// ---------------------------------------------------------------- stepping thread

void Wsg50::step(double dt) {
    const bool powered = world_.toolPowered(tool_);
    std::lock_guard lock(mutex_);
    if (powered != powered_) powerChanged(powered);
    if (releaseHeld_) {
        world_.release(tool_);
        held_.reset();
        releaseHeld_ = false;
    }
    if (!powered_ || !std::isfinite(dt) || dt <= 0.0) return;
    if (grasping_ == GraspingState::kHolding && held_ && world_.held(tool_) != held_) {
        // Taken out of the jaws (an operator, another tool): the part monitoring notices.
        held_.reset();
        grasping_ = GraspingState::kPartLost;
        ++statistics_.lostPart;
    }
    if (motion_) advance(dt);
    world_.setFingerOpening(tool_, width_ * 1e-3);  // its finger tips touch, not the gap
}

void Wsg50::powerChanged(bool powered) {
    powered_ = powered;
    if (!powered) {
        // Power gone: the controller forgets everything but where the jaws physically are.
        motion_.reset();  // its client is dropped with the connection: no answer
        velocity_ = 0.0;
        referenced_ = false;
        fastStop_ = false;
        eventFlags_ = 0;
        grasping_ = GraspingState::kIdle;
        // Without power the jaws hold no force: the part is let go.
        if (held_) releaseHeld_ = true;
        acceleration_ = config_.acceleration;
        forceLimit_ = config_.forceLimit;
    }
    wake();
}

void Wsg50::advance(double dt) {
    Motion& m = *motion_;
    m.started = true;
    const double remaining = m.target - width_;
    const double direction = remaining >= 0.0 ? 1.0 : -1.0;
    // Trapezoidal speed: accelerate at the set acceleration, cruise at the speed, brake so as
    // to stop on the target.
    const double brake = std::sqrt(2.0 * acceleration_ * std::abs(remaining));
    const double speed = std::min({m.speed, std::abs(velocity_) + acceleration_ * dt, brake});
    double next = width_ + direction * std::max(speed, 1e-3) * dt;
    const bool arrives = direction > 0 ? next >= m.target : next <= m.target;
    if (arrives) next = m.target;
    velocity_ = direction * speed;

    // Closing: an object between the fingers stops them where they touch it.
    if (direction < 0 && (m.kind == MotionKind::kGrasp || m.kind == MotionKind::kPosition)) {
        const auto contact = world_.objectBetweenFingers(tool_, width_ / 1000.0);
        if (contact && contact->width * 1000.0 >= next) {
            width_ = std::min(width_, contact->width * 1000.0);
            if (m.kind == MotionKind::kPosition) {
                eventFlags_ |= w::system_flag::kBlockedMinus;
                grasping_ = GraspingState::kError;
                return finishMotion(Status::kAxisBlocked);
            }
            ++statistics_.total;
            if (world_.hold(tool_, contact->object)) {
                held_ = contact->object;
                grasping_ = GraspingState::kHolding;
                return finishMotion(Status::kSuccess);
            }
            grasping_ = GraspingState::kError;  // held by another tool
            return finishMotion(Status::kCmdFailed);
        }
    }
    width_ = next;
    if (!arrives) return;

    eventFlags_ |= w::system_flag::kTargetPositionReached;
    switch (m.kind) {
        case MotionKind::kHoming:
            referenced_ = true;
            grasping_ = GraspingState::kIdle;
            return finishMotion(Status::kSuccess);
        case MotionKind::kPosition:
        case MotionKind::kRelease:
            grasping_ = GraspingState::kIdle;
            return finishMotion(Status::kSuccess);
        case MotionKind::kGrasp:
            ++statistics_.total;
            ++statistics_.noPart;
            grasping_ = GraspingState::kNoPartFound;
            return finishMotion(Status::kCmdFailed);
    }
}

}  // namespace pnp::sim::wsg
