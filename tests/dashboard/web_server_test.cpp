// The dashboard's HTTP + WebSocket server over real loopback sockets: static files, 404,
// path traversal refused, the API, a broadcast reaching two pages, an oversized message
// closing only its page, a page that does not read dropped without blocking the others.
#include "dashboard/web_server.hpp"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "dashboard/robot_description.hpp"
#include "ws_test_client.hpp"

namespace {

using namespace std::chrono_literals;
using pnp::dashboard::HttpReply;
using pnp::dashboard::WebServer;
using pnp::dashboard::WebServerOptions;
using pnp::dashboard::test::WsTestClient;
namespace fs = std::filesystem;

struct HttpResult {
    int status = 0;
    std::string head;
    std::string body;
};

// One raw HTTP/1.1 request (the target is sent as is: no client-side normalisation).
HttpResult httpGet(std::uint16_t port, const std::string& target,
                   const std::string& method = "GET") {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(port);
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    HttpResult r;
    if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
        ::close(fd);
        return r;
    }
    const std::string request =
        method + " " + target + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
    (void)!::send(fd, request.data(), request.size(), MSG_NOSIGNAL);
    std::string all;
    const auto until = std::chrono::steady_clock::now() + 5s;
    char buf[65536];
    while (std::chrono::steady_clock::now() < until && all.size() < 64 * 1024 * 1024) {
        pollfd p{fd, POLLIN, 0};
        if (::poll(&p, 1, 200) <= 0) continue;
        const auto n = ::recv(fd, buf, sizeof buf, 0);
        if (n <= 0) break;
        all.append(buf, static_cast<std::size_t>(n));
    }
    ::close(fd);
    const auto split = all.find("\r\n\r\n");
    if (split == std::string::npos || all.size() < 12) return r;
    r.head = all.substr(0, split);
    r.body = all.substr(split + 4);
    r.status = std::stoi(all.substr(9, 3));
    return r;
}

class WebServerTest : public ::testing::Test {
  protected:
    void SetUp() override {
        root = fs::temp_directory_path() /
               ("pnp-dashboard-test-" + std::to_string(::getpid()) + "-" +
                ::testing::UnitTest::GetInstance()->current_test_info()->name());
        fs::create_directories(root / "assets" / "js");
        std::ofstream(root / "assets" / "index.html") << "<!doctype html><title>cell</title>";
        std::ofstream(root / "assets" / "js" / "app.js") << "export const x = 1;\n";
        std::ofstream(root / "assets" / ".hidden") << "no";
        std::ofstream(root / "secret.txt") << "outside";
        fs::create_symlink(root / "secret.txt", root / "assets" / "link.txt");
    }
    void TearDown() override {
        web.reset();
        std::error_code ec;
        fs::remove_all(root, ec);
    }
    void start(WebServerOptions o = {}) {
        o.host = "127.0.0.1";
        o.port = 0;
        o.assets = root / "assets";
        web = std::make_unique<WebServer>(o);
        web->onApi([](std::string_view path) -> std::optional<HttpReply> {
            if (path == "snapshot")
                return HttpReply{200, "application/json", R"({"type":"snapshot"})"};
            if (path.starts_with("robot/"))
                if (auto d = pnp::dashboard::robotDescription(path.substr(6)))
                    return HttpReply{200, "application/json", d->dump()};
            return std::nullopt;
        });
        web->onOpen([](pnp::dashboard::ClientId) { return std::string(R"({"type":"snapshot"})"); });
        web->onMessage([this](pnp::dashboard::ClientId id, std::string text) {
            web->send(id, "echo:" + text);
        });
        web->start();
        ASSERT_NE(web->port(), 0);
    }
    fs::path root;
    std::unique_ptr<WebServer> web;
};

TEST_F(WebServerTest, ServesStaticFilesWithTheirContentType) {
    start();
    auto index = httpGet(web->port(), "/");
    EXPECT_EQ(index.status, 200);
    EXPECT_NE(index.head.find("text/html"), std::string::npos);
    EXPECT_EQ(index.body, "<!doctype html><title>cell</title>");
    auto js = httpGet(web->port(), "/js/app.js?v=3");
    EXPECT_EQ(js.status, 200);
    EXPECT_NE(js.head.find("text/javascript"), std::string::npos);
    EXPECT_EQ(js.body, "export const x = 1;\n");
}

TEST_F(WebServerTest, UnknownFilesAre404AndOnlyGetIsServed) {
    start();
    EXPECT_EQ(httpGet(web->port(), "/nope.js").status, 404);
    EXPECT_EQ(httpGet(web->port(), "/api/nothing").status, 404);
    EXPECT_EQ(httpGet(web->port(), "/", "DELETE").status, 405);
}

TEST_F(WebServerTest, PathTraversalIsRefused) {
    start();
    for (const std::string target :
         {"/../secret.txt", "/js/../../secret.txt", "/%2e%2e/secret.txt", "/..%2fsecret.txt",
          "/.hidden", "/link.txt", "/js\\..\\..\\secret.txt"}) {
        const auto r = httpGet(web->port(), target);
        EXPECT_EQ(r.status, 404) << target;
        EXPECT_EQ(r.body.find("outside"), std::string::npos) << target;
    }
    EXPECT_EQ(httpGet(web->port(), "/" + std::string(600, 'a')).status, 414);
}

