#include "ws_test_client.hpp"

#include <condition_variable>
#include <deque>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <websocketpp/client.hpp>

#include "dashboard/websocket_config.hpp"

namespace pnp::dashboard::test {

using Endpoint = websocketpp::client<wsconfig::Client>;

struct WsTestClient::Impl {
    Endpoint endpoint;
    websocketpp::connection_hdl hdl;
    std::thread thread;
    mutable std::mutex mutex;
    std::condition_variable wake;
    std::deque<std::string> messages;
    std::size_t count = 0;
    bool open = false;
    bool closed = false;
    int code = 0;
};

WsTestClient::WsTestClient(std::uint16_t port, std::chrono::milliseconds timeout,
                           const std::string& path)
    : impl_(std::make_unique<Impl>()) {
    Impl& d = *impl_;
    d.endpoint.init_asio();
    d.endpoint.set_open_handler([&d](websocketpp::connection_hdl) {
        std::lock_guard lock(d.mutex);
        d.open = true;
        d.wake.notify_all();
    });
    auto onEnd = [&d](websocketpp::connection_hdl h) {
        std::lock_guard lock(d.mutex);
        d.closed = true;
        websocketpp::lib::error_code ec;
        if (auto con = d.endpoint.get_con_from_hdl(h, ec)) d.code = con->get_remote_close_code();
        d.wake.notify_all();
    };
    d.endpoint.set_close_handler(onEnd);
    d.endpoint.set_fail_handler(onEnd);
    d.endpoint.set_message_handler([&d](websocketpp::connection_hdl, Endpoint::message_ptr m) {
        std::lock_guard lock(d.mutex);
        d.messages.push_back(m->get_payload());
        ++d.count;
        d.wake.notify_all();
    });
    websocketpp::lib::error_code ec;
    auto con = d.endpoint.get_connection("ws://127.0.0.1:" + std::to_string(port) + path, ec);
    if (ec) throw std::runtime_error("ws client: " + ec.message());
    d.hdl = con->get_handle();
    d.endpoint.connect(con);
    d.thread = std::thread([&d] { d.endpoint.run(); });
    std::unique_lock lock(d.mutex);
    if (!d.wake.wait_for(lock, timeout, [&] { return d.open || d.closed; }) || !d.open) {
        lock.unlock();
        d.endpoint.stop();
        d.thread.join();
        throw std::runtime_error("ws client: no WebSocket handshake on port " +
                                 std::to_string(port) + path);
    }
}

WsTestClient::~WsTestClient() {
    Impl& d = *impl_;
    websocketpp::lib::error_code ec;
    d.endpoint.close(d.hdl, websocketpp::close::status::normal, "", ec);
    {
        std::unique_lock lock(d.mutex);
        d.wake.wait_for(lock, std::chrono::milliseconds(500), [&] { return d.closed; });
    }
    d.endpoint.stop();
    if (d.thread.joinable()) d.thread.join();
}

std::optional<std::string> WsTestClient::next(std::chrono::milliseconds timeout) {
    Impl& d = *impl_;
    std::unique_lock lock(d.mutex);
    if (!d.wake.wait_for(lock, timeout, [&] { return !d.messages.empty(); })) return std::nullopt;
    std::string m = std::move(d.messages.front());
    d.messages.pop_front();
    return m;
}

void WsTestClient::send(const std::string& text) {
    websocketpp::lib::error_code ec;
    impl_->endpoint.send(impl_->hdl, text, websocketpp::frame::opcode::text, ec);
    if (ec) throw std::runtime_error("ws client send: " + ec.message());
}

bool WsTestClient::waitClosed(std::chrono::milliseconds timeout) {
    std::unique_lock lock(impl_->mutex);
    return impl_->wake.wait_for(lock, timeout, [&] { return impl_->closed; });
}

int WsTestClient::closeCode() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->code;
}

std::size_t WsTestClient::received() const {
    std::lock_guard lock(impl_->mutex);
    return impl_->count;
}

}  // namespace pnp::dashboard::test
