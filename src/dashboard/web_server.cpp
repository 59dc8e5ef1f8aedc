// C++17 translation unit (see web_server.hpp): websocketpp on standalone asio.
#include "dashboard/web_server.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
#include <utility>
#include <vector>

#include "dashboard/websocket_config.hpp"
// After the config: websocketpp's headers take the asio / STL choice from its macros.
#include <websocketpp/server.hpp>

namespace pnp::dashboard {

namespace fs = std::filesystem;
using Endpoint = websocketpp::server<wsconfig::Server>;
using Handle = websocketpp::connection_hdl;

std::string contentTypeOf(const fs::path& file) {
    static const std::map<std::string, std::string> types = {
        {".html", "text/html; charset=utf-8"},
        {".js", "text/javascript; charset=utf-8"},
        {".mjs", "text/javascript; charset=utf-8"},
        {".css", "text/css; charset=utf-8"},
        {".json", "application/json"},
        {".map", "application/json"},
        {".svg", "image/svg+xml"},
        {".png", "image/png"},
        {".jpg", "image/jpeg"},
        {".ico", "image/x-icon"},
        {".txt", "text/plain; charset=utf-8"},
        {".wasm", "application/wasm"},
        {".glb", "model/gltf-binary"},
        {".stl", "model/stl"},
        {".urdf", "application/xml"},
        {".dae", "model/vnd.collada+xml"},
    };
    const auto it = types.find(file.extension().string());
    return it == types.end() ? "application/octet-stream" : it->second;
}

std::optional<fs::path> resolveAsset(const fs::path& root, std::string_view target,
                                     std::size_t maxPathLength) {
    if (root.empty() || target.size() > maxPathLength) return std::nullopt;
    if (const auto q = target.find_first_of("?#"); q != std::string_view::npos)
        target = target.substr(0, q);
    if (target.empty() || target.front() != '/') return std::nullopt;
    fs::path relative;
    std::size_t pos = 1;
    while (pos <= target.size()) {
        auto end = target.find('/', pos);
        if (end == std::string_view::npos) end = target.size();
        const std::string_view segment = target.substr(pos, end - pos);
        pos = end + 1;
        if (segment.empty()) continue;
        // ".." and hidden files; '%' would let "..%2f" pass the check and be decoded later
        if (segment.front() == '.') return std::nullopt;
        for (const char c : segment)
            if (c == '\\' || c == '\0' || c == '%' || static_cast<unsigned char>(c) < 0x20)
                return std::nullopt;
        relative /= std::string(segment);
    }
    std::error_code ec;
    fs::path file = root / relative;
    if (fs::is_directory(file, ec)) file /= "index.html";
    // A symlink inside the folder may still point out of it.
    const fs::path realRoot = fs::canonical(root, ec);
    if (ec) return std::nullopt;
    const fs::path realFile = fs::canonical(file, ec);
    if (ec) return std::nullopt;
    const auto mismatch =
        std::mismatch(realRoot.begin(), realRoot.end(), realFile.begin(), realFile.end());
    if (mismatch.first != realRoot.end()) return std::nullopt;
    if (!fs::is_regular_file(realFile, ec)) return std::nullopt;
    return realFile;
}

struct WebServer::Impl {
    WebServerOptions options;
    ApiHandler api;
    OpenHandler open;
    MessageHandler message;
    CloseHandler closed;

    Endpoint endpoint;
    std::thread thread;
    std::atomic<std::uint16_t> boundPort{0};
    std::atomic<bool> running{false};

    // asio thread only
    std::map<ClientId, Handle> clients;
    std::map<Handle, ClientId, std::owner_less<Handle>> ids;
    std::set<ClientId> dropping;  // closed for a full queue, not yet gone
    ClientId nextId = 1;
    std::atomic<std::size_t> clientCount{0};

    explicit Impl(WebServerOptions o) : options(std::move(o)) {}

    static void reply(Endpoint::connection_ptr& con, int status, const std::string& type,
                      std::string body) {
        con->set_status(static_cast<websocketpp::http::status_code::value>(status));
        con->replace_header("Content-Type", type);
        con->replace_header("Cache-Control", "no-store");
        con->set_body(std::move(body));
    }

