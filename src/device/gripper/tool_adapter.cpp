// ToolAdapter: the power poller and the server's lifecycle (see tool_adapter.hpp).
#include "device/gripper/tool_adapter.hpp"

#include <condition_variable>
#include <mutex>
#include <thread>

namespace pnp::device::gripper {

struct ToolAdapter::Impl {
    ToolAdapter& self;
    ToolAdapterOptions options;
    Announce announce;
    std::function<void(const PowerEvent&)> callback;

    // The server and device: built ahead (standby) and started on power-up.
    std::unique_ptr<ua::server::Server> server;
    std::unique_ptr<GripperDevice> device;
    Announcement announcement;
    bool connected = false;  // only the poller thread (under the hardware lock)

    mutable std::mutex mutex;  // endpoint, stopping
    std::condition_variable wake;
    bool stopping = false;
    std::string endpoint;
    std::atomic<bool> cancel{false};  // stop(): ends an activation in progress
    std::thread thread;

    Impl(ToolAdapter& s, ToolAdapterOptions o, Announce a)
        : self(s), options(std::move(o)), announce(std::move(a)) {}

    std::string lastError;  // an error repeated every poll is told once

    void emit(PowerEvent e) {
        if (e.kind == PowerEvent::Kind::kError) {
            if (e.message == lastError) return;
            lastError = e.message;
        } else {
            lastError.clear();
        }
        if (callback) callback(e);
    }

    void prepare() {
        if (server) return;
        auto s = std::make_unique<ua::server::Server>(options.server);
        auto d = std::make_unique<GripperDevice>(*s, self.access_, options.device);
        if (options.prepareServer) options.prepareServer(*s);
        device = std::move(d);
        server = std::move(s);
    }

    // One poll: connect when needed, then status. nullopt: the hardware is busy (a skill's
    // call in flight, which reports a dead device itself).
    std::optional<bool> poll() {
        auto r = self.access_.tryWith([&](GripperHardware& h) -> Result<Status> {
            const auto deadline = Clock::now() + options.pollTimeout;
            if (!connected) {
                auto c = h.connect(deadline);
                if (!c) return c.error();
                connected = true;
            }
            auto s = h.status(Clock::now() + options.pollTimeout);
            if (!s &&
                (s.error().kind == ErrorKind::kNoDevice || s.error().kind == ErrorKind::kTimeout)) {
                // A fresh transport (a TCP peer may be gone), at once: a skill that takes the
                // hardware next must not find it disconnected while the device still answers
                // (a poll that was only late on a loaded machine).
                h.disconnect();
                connected = static_cast<bool>(h.connect(Clock::now() + options.pollTimeout));
            }
            return s;
        });
        if (!r) return std::nullopt;
        return r->ok();
    }

    void up(Clock::time_point firstAnswer) {
        try {
            prepare();
            device->refreshIdentity();
            server->start();
        } catch (const std::exception& e) {
            emit({PowerEvent::Kind::kError,
                  {},
                  {},
                  std::string("cannot start the server: ") + e.what()});
            if (server && server->running()) server->stop();
            return;
        }
        // The same port on every later power-up.
        if (options.server.port == 0) options.server.port = server->port();
        {
            std::lock_guard l(mutex);
            endpoint = server->endpointUrl();
        }
        std::string announceError;
        if (announce) {
            try {
                announcement = announce(*server);
            } catch (const std::exception& e) {
                announceError = e.what();
            }
        }
        self.serving_ = true;
        ++self.powerUps_;
        emit({PowerEvent::Kind::kUp, self.endpointUrl(), Clock::now() - firstAnswer, {}});
        if (!announceError.empty())
            emit(
                {PowerEvent::Kind::kError, self.endpointUrl(), {}, "announcing: " + announceError});
        if (options.activateOnPowerUp) activate();
    }

    void activate() {
        const auto deadline = Clock::now() + options.device.activateTimeout;
        auto r = self.access_.with([&](GripperHardware& h) { return h.activate(deadline, cancel); },
                                   deadline, &cancel);
        if (r && !r->ok() && r->error().kind != ErrorKind::kCancelled)
            emit({PowerEvent::Kind::kError,
                  self.endpointUrl(),
                  {},
                  "activation: " + r->error().message});
    }

    void down(const std::string& why) {
        announcement.reset();  // goodbye on mDNS, unregistered: gone everywhere at once
        device.reset();        // halts running skills
        if (server) server->stop();
        server.reset();
        self.serving_ = false;
        self.access_.forget();
        self.access_.with(
            [&](GripperHardware& h) {
                h.disconnect();
                connected = false;
                return 0;
            },
            Clock::now() + options.pollTimeout);
        emit({PowerEvent::Kind::kDown, self.endpointUrl(), {}, why});
    }

    void run() {
        for (;;) {
            const auto cycle = Clock::now();
            const std::optional<bool> answered = poll();
            const auto last = self.access_.lastAnswer();
            if (answered && *answered) {
                if (!self.serving_) up(last.value_or(cycle));
            } else if (answered && self.serving_) {
                // Silent for longer than the grace time: unplugged.
                if (!last || Clock::now() - *last > options.graceTime)
                    down("the device stopped answering");
            }
            if (!self.serving_ && !server) {
                try {
                    prepare();  // the next power-up only starts it
                } catch (const std::exception& e) {
                    emit({PowerEvent::Kind::kError, {}, {}, e.what()});
                }
            }
            std::unique_lock l(mutex);
            if (wake.wait_until(l, cycle + options.pollPeriod, [&] { return stopping; })) break;
        }
        if (self.serving_) down("stopped");
        self.access_.with(
            [&](GripperHardware& h) {
                if (connected) h.disconnect();
                connected = false;
                return 0;
            },
            Clock::now() + options.pollTimeout);
    }
};

ToolAdapter::ToolAdapter(GripperHardware& hardware, ToolAdapterOptions options, Announce announce)
    : access_(hardware),
      impl_(std::make_unique<Impl>(*this, std::move(options), std::move(announce))) {
    impl_->prepare();
}

ToolAdapter::~ToolAdapter() {
    stop();
    impl_->device.reset();
    impl_->server.reset();
}

void ToolAdapter::onEvent(std::function<void(const PowerEvent&)> callback) {
    impl_->callback = std::move(callback);
}

void ToolAdapter::start() {
    if (impl_->thread.joinable()) return;
    {
        std::lock_guard l(impl_->mutex);
        impl_->stopping = false;
    }
    impl_->cancel = false;
    impl_->thread = std::thread([this] { impl_->run(); });
}

void ToolAdapter::stop() {
    {
        std::lock_guard l(impl_->mutex);
        impl_->stopping = true;
    }
    impl_->cancel = true;
    impl_->wake.notify_all();
    if (impl_->thread.joinable()) impl_->thread.join();
}

std::string ToolAdapter::endpointUrl() const {
    std::lock_guard l(impl_->mutex);
    return impl_->endpoint;
}

}  // namespace pnp::device::gripper