TEST_F(WebServerTest, ApiSnapshotAndRobotGeometry) {
    start();
    const auto snap = httpGet(web->port(), "/api/snapshot");
    EXPECT_EQ(snap.status, 200);
    EXPECT_EQ(nlohmann::json::parse(snap.body)["type"], "snapshot");
    const auto ur5 = httpGet(web->port(), "/api/robot/ur5e");
    ASSERT_EQ(ur5.status, 200);
    const auto j = nlohmann::json::parse(ur5.body);
    EXPECT_EQ(j["model"], "UR5");
    ASSERT_EQ(j["dh"].size(), 6u);
    EXPECT_DOUBLE_EQ(j["dh"][0]["d"].get<double>(), 0.089159);
    EXPECT_DOUBLE_EQ(j["dh"][1]["a"].get<double>(), -0.425);
    EXPECT_EQ(httpGet(web->port(), "/api/robot/R2D2").status, 404);
}

TEST_F(WebServerTest, BroadcastReachesEveryPageAfterItsSnapshot) {
    start();
    WsTestClient a(web->port(), 3s), b(web->port(), 3s);
    EXPECT_EQ(a.next(2s).value_or(""), R"({"type":"snapshot"})");
    EXPECT_EQ(b.next(2s).value_or(""), R"({"type":"snapshot"})");
    web->broadcast(R"({"type":"server","op":"add"})");
    EXPECT_EQ(a.next(2s).value_or(""), R"({"type":"server","op":"add"})");
    EXPECT_EQ(b.next(2s).value_or(""), R"({"type":"server","op":"add"})");
    a.send("hello");
    EXPECT_EQ(a.next(2s).value_or(""), "echo:hello");
    EXPECT_FALSE(b.next(100ms).has_value());  // a reply goes to its page only
    EXPECT_EQ(web->clientCount(), 2u);
}

TEST_F(WebServerTest, WebSocketOnlyAtWs) {
    start();
    EXPECT_THROW(WsTestClient(web->port(), 2s, "/other"), std::runtime_error);
}

TEST_F(WebServerTest, OversizedMessageClosesOnlyThatPage) {
    start();
    WsTestClient big(web->port(), 3s), other(web->port(), 3s);
    ASSERT_TRUE(big.next(2s));
    ASSERT_TRUE(other.next(2s));
    big.send(std::string(65 * 1024, 'x'));
    ASSERT_TRUE(big.waitClosed(3s));
    EXPECT_EQ(big.closeCode(), 1009);  // message too big
    web->broadcast("still here");
    EXPECT_EQ(other.next(2s).value_or(""), "still here");
    other.send("ping");
    EXPECT_EQ(other.next(2s).value_or(""), "echo:ping");
}

TEST_F(WebServerTest, ClientLimitRefusesTheNextPage) {
    WebServerOptions o;
    o.maxClients = 2;
    start(o);
    WsTestClient a(web->port(), 3s), b(web->port(), 3s);
    ASSERT_TRUE(a.next(2s));
    ASSERT_TRUE(b.next(2s));
    EXPECT_THROW(WsTestClient(web->port(), 2s), std::runtime_error);
}

TEST_F(WebServerTest, FullSendQueueDropsThatPageOnly) {
    WebServerOptions o;
    o.maxQueuedBytes = 256 * 1024;
    start(o);
    // A page that never reads: a raw socket that does the handshake and then stops reading.
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    int small = 4096;
    ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &small, sizeof small);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(web->port());
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
    const std::string handshake =
        "GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";
    ASSERT_EQ(::send(fd, handshake.data(), handshake.size(), MSG_NOSIGNAL),
              static_cast<ssize_t>(handshake.size()));
    WsTestClient reader(web->port(), 3s);
    ASSERT_TRUE(reader.next(2s));
    const auto until = std::chrono::steady_clock::now() + 10s;
    while (web->clientCount() == 2 && std::chrono::steady_clock::now() < until) {
        // 128 KiB a round, below the limit for a page that reads, and the next round only
        // once the reading page has had this one (so its queue never holds two rounds, however
        // slowly the server's thread runs); the stalled page's queue grows once the kernel's
        // socket buffers are full
        for (int i = 0; i < 2; ++i) web->broadcast(std::string(64 * 1024, 'w'));
        for (int got = 0; got < 2 && web->clientCount() == 2;)
            if (const auto m = reader.next(5s); m)
                ++got;
            else
                break;
    }
    // The stalled page was closed (its close handshake then times out on the server).
    EXPECT_LT(std::chrono::steady_clock::now(), until);
    web->broadcast("after");
    std::optional<std::string> m;
    const auto until2 = std::chrono::steady_clock::now() + 5s;
    while (std::chrono::steady_clock::now() < until2 && (m = reader.next(1s)) && *m != "after") {
    }
    EXPECT_EQ(m.value_or(""), "after");
    EXPECT_FALSE(reader.waitClosed(0ms));
    EXPECT_EQ(web->clientCount(), 1u);
    ::close(fd);
}

}  // namespace
