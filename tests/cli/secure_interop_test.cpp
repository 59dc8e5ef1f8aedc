// Secured OPC UA between pnp and node-opcua (issue 24, point 6), both ways, for every
// security policy (Basic256Sha256, Aes128_Sha256_RsaOaep, Aes256_Sha256_RsaPss) x mode (Sign,
// SignAndEncrypt):
//   a/b. tests/interop/node_secure_client.js -> `pnp ua serve --pki DIR --users FILE`:
//        anonymous (reads; Demo.Echo refused by the role policy), a UserName token (password
//        encrypted by node-opcua for the policy) and an X.509 user token of Operators (reads,
//        Demo.Echo), and a wrong password (refused);
//   c.   an untrusted node-opcua client lands in DIR/rejected/certs, is refused, and connects
//        after `pnp pki trust`;
//   d.   `pnp ua read --pki DIR` -> tests/interop/node_secure_server.js: anonymous, UserName
//        and X.509 user tokens; our client refuses that server while its certificate is not
//        trusted (and says `pnp pki trust`), and the server refuses our client until it trusts
//        it;
//   e.   a node-opcua server (tests/interop/node_lds.js server) registers with `pnp lds` over
//        the LDS's most secure endpoint: refused while untrusted (its certificate in rejected/),
//        registered after `pnp pki trust` and a restart, unregistered when it stops.
// Every process is a child of this test, kept by its PID and stopped (SIGTERM, then SIGKILL);
// every wait has a deadline; the temporary folder is removed at the end. The servers and
// PKI folders are shared by all cases (started once, concurrently, at the first case): one
// node process runs the whole a/b matrix. Skipped (not failed) without `node` or node-opcua.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <ostream>
#include <string>
#include <thread>
#include <vector>

#include "support/child_process.hpp"
#include "support/json_lines.hpp"

#ifndef PNP_BINARY
#error "PNP_BINARY (path of the pnp executable) must be defined"
#endif
#ifndef PNP_SOURCE_DIR
#error "PNP_SOURCE_DIR must be defined"
#endif

namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;
using namespace std::chrono_literals;
using pnp::testing::ChildProcess;
using pnp::testing::jsonLines;

const std::string kInterop = std::string(PNP_SOURCE_DIR) + "/tests/interop/";
constexpr const char* kDemoInt32 = "nsu=urn:pnp:demo;s=Scalar.Int32";
constexpr const char* kOperatorPassword = "s3cret-operator";

// ---- processes -----------------------------------------------------------------------------

struct RunResult {
    int exitCode = -1;  // -1: killed by a signal or by the deadline
    bool timedOut = false;
    std::string out;
    std::string err;
    std::string text() const {
        return "exit " + std::to_string(exitCode) + (timedOut ? " (deadline)" : "") +
               "\nstdout:\n" + out + "\nstderr:\n" + err;
    }
};

