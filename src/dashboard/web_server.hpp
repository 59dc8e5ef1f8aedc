// The dashboard's HTTP + WebSocket server: one port, one asio thread that only does I/O.
//
//   WebServer web({.host = "127.0.0.1", .port = 8080, .assets = "build/web/dashboard"});
//   web.onApi([&](std::string_view path) -> std::optional<HttpReply> { ... });  // GET /api/...
//   web.onOpen([&](ClientId) { return snapshotJson(); });    // the first message of a client
//   web.onMessage([&](ClientId id, std::string text) { ... });
//   web.start();
//   web.broadcast(R"({"type":"server",...})");               // from any thread
//
// GET serves files below `assets` (no "..", no hidden segments, no symlink leading out,
// bounded path and file size, Content-Type by extension); GET /api/... goes to the API
// handler; /ws is the WebSocket. Handlers run on the asio thread: they must be quick (read
// prepared state, queue work elsewhere). Each client's outgoing bytes are bounded: a client
// whose queue exceeds maxQueuedBytes is closed (1008, "send queue full") and the others go on.
// Incoming WebSocket messages above maxIncomingBytes close that client (1009).
//
// This header is C++17 (web_server.cpp compiles as C++17: websocketpp 0.8.2 is not C++20
// code), so it includes nothing of pnp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

namespace pnp::dashboard {

using ClientId = std::uint64_t;

struct HttpReply {
    int status = 200;
    std::string contentType = "application/json";
    std::string body;
};

struct WebServerOptions {
    std::string host = "127.0.0.1";
    std::uint16_t port = 8080;                     // 0: any free port (see port())
    std::filesystem::path assets;                  // static files; empty: none (404)
    std::size_t maxClients = 64;                   // WebSocket clients; more are refused (HTTP 503)
    std::size_t maxIncomingBytes = 64 * 1024;      // per WebSocket message from a page
    std::size_t maxQueuedBytes = 8 * 1024 * 1024;  // per client, not yet written
    std::size_t maxFileBytes = 32 * 1024 * 1024;   // a static file larger: 404 is wrong, 500
    std::size_t maxPathLength = 512;               // request target, bytes
};

class WebServer {
  public:
    using ApiHandler = std::function<std::optional<HttpReply>(std::string_view path)>;
    using OpenHandler = std::function<std::string(ClientId)>;  // "" = nothing to send first
    using MessageHandler = std::function<void(ClientId, std::string text)>;
    using CloseHandler = std::function<void(ClientId)>;

    explicit WebServer(WebServerOptions options);
    ~WebServer();  // stop()
    WebServer(const WebServer&) = delete;
    WebServer& operator=(const WebServer&) = delete;

    // Set before start(). The API handler gets the path below /api/ ("snapshot",
    // "robot/UR5"); nullopt = 404.
    void onApi(ApiHandler handler);
    void onOpen(OpenHandler handler);
    void onMessage(MessageHandler handler);
    void onClose(CloseHandler handler);

    // Binds and starts the asio thread. Throws std::runtime_error (address in use, ...).
    void start();
    // Closes every client (1001 going away), stops the thread; idempotent.
    void stop();
    std::uint16_t port() const;  // the bound port (after start())

    // Thread-safe; queued to the asio thread, sent in order of the calls.
    void broadcast(std::string text);
    void send(ClientId client, std::string text);
    void close(ClientId client, std::uint16_t code, std::string reason);
    std::size_t clientCount() const;

    struct Impl;

  private:
    std::unique_ptr<Impl> impl_;
};

// Content-Type of a file by its extension ("application/octet-stream" when unknown).
std::string contentTypeOf(const std::filesystem::path& file);
// The file below `root` for a request path ("/", "/js/app.js"; the query is stripped), or
// nullopt for anything that could leave root or is too long: "..", ".x" segments, '\\',
// NUL, '%' (nothing of the page needs escapes), a symlink pointing out.
std::optional<std::filesystem::path> resolveAsset(const std::filesystem::path& root,
                                                  std::string_view target,
                                                  std::size_t maxPathLength);

}  // namespace pnp::dashboard
