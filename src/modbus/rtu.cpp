// Modbus over serial line V1.02, RTU mode: frames delimited by t3.5 of silence, address +
// PDU + CRC-16 (low byte first); the slave answers only frames for its address with a good
// CRC, and executes broadcasts (address 0) without answering.
#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <mutex>
#include <system_error>
#include <thread>

#include "modbus/modbus.hpp"

namespace pnp::modbus {

namespace {

using Clock = RtuFramer::Clock;

Clock::duration silenceFor(std::uint32_t baud) {
    // Above 19200 baud the spec fixes t3.5 at 1.75 ms (§2.5.1.1); below, 3.5 characters of
    // 11 bits (start, 8 data, parity or second stop, stop).
    if (baud == 0 || baud > 19200) return std::chrono::microseconds(1750);
    return std::chrono::microseconds(38'500'000 / baud + 1);
}

timespec toTimespec(Clock::duration d) {
    const auto ns =
        std::max<std::int64_t>(0, std::chrono::duration_cast<std::chrono::nanoseconds>(d).count());
    return {static_cast<time_t>(ns / 1'000'000'000), static_cast<long>(ns % 1'000'000'000)};
}

}  // namespace

RtuFramer::RtuFramer(RtuSlaveConfig config) : config_(config), silence_(silenceFor(config.baud)) {
    frame_.reserve(kMaxFrame);
}

std::optional<std::vector<std::uint8_t>> RtuFramer::receive(std::span<const std::uint8_t> bytes,
                                                            Clock::time_point now,
                                                            Registers& registers) {
    std::optional<std::vector<std::uint8_t>> response = expire(now, registers);
    if (bytes.empty()) return response;
    for (std::uint8_t b : bytes) {
        if (frame_.size() < kMaxFrame) {
            frame_.push_back(b);
        } else {
            overflow_ = true;  // keep swallowing until the silence that ends this frame
        }
    }
    last_ = now;
    return response;
}

std::optional<std::vector<std::uint8_t>> RtuFramer::expire(Clock::time_point now,
                                                           Registers& registers) {
    if (!last_ || now - *last_ < silence_) return std::nullopt;
    return complete(registers);
}

std::optional<Clock::time_point> RtuFramer::deadline() const {
    if (!last_) return std::nullopt;
    return *last_ + silence_;
}

std::optional<std::vector<std::uint8_t>> RtuFramer::complete(Registers& registers) {
    std::vector<std::uint8_t> frame;
    frame.swap(frame_);
    frame_.reserve(kMaxFrame);
    const bool overflow = overflow_;
    overflow_ = false;
    last_.reset();

    if (overflow) {
        ++stats_.tooLong;
        return std::nullopt;
    }
    if (frame.size() < 4) {
        ++stats_.tooShort;
        return std::nullopt;
    }
    const std::size_t body = frame.size() - 2;
    const std::uint16_t crc = crc16(std::span(frame.data(), body));
    if (frame[body] != (crc & 0xFF) || frame[body + 1] != (crc >> 8)) {
        ++stats_.badCrc;
        return std::nullopt;
    }
    const std::uint8_t address = frame[0];
    if (address != 0 && address != config_.slave) {
        ++stats_.otherSlave;
        return std::nullopt;
    }
    if (!registers.answering()) {
        ++stats_.notAnswering;
        return std::nullopt;
    }
    const std::span<const std::uint8_t> pdu(frame.data() + 1, body - 1);
    std::vector<std::uint8_t> reply = answer(registers, pdu);
    if (address == 0) {
        ++stats_.broadcasts;
        return std::nullopt;
    }
    ++stats_.frames;
    std::vector<std::uint8_t> adu;
    adu.reserve(reply.size() + 3);
    adu.push_back(config_.slave);
    adu.insert(adu.end(), reply.begin(), reply.end());
    const std::uint16_t out = crc16(adu);
    adu.push_back(static_cast<std::uint8_t>(out & 0xFF));
    adu.push_back(static_cast<std::uint8_t>(out >> 8));
    return adu;
}

struct RtuSlave::Impl {
    Impl(int fd, RtuSlaveConfig config, Registers& registers)
        : fd(fd), registers(registers), framer(config) {}