    void onHttp(Handle hdl) {
        auto con = endpoint.get_con_from_hdl(hdl);
        const auto& request = con->get_request();
        const std::string& target = con->get_resource();
        if (request.get_method() != "GET") {
            reply(con, 405, "text/plain; charset=utf-8", "only GET\n");
            return;
        }
        if (target.size() > options.maxPathLength) {
            reply(con, 414, "text/plain; charset=utf-8", "request target too long\n");
            return;
        }
        constexpr std::string_view kApi = "/api/";
        if (target.compare(0, kApi.size(), kApi) == 0) {
            std::optional<HttpReply> r;
            try {
                if (api) r = api(std::string_view(target).substr(kApi.size()));
            } catch (const std::exception& e) {
                r = HttpReply{500, "text/plain; charset=utf-8", std::string(e.what()) + "\n"};
            }
            if (!r) r = HttpReply{404, "text/plain; charset=utf-8", "not found\n"};
            reply(con, r->status, r->contentType, std::move(r->body));
            return;
        }
        const auto file = resolveAsset(options.assets, target, options.maxPathLength);
        if (!file) {
            reply(con, 404, "text/plain; charset=utf-8", "not found\n");
            return;
        }
        std::error_code ec;
        const auto size = fs::file_size(*file, ec);
        if (ec || size > options.maxFileBytes) {
            reply(con, 500, "text/plain; charset=utf-8", "file unreadable or too large\n");
            return;
        }
        std::string body(static_cast<std::size_t>(size), '\0');
        std::ifstream in(*file, std::ios::binary);
        if (!in.read(body.data(), static_cast<std::streamsize>(body.size()))) {
            reply(con, 500, "text/plain; charset=utf-8", "file unreadable\n");
            return;
        }
        reply(con, 200, contentTypeOf(*file), std::move(body));
    }

    bool onValidate(Handle hdl) {
        auto con = endpoint.get_con_from_hdl(hdl);
        const std::string& target = con->get_resource();
        if (target != "/ws" && target.compare(0, 4, "/ws?") != 0) {
            con->set_status(websocketpp::http::status_code::not_found);
            return false;
        }
        if (clients.size() >= options.maxClients) {
            con->set_status(websocketpp::http::status_code::service_unavailable);
            return false;
        }
        return true;
    }

    void onOpen(Handle hdl) {
        const ClientId id = nextId++;
        clients.emplace(id, hdl);
        ids.emplace(hdl, id);
        clientCount = clients.size();
        auto con = endpoint.get_con_from_hdl(hdl);
        con->set_max_message_size(options.maxIncomingBytes);
        if (!open) return;
        std::string first;
        try {
            first = open(id);
        } catch (const std::exception&) {
            first.clear();
        }
        if (!first.empty()) sendTo(id, hdl, first);
    }

    void onClosed(Handle hdl) {
        const auto it = ids.find(hdl);
        if (it == ids.end()) return;
        const ClientId id = it->second;
        ids.erase(it);
        clients.erase(id);
        dropping.erase(id);
        clientCount = clients.size();
        if (closed) closed(id);
    }

    void onMessage(Handle hdl, Endpoint::message_ptr msg) {
        const auto it = ids.find(hdl);
        if (it == ids.end() || !message) return;
        if (msg->get_opcode() != websocketpp::frame::opcode::text) {
            closeClient(hdl, websocketpp::close::status::unsupported_data, "text frames only");
            return;
        }
        message(it->second, std::move(msg->get_raw_payload()));
    }

    void closeClient(Handle hdl, std::uint16_t code, const std::string& reason) {
        websocketpp::lib::error_code ec;
        endpoint.close(hdl, code, reason, ec);  // an already closing connection: ignored
    }

    // A page that does not read: the close frame waits behind its queue, so after a grace
    // period the connection is cut (its slot must not stay taken).
    void drop(Handle hdl) {
        const auto it = ids.find(hdl);
        if (it == ids.end() || !dropping.insert(it->second).second) return;
        closeClient(hdl, websocketpp::close::status::policy_violation, "send queue full");
        auto timer = std::make_shared<asio::steady_timer>(endpoint.get_io_service(),
                                                          std::chrono::seconds(1));
        timer->async_wait([this, hdl, timer](const asio::error_code&) {
            websocketpp::lib::error_code ec;
            auto con = endpoint.get_con_from_hdl(hdl, ec);
            if (!ec && con && con->get_state() != websocketpp::session::state::closed)
                con->terminate(websocketpp::error::make_error_code(websocketpp::error::general));
        });
    }

