// A small WebSocket client for the dashboard's tests (websocketpp's client on its own asio
// thread). C++17 like web_server.cpp: ws_test_client.cpp includes websocketpp.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

namespace pnp::dashboard::test {

class WsTestClient {
  public:
    // Connects to ws://127.0.0.1:<port><path>; throws std::runtime_error when the handshake
    // did not complete within `timeout`.
    explicit WsTestClient(std::uint16_t port, std::chrono::milliseconds timeout,
                          const std::string& path = "/ws");
    ~WsTestClient();
    WsTestClient(const WsTestClient&) = delete;
    WsTestClient& operator=(const WsTestClient&) = delete;

    // The next text message received, or nullopt after `timeout`.
    std::optional<std::string> next(std::chrono::milliseconds timeout);
    void send(const std::string& text);
    // True once the connection closed (waits up to `timeout`); the peer's close code then.
    bool waitClosed(std::chrono::milliseconds timeout);
    int closeCode() const;
    std::size_t received() const;

    struct Impl;

  private:
    std::unique_ptr<Impl> impl_;
};

}  // namespace pnp::dashboard::test