// Runs argv[0] (a full path) to its end with `input` on stdin, collecting stdout and stderr
// (each bounded to 1 MiB). Past `deadline` the child gets SIGTERM, 2 s later SIGKILL; it is
// always reaped before this returns.
RunResult run(const std::vector<std::string>& argv, std::chrono::milliseconds deadline,
              const std::string& input = {}) {
    RunResult r;
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    int in[2], out[2], err[2];
    if (::pipe2(in, O_CLOEXEC) != 0 || ::pipe2(out, O_CLOEXEC) != 0 ||
        ::pipe2(err, O_CLOEXEC) != 0) {
        r.err = "pipe failed";
        return r;
    }
    const pid_t parent = ::getpid();
    const pid_t pid = ::fork();
    if (pid == 0) {  // only async-signal-safe calls until exec
        ::prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (::getppid() != parent) ::_exit(127);
        ::dup2(in[0], STDIN_FILENO);
        ::dup2(out[1], STDOUT_FILENO);
        ::dup2(err[1], STDERR_FILENO);
        ::execv(args[0], args.data());
        ::_exit(127);
    }
    ::close(in[0]);
    ::close(out[1]);
    ::close(err[1]);
    if (pid < 0) {
        ::close(in[1]);
        ::close(out[0]);
        ::close(err[0]);
        r.err = "fork failed";
        return r;
    }
    // Small inputs (a password line) fit into the pipe: written at once, then EOF. A child
    // that exits without reading must not kill this process with SIGPIPE: it is blocked for
    // the write and a pending one is consumed.
    if (!input.empty()) {
        sigset_t pipeSignal, previous;
        sigemptyset(&pipeSignal);
        sigaddset(&pipeSignal, SIGPIPE);
        ::pthread_sigmask(SIG_BLOCK, &pipeSignal, &previous);
        const ssize_t n = ::write(in[1], input.data(), input.size());
        if (n < 0) {
            const timespec now{0, 0};
            ::sigtimedwait(&pipeSignal, nullptr, &now);
        }
        ::pthread_sigmask(SIG_SETMASK, &previous, nullptr);
    }
    ::close(in[1]);

    const auto end = std::chrono::steady_clock::now() + deadline;
    const auto left = [&] {
        return std::max<long>(0, std::chrono::duration_cast<std::chrono::milliseconds>(
                                     end - std::chrono::steady_clock::now())
                                     .count());
    };
    pollfd fds[2] = {{out[0], POLLIN, 0}, {err[0], POLLIN, 0}};
    std::string* sinks[2] = {&r.out, &r.err};
    int openPipes = 2;
    while (openPipes > 0 && left() > 0) {
        if (::poll(fds, 2, static_cast<int>(std::min<long>(left(), 200))) <= 0) continue;
        for (int k = 0; k < 2; ++k) {
            if (fds[k].fd < 0 || (fds[k].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
            char buf[4096];
            const ssize_t n = ::read(fds[k].fd, buf, sizeof buf);
            if (n > 0) {
                if (sinks[k]->size() < (1u << 20)) sinks[k]->append(buf, static_cast<size_t>(n));
            } else {
                ::close(fds[k].fd);
                fds[k].fd = -1;
                --openPipes;
            }
        }
    }
    for (auto& f : fds)
        if (f.fd >= 0) ::close(f.fd);
    int status = 0;
    pid_t done = 0;
    while ((done = ::waitpid(pid, &status, WNOHANG)) == 0 && left() > 0)
        std::this_thread::sleep_for(10ms);
    if (done == 0) {
        r.timedOut = true;
        ::kill(pid, SIGTERM);
        const auto grace = std::chrono::steady_clock::now() + 2s;
        while ((done = ::waitpid(pid, &status, WNOHANG)) == 0 &&
               std::chrono::steady_clock::now() < grace)
            std::this_thread::sleep_for(10ms);
        if (done == 0) {
            ::kill(pid, SIGKILL);
            ::waitpid(pid, &status, 0);
        }
    }
    r.exitCode = !r.timedOut && WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return r;
}

RunResult pnp(std::vector<std::string> args, const std::string& input = {},
              std::chrono::milliseconds deadline = 30s) {
    args.insert(args.begin(), PNP_BINARY);
    return run(args, deadline, input);
}

// j[key] if it is a string, else "" (null, missing, another type).
std::string str(const Json& j, const char* key) {
    const auto it = j.find(key);
    return it != j.end() && it->is_string() ? it->get<std::string>() : std::string();
}

// The first JSON line a background child prints on stdout (within `timeout`), else nullopt
// with `error` set.
std::optional<Json> firstJsonLine(ChildProcess& child, std::chrono::milliseconds timeout,
                                  std::string& error) {
    std::string line;
    if (!child.waitForPrefix("{", timeout, error, &line)) return std::nullopt;
    Json j = Json::parse(line, nullptr, false);
    if (j.is_discarded()) {
        error = "not JSON: " + line;
        return std::nullopt;
    }
    return j;
}

// ---- files ---------------------------------------------------------------------------------

void copyInto(const fs::path& file, const fs::path& dir, const std::string& name) {
    fs::create_directories(dir);
    fs::copy_file(file, dir / name, fs::copy_options::overwrite_existing);
}

// The newest *.der in dir (a PKI's own/certs), or "".
fs::path newestDer(const fs::path& dir) {
    fs::path best;
    fs::file_time_type bestTime{};
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(dir, ec)) {
        if (e.path().extension() != ".der") continue;
        const auto t = e.last_write_time(ec);
        if (best.empty() || t > bestTime) {
            best = e.path();
            bestTime = t;
        }
    }
    return best;
}

std::size_t fileCount(const fs::path& dir) {
    std::error_code ec;
    std::size_t n = 0;
    for (const auto& e : fs::directory_iterator(dir, ec))
        if (e.is_regular_file()) ++n;
    return n;
}

// `pnp pki --pki dir list --json`: the entry with `thumbprint`, or null.
Json pkiEntry(const fs::path& dir, const std::string& thumbprint) {
    const RunResult r = pnp({"pki", "--pki", dir.string(), "list", "--json"});
    if (r.exitCode != 0) return Json();
    Json list = Json::parse(r.out, nullptr, false);
    if (!list.is_array()) return Json();
    for (const auto& e : list)
        if (str(e, "thumbprint") == thumbprint) return e;
    return Json();
}

// ---- what all cases share ------------------------------------------------------------------

// Started once, at the first case that needs it; stopped and removed at the end.
struct Shared {
    std::string skip;   // why every case is skipped ("" if node-opcua is there)
    std::string setup;  // what went wrong while setting up, for every case ("" if nothing)
    // ... for the cases of node-opcua's client against `pnp ua serve` (a/b/c), and for those of
    // our client against node-opcua's server (d).
    std::string nodeClientSetup, pnpClientSetup;
    // What went wrong while making the users (`pnp user`) and the user certificate (`pnp pki
    // create`): fails the cases with user tokens only (without users file the server runs
    // with anonymous access alone).
    std::string passwordUserSetup, certificateUserSetup, userCertificateSetup;

    std::string node;
    fs::path root;

    // a/b/c: `pnp ua serve` with its PKI and users, the node-opcua client's PKI.
    ChildProcess pnpServer;
    std::string pnpServerUrl;
    fs::path serverPki;
    fs::path usersFile;
    fs::path nodeClientPki;
    std::string nodeClientThumbprint;
    fs::path userCert, userKey;  // X.509 user "alice"

    // d: the node-opcua server and our client's PKI.
    ChildProcess nodeServer;
    std::string nodeServerUrl, nodeServerSignOnlyUrl, nodeServerThumbprint;
    fs::path nodeServerPki, nodeServerUserPki, nodeServerCert;
    fs::path pnpClientPki;
    RunResult firstPnpClientRun;  // before the node-opcua server trusted our client

    // The a/b matrix (one node process for every policy x mode x identity), run once.
    bool matrixDone = false;
    RunResult matrixRun;
    std::vector<Json> matrix;

    ~Shared() {
        pnpServer.stop();
        nodeServer.stop();
        std::error_code ec;
        if (!root.empty()) fs::remove_all(root, ec);
    }

    std::vector<std::string> nodeArgs(const std::string& script,
                                      std::vector<std::string> args) const {
        args.insert(args.begin(), {node, kInterop + script});
        return args;
    }

    void start();
    void startAll();
};

std::unique_ptr<Shared> gShared;

Shared& shared() {
    if (!gShared) {
        gShared = std::make_unique<Shared>();
        gShared->start();
    }
    return *gShared;
}

class SecureInteropEnvironment : public ::testing::Environment {
  public:
    void TearDown() override { gShared.reset(); }
};
[[maybe_unused]] ::testing::Environment* const kEnvironment =
    ::testing::AddGlobalTestEnvironment(new SecureInteropEnvironment);

void Shared::start() {
    node = pnp::testing::findInPath("node");
    if (node.empty()) {
        skip = "`node` missing";
        return;
    }
    if (::access((std::string(PNP_SOURCE_DIR) + "/node_modules/node-opcua").c_str(), R_OK) != 0) {
        skip = "node_modules/node-opcua missing (npm ci)";
        return;
    }
    try {
        startAll();
    } catch (const std::exception& e) {
        setup += std::string("exception: ") + e.what() + "\n";
    }
}

void Shared::startAll() {
    root = fs::path(::testing::TempDir()) / ("pnp_secure_interop_" + std::to_string(::getpid()));
    fs::remove_all(root);
    fs::create_directories(root);
    serverPki = root / "server-pki";
    usersFile = root / "users";
    nodeClientPki = root / "node-client-pki";
    userCert = root / "alice.der";
    userKey = root / "alice.pem";
    nodeServerPki = root / "node-server-pki";
    nodeServerUserPki = root / "node-server-user-pki";
    nodeServerCert = root / "node-server.der";
    pnpClientPki = root / "pnp-client-pki";
    std::string error;

    // The slow starts first, side by side: node-opcua's server, node-opcua's client
    // certificate (an RSA key in JavaScript) and `pnp ua serve` (its certificate at first start).
    const unsigned short nodePort = pnp::testing::freeLoopbackPortRange(2);
    if (!nodeServer.start(nodeArgs("node_secure_server.js",
                                   {"--port", std::to_string(nodePort), "--sign-only-port",
                                    std::to_string(nodePort + 1), "--pki", nodeServerPki.string(),
                                    "--user-pki", nodeServerUserPki.string(), "--user",
                                    std::string("operator:") + kOperatorPassword, "--export-cert",
                                    nodeServerCert.string()}),
                          (root / "node-server.stderr").string(), error))
        pnpClientSetup += "node_secure_server.js: " + error + "\n";
    ChildProcess nodeInit;
    const fs::path nodeClientDer = root / "node-client.der";
    if (!nodeInit.start(
            nodeArgs("node_secure_client.js", {"--init", "--pki", nodeClientPki.string(),
                                               "--export-cert", nodeClientDer.string()}),
            (root / "node-client-init.stderr").string(), error))
        nodeClientSetup += "node_secure_client.js --init: " + error + "\n";

    // Users: a password user and an X.509 user (a certificate made by `pnp pki create`).
    RunResult r = pnp({"user", "--users", usersFile.string(), "add", "operator", "--role",
                       "Operator", "--password-stdin"},
                      std::string(kOperatorPassword) + "\n");
    if (r.exitCode != 0) passwordUserSetup += "pnp user add operator: " + r.text() + "\n";
    r = pnp({"pki", "create", "--uri", "urn:pnp:interop:user:alice", "--name", "alice",
             "--out-cert", userCert.string(), "--out-key", userKey.string()});
    if (r.exitCode != 0 || !fs::exists(userCert) || !fs::exists(userKey))
        userCertificateSetup += "pnp pki create (user certificate): " + r.text() + "\n";
    if (userCertificateSetup.empty()) {
        r = pnp({"user", "--users", usersFile.string(), "add", "alice", "--role", "Operator",
                 "--cert", userCert.string()});
        if (r.exitCode != 0)
            certificateUserSetup += "pnp user add alice --cert: " + r.text() + "\n";
        // The server validates user certificates against its trust list too.
        r = pnp({"pki", "--pki", serverPki.string(), "trust", userCert.string()});
        if (r.exitCode != 0) certificateUserSetup += "pnp pki trust alice.der: " + r.text() + "\n";
    }

    std::vector<std::string> serve = {
        PNP_BINARY, "ua", "serve",         "--host", "127.0.0.1",
        "--port",   "0",  "--no-register", "--pki",  serverPki.string()};
    if (fs::exists(usersFile)) {
        serve.push_back("--users");
        serve.push_back(usersFile.string());
    }
    if (!pnpServer.start(serve, (root / "pnp-server.stderr").string(), error))
        nodeClientSetup += "pnp ua serve: " + error + "\n";
    std::string line;
    if (pnpServer.waitForPrefix("listening on ", 30s, error, &line))
        pnpServerUrl = line.substr(std::string("listening on ").size());
    else
        nodeClientSetup +=
            "pnp ua serve: " + error + "\nits stderr:\n" + pnpServer.logTail() + "\n";

    if (auto j = firstJsonLine(nodeInit, 60s, error)) {
        nodeClientThumbprint = str(*j, "thumbprint");
    } else {
        nodeClientSetup += "node_secure_client.js --init: " + error + "\nits stderr:\n" +
                           nodeInit.logTail() + "\n";
    }
    nodeInit.stop();

    // Trust both ways: the node-opcua client's certificate in the server's trusted/certs (as
    // an operator would copy it: DER, any name), the server's in the client's.
    if (fs::exists(nodeClientDer))
        copyInto(nodeClientDer, serverPki / "trusted" / "certs", "node-opcua-client.der");
    const fs::path serverCert = newestDer(serverPki / "own" / "certs");
    if (serverCert.empty())
        nodeClientSetup += "no certificate in " + (serverPki / "own" / "certs").string() + "\n";
    else
        copyInto(serverCert, nodeClientPki / "trusted" / "certs", "pnp-server.der");

    // d: the node-opcua server.
    if (auto j = firstJsonLine(nodeServer, 60s, error)) {
        nodeServerUrl = str(*j, "endpointUrl");
        nodeServerSignOnlyUrl = str(*j, "signOnlyUrl");
        nodeServerThumbprint = str(*j, "thumbprint");
    } else {
        pnpClientSetup +=
            "node_secure_server.js: " + error + "\nits stderr:\n" + nodeServer.logTail() + "\n";
        return;
    }
    // Our client trusts the node-opcua server (its certificate in our trusted/certs) and the
    // user certificate is trusted by the node-opcua server's user PKI.
    copyInto(nodeServerCert, pnpClientPki / "trusted" / "certs", "node-opcua-server.der");
    if (fs::exists(userCert))
        copyInto(userCert, nodeServerUserPki / "trusted" / "certs", "alice.der");
    // The first connection creates our client's certificate; the node-opcua server does not
    // trust it yet and refuses (checked by RefusedUntilTheServerTrustsIt).
    firstPnpClientRun =
        pnp({"ua", "read", nodeServerUrl, "i=2259", "--pki", pnpClientPki.string(), "--json"});
    const fs::path clientCert = newestDer(pnpClientPki / "own" / "certs");
    if (clientCert.empty()) {
        pnpClientSetup += "no certificate in " + (pnpClientPki / "own" / "certs").string() +
                          " after `pnp ua read --pki`: " + firstPnpClientRun.text() + "\n";
        return;
    }
    // The operator of the node-opcua server trusts our client: the certificate goes to
    // trusted/, the copy in rejected/ goes (a certificate in both counts as rejected).
    // node-opcua files a refused certificate in the background and watches its folders, so
    // the copy is removed again until the server accepts our client (bounded: 30 s).
    copyInto(clientCert, nodeServerPki / "trusted" / "certs", "pnp-client.der");
    const auto end = std::chrono::steady_clock::now() + 30s;
    RunResult probe;
    // A probe right after the removal can come before the server has seen it; refused again,
    // the certificate is filed again: each probe waits a little after the removal.
    do {
        std::error_code ec;
        for (const auto& e : fs::directory_iterator(nodeServerPki / "rejected", ec))
            fs::remove(e.path(), ec);
        std::this_thread::sleep_for(500ms);
        probe = pnp({"ua", "read", nodeServerUrl, "i=2259", "--pki", pnpClientPki.string()});
        if (probe.exitCode == 0) break;
    } while (std::chrono::steady_clock::now() < end);
    if (probe.exitCode != 0)
        pnpClientSetup +=
            "our client was not accepted by the node-opcua server after trusting it: " +
            probe.text() + "\nnode server stderr:\n" + nodeServer.logTail() + "\n";
}

// ---- parameters ----------------------------------------------------------------------------

struct PolicyMode {
    const char* policy;   // the policy's name (the URI's fragment)
    const char* mode;     // node-opcua's name
    const char* cliMode;  // `pnp ua read --mode`
};

const PolicyMode kPolicyModes[] = {
    {"Basic256Sha256", "Sign", "sign"},
    {"Basic256Sha256", "SignAndEncrypt", "encrypt"},
    {"Aes128_Sha256_RsaOaep", "Sign", "sign"},
    {"Aes128_Sha256_RsaOaep", "SignAndEncrypt", "encrypt"},
    {"Aes256_Sha256_RsaPss", "Sign", "sign"},
    {"Aes256_Sha256_RsaPss", "SignAndEncrypt", "encrypt"},
};

void PrintTo(const PolicyMode& p, std::ostream* os) { *os << p.policy << " " << p.mode; }

std::string paramName(const ::testing::TestParamInfo<PolicyMode>& info) {
    return std::string(info.param.policy) + "_" + info.param.mode;
}

// The identities of the a/b matrix, in the order of node_secure_client.js --identity.
enum MatrixIdentity { kAnonymous = 0, kUserName = 1, kX509 = 2, kWrongPassword = 3 };

class SecureInteropCase : public ::testing::Test {
  protected:
    void SetUp() override {
        Shared& s = shared();
        if (!s.skip.empty()) GTEST_SKIP() << s.skip;
        ASSERT_TRUE(s.setup.empty()) << "setting up failed:\n" << s.setup;
    }
};

// a/b/c: node-opcua's client against `pnp ua serve`.
class NodeClientCase : public SecureInteropCase {
  protected:
    void SetUp() override {
        SecureInteropCase::SetUp();
        if (IsSkipped() || HasFatalFailure()) return;
        ASSERT_TRUE(shared().nodeClientSetup.empty()) << "setting up failed:\n"
                                                      << shared().nodeClientSetup;
    }
};

// d: our client against node-opcua's server.
class PnpClientCase : public SecureInteropCase {
  protected:
    void SetUp() override {
        SecureInteropCase::SetUp();
        if (IsSkipped() || HasFatalFailure()) return;
        ASSERT_TRUE(shared().pnpClientSetup.empty()) << "setting up failed:\n"
                                                     << shared().pnpClientSetup;
    }
};

// ---- a/b: node-opcua client -> pnp ua serve ------------------------------------------------

class NodeClientToPnpServer : public NodeClientCase,
                              public ::testing::WithParamInterface<PolicyMode> {
  protected:
    // The matrix row of this case's policy x mode and `identity`.
    Json row(MatrixIdentity identity) {
        Shared& s = shared();
        if (!s.matrixDone) {
            s.matrixDone = true;
            s.matrixRun =
                run(s.nodeArgs("node_secure_client.js",
                               {s.pnpServerUrl, "--pki", s.nodeClientPki.string(), "--policy",
                                "all", "--mode", "all", "--identity", "anonymous", "--identity",
                                std::string("user:operator:") + kOperatorPassword, "--identity",
                                "x509:" + s.userCert.string() + ":" + s.userKey.string(),
                                "--identity", "user:operator:wrong-password", "--call-echo"}),
                    100s);
            s.matrix = jsonLines(s.matrixRun.out);
        }
        for (const auto& j : s.matrix)
            if (str(j, "policy") == GetParam().policy && str(j, "mode") == GetParam().mode &&
                j.value("index", -1) == identity)
                return j;
        ADD_FAILURE() << "no result for " << GetParam().policy << " " << GetParam().mode
                      << " identity " << identity << ":\n"
                      << s.matrixRun.text() << "\nserver stderr:\n"
                      << s.pnpServer.logTail();
        return Json();
    }

    // Channel, session and reads served; Demo.Echo answered with `call` (the role policy of
    // pnp servers with users: anonymous sessions observe, Operators call).
    void expectServed(MatrixIdentity identity, const std::string& call) {
        const Json j = row(identity);
        if (j.is_null()) return;
        EXPECT_TRUE(j.value("ok", false)) << j.dump() << "\nserver stderr:\n"
                                          << shared().pnpServer.logTail();
        EXPECT_EQ(j.value("state", -1), 0) << "ServerStatus.State is not Running: " << j.dump();
        EXPECT_TRUE(j.contains("demoInt32") && j["demoInt32"].is_number())
            << "Demo Scalar.Int32 not read: " << j.dump();
        EXPECT_EQ(str(j, "call"), call) << "Demo.Echo: " << j.dump();
        if (call == "Good") {
            EXPECT_NE(str(j, "echo"), "") << j.dump();
        }
    }
};

TEST_P(NodeClientToPnpServer, Anonymous) { expectServed(kAnonymous, "BadUserAccessDenied"); }

TEST_P(NodeClientToPnpServer, UserNameTokenWithEncryptedPassword) {
    ASSERT_EQ(shared().passwordUserSetup, "");
    expectServed(kUserName, "Good");
}

TEST_P(NodeClientToPnpServer, X509UserToken) {
    ASSERT_EQ(shared().userCertificateSetup + shared().certificateUserSetup, "");
    expectServed(kX509, "Good");
}

TEST_P(NodeClientToPnpServer, WrongPasswordIsRefused) {
    ASSERT_EQ(shared().passwordUserSetup, "");
    const Json j = row(kWrongPassword);
    if (j.is_null()) return;
    EXPECT_FALSE(j.value("ok", true)) << j.dump();
    const std::string status = str(j, "status");
    EXPECT_TRUE(status == "BadUserAccessDenied" || status == "BadIdentityTokenRejected")
        << j.dump();
}

INSTANTIATE_TEST_SUITE_P(PolicyMode, NodeClientToPnpServer, ::testing::ValuesIn(kPolicyModes),
                         paramName);

// ---- c: an untrusted node-opcua client, then `pnp pki trust` -------------------------------

TEST_F(NodeClientCase, UntrustedNodeClientIsRejectedUntilTrusted) {
    Shared& s = shared();
    // A server of its own, whose PKI has never seen the node-opcua client.
    const fs::path pki = s.root / "server2-pki";
    ChildProcess server;
    std::string error, line;
    ASSERT_TRUE(server.start({PNP_BINARY, "ua", "serve", "--host", "127.0.0.1", "--port", "0",
                              "--no-register", "--pki", pki.string()},
                             (s.root / "pnp-server2.stderr").string(), error))
        << error;
    ASSERT_TRUE(server.waitForPrefix("listening on ", 30s, error, &line)) << error << "\n"
                                                                          << server.logTail();
    const std::string url = line.substr(std::string("listening on ").size());
    const fs::path serverCert = newestDer(pki / "own" / "certs");
    ASSERT_FALSE(serverCert.empty());
    copyInto(serverCert, s.nodeClientPki / "trusted" / "certs", "pnp-server2.der");

    const auto connect = [&] {
        return run(
            s.nodeArgs("node_secure_client.js", {url, "--pki", s.nodeClientPki.string(), "--policy",
                                                 "Basic256Sha256", "--mode", "SignAndEncrypt"}),
            60s);
    };
    RunResult r = connect();
    EXPECT_NE(r.exitCode, 0) << r.text();
    auto lines = jsonLines(r.out);
    ASSERT_EQ(lines.size(), 1u) << r.text();
    EXPECT_FALSE(lines[0].value("ok", true)) << lines[0].dump();
    // Refused at OpenSecureChannel. Our server answers with an ERR message
    // (BadSecurityChecksFailed) and closes (OPC 10000-6 §7.1.5); node-opcua 2.186.4 reports a
    // status only for an OpenSecureChannel ServiceFault and, for an ERR without a request id,
    // only that the server closed the connection while it was opening the channel.
    const std::string refusal = str(lines[0], "status") + " " + str(lines[0], "error");
    EXPECT_TRUE(refusal.find("BadSecurityChecksFailed") != std::string::npos ||
                refusal.find("may have been rejected by server") != std::string::npos)
        << lines[0].dump();

    // The refused certificate is in rejected/certs, for the operator to approve.
    EXPECT_GE(fileCount(pki / "rejected" / "certs"), 1u);
    const Json entry = pkiEntry(pki, s.nodeClientThumbprint);
    ASSERT_FALSE(entry.is_null()) << "`pnp pki list` does not show " << s.nodeClientThumbprint;
    EXPECT_EQ(str(entry, "state"), "rejected") << entry.dump();

    const RunResult trust =
        pnp({"pki", "--pki", pki.string(), "trust", s.nodeClientThumbprint.substr(0, 12)});
    ASSERT_EQ(trust.exitCode, 0) << trust.text();
    EXPECT_EQ(str(pkiEntry(pki, s.nodeClientThumbprint), "state"), "trusted");

    r = connect();
    EXPECT_EQ(r.exitCode, 0) << r.text() << "\nserver stderr:\n" << server.logTail();
    lines = jsonLines(r.out);
    ASSERT_EQ(lines.size(), 1u) << r.text();
    EXPECT_TRUE(lines[0].value("ok", false)) << lines[0].dump();
    EXPECT_TRUE(server.running()) << server.logTail();
    server.stop();
}

// ---- d: pnp ua read -> node-opcua server ---------------------------------------------------

class PnpClientToNodeServer : public PnpClientCase,
                              public ::testing::WithParamInterface<PolicyMode> {
  protected:
    // `pnp ua read URL i=2259 <demo Scalar.Int32>` with this case's policy and mode (Sign: the
    // listener that offers Sign only, since our client takes the most secure endpoint it
    // may), plus `extra` options.
    RunResult read(const std::vector<std::string>& extra) {
        Shared& s = shared();
        const bool sign = std::string(GetParam().mode) == "Sign";
        std::vector<std::string> args = {"ua",
                                         "read",
                                         sign ? s.nodeServerSignOnlyUrl : s.nodeServerUrl,
                                         "i=2259",
                                         kDemoInt32,
                                         "--pki",
                                         s.pnpClientPki.string(),
                                         "--policy",
                                         GetParam().policy,
                                         "--mode",
                                         GetParam().cliMode,
                                         "--json"};
        args.insert(args.end(), extra.begin(), extra.end());
        return pnp(args);
    }

    void expectRead(const std::vector<std::string>& extra) {
        const RunResult r = read(extra);
        ASSERT_EQ(r.exitCode, 0) << r.text() << "\nnode server stderr:\n"
                                 << shared().nodeServer.logTail(2000);
        const Json j = Json::parse(r.out, nullptr, false);
        ASSERT_TRUE(j.is_object() && j.contains("results")) << r.out;
        ASSERT_EQ(j["results"].size(), 2u) << r.out;
        for (const auto& v : j["results"]) EXPECT_EQ(str(v, "status"), "Good") << v.dump();
        EXPECT_EQ(j["results"][0].value("value", Json()), 0) << "State is not Running: " << r.out;
    }
};

TEST_P(PnpClientToNodeServer, Anonymous) { expectRead({}); }

TEST_P(PnpClientToNodeServer, UserNameToken) {
    expectRead({"--user", std::string("operator:") + kOperatorPassword});
}

TEST_P(PnpClientToNodeServer, X509UserToken) {
    Shared& s = shared();
    ASSERT_EQ(s.userCertificateSetup, "");
    expectRead({"--user-cert", s.userCert.string(), "--user-key", s.userKey.string()});
}

TEST_P(PnpClientToNodeServer, WrongPasswordIsRefused) {
    const RunResult r = read({"--user", "operator:wrong-password"});
    EXPECT_NE(r.exitCode, 0) << r.text();
    EXPECT_TRUE(r.err.find("BadUserAccessDenied") != std::string::npos ||
                r.err.find("BadIdentityTokenRejected") != std::string::npos)
        << r.text();
}

INSTANTIATE_TEST_SUITE_P(PolicyMode, PnpClientToNodeServer, ::testing::ValuesIn(kPolicyModes),
                         paramName);

TEST_F(PnpClientCase, RefusedUntilTheNodeServerTrustsIt) {
    // The first run of the shared setup, before the node-opcua server trusted our client.
    const RunResult& r = shared().firstPnpClientRun;
    EXPECT_NE(r.exitCode, 0) << r.text();
    EXPECT_TRUE(r.err.find("BadSecurityChecksFailed") != std::string::npos ||
                r.err.find("BadCertificateUntrusted") != std::string::npos)
        << r.text();
}

TEST_F(PnpClientCase, RefusesAnUntrustedNodeServer) {
    Shared& s = shared();
    const fs::path pki = s.root / "pnp-client2-pki";  // has never seen the node-opcua server
    const RunResult r = pnp({"ua", "read", s.nodeServerUrl, "i=2259", "--pki", pki.string()});
    EXPECT_NE(r.exitCode, 0) << r.text();
    EXPECT_NE(r.err.find("pnp pki trust"), std::string::npos)
        << "the message does not tell how to trust the server:\n"
        << r.text();
    // The server's certificate waits in rejected/ for the operator.
    const Json entry = pkiEntry(pki, s.nodeServerThumbprint);
    ASSERT_FALSE(entry.is_null()) << "`pnp pki list` does not show the node-opcua server "
                                  << s.nodeServerThumbprint;
    EXPECT_EQ(str(entry, "state"), "rejected") << entry.dump();
    // The operator approves it.
    const RunResult trust =
        pnp({"pki", "--pki", pki.string(), "trust", s.nodeServerThumbprint.substr(0, 12)});
    ASSERT_EQ(trust.exitCode, 0) << trust.text();
    EXPECT_EQ(str(pkiEntry(pki, s.nodeServerThumbprint), "state"), "trusted");
}

// ---- e: a node-opcua server registers with our LDS over a secure channel -------------------

// `pnp discover --lds URL --once --json --no-details`: the entry whose url is `url`, or null.
Json registered(const std::string& ldsUrl, const std::string& url) {
    const RunResult r = pnp({"discover", "--lds", ldsUrl, "--no-mdns", "--once", "--json",
                             "--no-details", "--duration", "500"});
    Json list = Json::parse(r.out, nullptr, false);
    if (!list.is_array()) return Json();
    for (const auto& e : list)
        if (str(e, "url") == url) return e;
    return Json();
}

// Polls `pred` every 250 ms until it holds or `timeout` passes.
template <typename Pred>
bool eventually(Pred pred, std::chrono::milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (true) {
        if (pred()) return true;
        if (std::chrono::steady_clock::now() >= end) return false;
        std::this_thread::sleep_for(250ms);
    }
}

TEST_F(SecureInteropCase, NodeServerRegistersWithOurLdsOverASecureChannelOnceTrusted) {
    Shared& s = shared();
    const fs::path ldsPki = s.root / "lds-pki";
    const fs::path nodePki = s.root / "node-registering-pki";
    ChildProcess lds;
    std::string error, line;
    // Part 12's registration period: node-opcua renews every 8 minutes only.
    ASSERT_TRUE(lds.start({PNP_BINARY, "lds", "--host", "127.0.0.1", "--port", "0", "--pki",
                           ldsPki.string(), "--registration-expiry", "600000"},
                          (s.root / "lds.stderr").string(), error))
        << error;
    ASSERT_TRUE(lds.waitForPrefix("listening on ", 30s, error, &line)) << error << "\n"
                                                                       << lds.logTail();
    const std::string ldsUrl = line.substr(std::string("listening on ").size());
    const unsigned short port = pnp::testing::freeLoopbackPortRange(1);
    const std::string url = "opc.tcp://127.0.0.1:" + std::to_string(port);
    const auto startNodeServer = [&](ChildProcess& p, const std::string& log) {
        std::string e;
        ASSERT_TRUE(
            p.start({"/usr/bin/env", "PNP_NODE_PKI_DIR=" + nodePki.string(), s.node,
                     kInterop + "node_lds.js", "server", std::to_string(port), "127.0.0.1", ldsUrl},
                    (s.root / log).string(), e))
            << e;
        // node-opcua makes its certificate at the first start (an RSA key in JavaScript).
        ASSERT_TRUE(p.waitForPrefix("listening on ", 60s, e)) << e << "\n" << p.logTail();
    };

    // 1. Its certificate is unknown to the LDS: GetEndpoints over None is answered, the
    //    registration over SignAndEncrypt is refused and the certificate waits in rejected/.
    ChildProcess node;
    startNodeServer(node, "node-registering-1.stderr");
    ASSERT_FALSE(HasFatalFailure());
    EXPECT_TRUE(eventually([&] { return fileCount(ldsPki / "rejected" / "certs") >= 1; }, 30s))
        << "no certificate in the LDS's rejected/certs\nnode:\n"
        << node.logTail() << "\nlds:\n"
        << lds.logTail();
    EXPECT_TRUE(registered(ldsUrl, url).is_null()) << "registered without being trusted";
    // ... and the LDS told its operator which certificate it refused and how to approve it.
    EXPECT_TRUE(eventually(
        [&] {
            const std::string log = lds.logTail();
            return log.find(
                       "refused the certificate of urn:pnp:node-opcua-registering-server "
                       "(BadCertificateUntrusted); approve it with `pnp pki trust ") !=
                   std::string::npos;
        },
        5s))
        << lds.logTail();
    node.stop();

    // 2. The operator approves it (the only rejected certificate) and restarts the device.
    const RunResult list = pnp({"pki", "--pki", ldsPki.string(), "list", "--json"});
    ASSERT_EQ(list.exitCode, 0) << list.text();
    std::string thumbprint;
    const Json entries = Json::parse(list.out, nullptr, false);
    ASSERT_TRUE(entries.is_array()) << list.out;
    for (const auto& e : entries)
        if (str(e, "state") == "rejected") thumbprint = str(e, "thumbprint");
    ASSERT_FALSE(thumbprint.empty()) << list.out;
    const RunResult trust = pnp({"pki", "--pki", ldsPki.string(), "trust", thumbprint});
    ASSERT_EQ(trust.exitCode, 0) << trust.text();

    ChildProcess node2;
    startNodeServer(node2, "node-registering-2.stderr");
    ASSERT_FALSE(HasFatalFailure());
    Json entry;
    EXPECT_TRUE(eventually(
        [&] {
            entry = registered(ldsUrl, url);
            return !entry.is_null();
        },
        30s))
        << "not registered after `pnp pki trust`\nnode:\n"
        << node2.logTail() << "\nlds:\n"
        << lds.logTail();
    // Its MdnsDiscoveryConfiguration's name (node-opcua: its ApplicationUri). The LDS runs
    // without --allow-none, so it accepted this RegisterServer2 over a secure channel only.
    EXPECT_EQ(str(entry, "name"), "urn:pnp:node-opcua-registering-server") << entry.dump();

    // 3. Stopping, it unregisters (RegisterServer2 IsOnline = false, again secured).
    node2.stop();
    EXPECT_TRUE(eventually([&] { return registered(ldsUrl, url).is_null(); }, 15s))
        << "still registered after the node-opcua server stopped";
    EXPECT_TRUE(lds.running()) << lds.logTail();
    lds.stop();
}

}  // namespace