    void run() {
        std::array<std::uint8_t, 512> buffer{};
        while (true) {
            // Wait for bytes, for the end of the frame in progress, or for stop(). Without a
            // frame in progress the wait is capped anyway (stop() also wakes it at once).
            std::optional<Clock::time_point> end;
            {
                std::lock_guard lock(mutex);
                end = framer.deadline();
            }
            const Clock::duration wait =
                end ? std::max(Clock::duration::zero(), *end - Clock::now())
                    : Clock::duration(std::chrono::seconds(1));
            std::array<pollfd, 2> fds{{{fd, POLLIN, 0}, {wake[0], POLLIN, 0}}};
            const timespec timeout = toTimespec(wait);
            const int n = ppoll(fds.data(), fds.size(), &timeout, nullptr);
            if (n < 0 && errno != EINTR) return;
            if (fds[1].revents != 0) return;  // stop()
            std::optional<std::vector<std::uint8_t>> response;
            if (fds[0].revents & POLLIN) {
                const ssize_t got = ::read(fd, buffer.data(), buffer.size());
                const auto now = Clock::now();
                std::lock_guard lock(mutex);
                if (got > 0) {
                    response = framer.receive(
                        std::span(buffer.data(), static_cast<std::size_t>(got)), now, registers);
                }
            } else if (fds[0].revents & (POLLHUP | POLLERR | POLLNVAL)) {
                // No peer on the line (e.g. a pty without its other side): do not spin.
                if (!pause(std::chrono::milliseconds(20))) return;
            }
            if (!response) {
                std::lock_guard lock(mutex);
                response = framer.expire(Clock::now(), registers);
            }
            if (response) send(*response);
        }
    }

    // Sleeps up to `d`; false when stop() came meanwhile.
    bool pause(Clock::duration d) {
        pollfd p{wake[0], POLLIN, 0};
        const timespec t = toTimespec(d);
        return ppoll(&p, 1, &t, nullptr) <= 0 || p.revents == 0;
    }

    // Writes the whole response or gives up after 100 ms (a line that takes nothing).
    void send(const std::vector<std::uint8_t>& bytes) {
        const auto deadline = Clock::now() + std::chrono::milliseconds(100);
        std::size_t done = 0;
        while (done < bytes.size()) {
            const ssize_t w = ::write(fd, bytes.data() + done, bytes.size() - done);
            if (w > 0) {
                done += static_cast<std::size_t>(w);
                continue;
            }
            if (w < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) return;
            const auto left = deadline - Clock::now();
            if (left <= Clock::duration::zero()) return;
            pollfd p{fd, POLLOUT, 0};
            const timespec t = toTimespec(left);
            ppoll(&p, 1, &t, nullptr);
        }
    }

    int fd;
    Registers& registers;
    mutable std::mutex mutex;  // the framer: the thread and stats()
    RtuFramer framer;
    std::array<int, 2> wake{-1, -1};
    std::thread thread;
};

RtuSlave::RtuSlave(int fd, RtuSlaveConfig config, Registers& registers)
    : impl_(std::make_unique<Impl>(fd, config, registers)) {}

RtuSlave::~RtuSlave() { stop(); }

void RtuSlave::start() {
    if (impl_->thread.joinable()) return;
    if (const int flags = fcntl(impl_->fd, F_GETFL);
        flags < 0 || fcntl(impl_->fd, F_SETFL, flags | O_NONBLOCK) < 0) {
        throw std::system_error(errno, std::generic_category(), "RtuSlave: fd");
    }
    if (pipe2(impl_->wake.data(), O_CLOEXEC | O_NONBLOCK) != 0) {
        throw std::system_error(errno, std::generic_category(), "RtuSlave: pipe");
    }
    impl_->thread = std::thread([impl = impl_.get()] { impl->run(); });
}

void RtuSlave::stop() {
    if (!impl_->thread.joinable()) return;
    const std::uint8_t byte = 1;
    [[maybe_unused]] const ssize_t w = ::write(impl_->wake[1], &byte, 1);
    impl_->thread.join();
    for (int& f : impl_->wake) {
        ::close(f);
        f = -1;
    }
}

RtuStats RtuSlave::stats() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->framer.stats();
}

}  // namespace pnp::modbus