    // asio thread
    void sendTo(ClientId, Handle hdl, const std::string& text) {
        websocketpp::lib::error_code ec;
        auto con = endpoint.get_con_from_hdl(hdl, ec);
        if (ec || !con || con->get_state() != websocketpp::session::state::open) return;
        if (con->get_buffered_amount() + text.size() > options.maxQueuedBytes) {
            drop(hdl);
            return;
        }
        con->send(text, websocketpp::frame::opcode::text);
    }
};

WebServer::WebServer(WebServerOptions options)
    : impl_(std::make_unique<Impl>(std::move(options))) {}

WebServer::~WebServer() { stop(); }

void WebServer::onApi(ApiHandler handler) { impl_->api = std::move(handler); }
void WebServer::onOpen(OpenHandler handler) { impl_->open = std::move(handler); }
void WebServer::onMessage(MessageHandler handler) { impl_->message = std::move(handler); }
void WebServer::onClose(CloseHandler handler) { impl_->closed = std::move(handler); }

void WebServer::start() {
    Impl& d = *impl_;
    if (d.running) return;
    auto& ep = d.endpoint;
    ep.init_asio();
    ep.set_reuse_addr(true);
    ep.set_max_message_size(d.options.maxIncomingBytes);
    ep.set_max_http_body_size(wsconfig::Server::max_http_body_size);
    ep.set_http_handler([&d](Handle h) { d.onHttp(h); });
    ep.set_validate_handler([&d](Handle h) { return d.onValidate(h); });
    ep.set_open_handler([&d](Handle h) { d.onOpen(h); });
    ep.set_close_handler([&d](Handle h) { d.onClosed(h); });
    ep.set_fail_handler([&d](Handle h) { d.onClosed(h); });
    ep.set_message_handler([&d](Handle h, Endpoint::message_ptr m) { d.onMessage(h, m); });
    websocketpp::lib::error_code ec;
    asio::error_code aec;
    const auto address = asio::ip::make_address(d.options.host, aec);
    if (aec) throw std::runtime_error("dashboard: bad --host " + d.options.host);
    ep.listen(asio::ip::tcp::endpoint(address, d.options.port), ec);
    if (ec)
        throw std::runtime_error("dashboard: cannot listen on " + d.options.host + ":" +
                                 std::to_string(d.options.port) + ": " + ec.message());
    const auto local = ep.get_local_endpoint(ec);
    if (ec) throw std::runtime_error("dashboard: " + ec.message());
    d.boundPort = local.port();
    ep.start_accept(ec);
    if (ec) throw std::runtime_error("dashboard: " + ec.message());
    d.running = true;
    d.thread = std::thread([&ep] {
        // Handlers do not throw into asio (they catch); a websocketpp exception from a peer's
        // bytes ends only the connection, so run() returns only when stopped.
        for (;;) {
            try {
                ep.run();
                return;
            } catch (const std::exception&) {
            }
        }
    });
}

void WebServer::stop() {
    Impl& d = *impl_;
    if (!d.running.exchange(false)) return;
    // Closes on the asio thread, then a bounded wait for the close handshakes.
    std::mutex m;
    std::condition_variable cv;
    bool closed = false;
    asio::post(d.endpoint.get_io_service(), [&] {
        websocketpp::lib::error_code ec;
        d.endpoint.stop_listening(ec);
        for (const auto& [id, hdl] : d.clients)
            d.closeClient(hdl, websocketpp::close::status::going_away, "dashboard stops");
        std::lock_guard lock(m);
        closed = true;
        cv.notify_all();
    });
    {
        std::unique_lock lock(m);
        cv.wait_for(lock, std::chrono::seconds(1), [&] { return closed; });
    }
    const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(500);
    while (d.clientCount > 0 && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    d.endpoint.stop();
    if (d.thread.joinable()) d.thread.join();
}

std::uint16_t WebServer::port() const { return impl_->boundPort; }

std::size_t WebServer::clientCount() const { return impl_->clientCount; }

void WebServer::broadcast(std::string text) {
    Impl& d = *impl_;
    if (!d.running) return;
    asio::post(d.endpoint.get_io_service(), [&d, text = std::move(text)] {
        for (const auto& [id, hdl] : d.clients) d.sendTo(id, hdl, text);
    });
}

void WebServer::send(ClientId client, std::string text) {
    Impl& d = *impl_;
    if (!d.running) return;
    asio::post(d.endpoint.get_io_service(), [&d, client, text = std::move(text)] {
        if (const auto it = d.clients.find(client); it != d.clients.end())
            d.sendTo(client, it->second, text);
    });
}

void WebServer::close(ClientId client, std::uint16_t code, std::string reason) {
    Impl& d = *impl_;
    if (!d.running) return;
    asio::post(d.endpoint.get_io_service(), [&d, client, code, reason = std::move(reason)] {
        if (const auto it = d.clients.find(client); it != d.clients.end())
            d.closeClient(it->second, code, reason);
    });
}

}  // namespace pnp::dashboard
