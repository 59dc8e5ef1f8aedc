// End-to-end tests of the `pnp` executable: `pnp ua serve` runs as a child process on a free
// port (killed by its PID whatever happens), the client subcommands run as processes against
// it, and the tests check their output, JSON and exit codes.
#include <arpa/inet.h>
#include <fcntl.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#ifndef PNP_BINARY
#error "PNP_BINARY (path of the pnp executable) must be defined"
#endif

namespace {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

struct Result {
    int exitCode = -1;  // -1: killed (timeout or signal)
    std::string out;
    std::string err;
    milliseconds elapsed{0};
};

// A child process with its stdout / stderr on pipes. The destructor kills it (by PID) if it
// still runs and reaps it.
class Child {
  public:
    explicit Child(const std::vector<std::string>& args) {
        int outPipe[2], errPipe[2];
        if (pipe2(outPipe, O_CLOEXEC) != 0 || pipe2(errPipe, O_CLOEXEC) != 0) return;
        start_ = Clock::now();
        pid_ = fork();
        if (pid_ == 0) {
            prctl(PR_SET_PDEATHSIG, SIGKILL);  // never outlive the test process
            dup2(outPipe[1], STDOUT_FILENO);
            dup2(errPipe[1], STDERR_FILENO);
            int devnull = open("/dev/null", O_RDONLY);
            if (devnull >= 0) dup2(devnull, STDIN_FILENO);
            std::vector<char*> argv;
            for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
            argv.push_back(nullptr);
            execv(argv[0], argv.data());
            _exit(127);
        }
        close(outPipe[1]);
        close(errPipe[1]);
        out_ = outPipe[0];
        err_ = errPipe[0];
    }
    ~Child() {
        kill();
        if (out_ >= 0) close(out_);
        if (err_ >= 0) close(err_);
    }
    Child(const Child&) = delete;
    Child& operator=(const Child&) = delete;

    pid_t pid() const { return pid_; }

    // Reads stdout until a line contains `needle` or the deadline passes; the line or nullopt.
    std::optional<std::string> waitForLine(const std::string& needle, milliseconds timeout) {
        const auto deadline = Clock::now() + timeout;
        for (;;) {
            auto nl = out.find('\n');
            while (nl != std::string::npos) {
                std::string line = out.substr(0, nl);
                out.erase(0, nl + 1);
                if (line.find(needle) != std::string::npos) return line;
                nl = out.find('\n');
            }
            auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now());
            if (left.count() <= 0 || !pump(left)) return std::nullopt;
        }
    }

    // Waits for the exit (collecting the output); kills the child after `timeout`.
    Result wait(milliseconds timeout) {
        const auto deadline = Clock::now() + timeout;
        while (out_ >= 0 || err_ >= 0) {
            auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now());
            if (left.count() <= 0) {
                kill();
                break;
            }
            pump(left);
        }
        Result r;
        r.out = out;
        r.err = err;
        if (pid_ > 0) {
            int st = 0;
            // Output closed: the process is exiting; still bound the wait.
            while (waitpid(pid_, &st, WNOHANG) == 0) {
                if (Clock::now() > deadline) {
                    ::kill(pid_, SIGKILL);
                    waitpid(pid_, &st, 0);
                    break;
                }
                std::this_thread::sleep_for(milliseconds(2));
            }
            r.exitCode = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
            pid_ = -1;
        }
        r.elapsed = std::chrono::duration_cast<milliseconds>(Clock::now() - start_);
        return r;
    }

    bool running() {
        if (pid_ <= 0) return false;
        int st = 0;
        return waitpid(pid_, &st, WNOHANG) == 0 ? true : (exited_ = st, pid_ = -1, false);
    }

    // SIGTERM, a bounded wait, then SIGKILL. Returns the exit code or -1.
    int terminate(milliseconds grace = milliseconds(5000)) {
        if (pid_ <= 0) return -1;
        ::kill(pid_, SIGTERM);
        const auto deadline = Clock::now() + grace;
        int st = 0;
        while (waitpid(pid_, &st, WNOHANG) == 0) {
            if (Clock::now() > deadline) {
                ::kill(pid_, SIGKILL);
                waitpid(pid_, &st, 0);
                pid_ = -1;
                return -1;
            }
            std::this_thread::sleep_for(milliseconds(5));
        }
        pid_ = -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    }

    std::string out, err;

  private:
    void kill() {
        if (pid_ <= 0) return;
        ::kill(pid_, SIGKILL);
        int st = 0;
        waitpid(pid_, &st, 0);
        pid_ = -1;
    }
    // Reads what is available on stdout / stderr (waiting at most `timeout`); false when
    // both are closed.
    bool pump(milliseconds timeout) {
        pollfd fds[2] = {{out_, POLLIN, 0}, {err_, POLLIN, 0}};
        if (out_ < 0 && err_ < 0) return false;
        int n = poll(fds, 2, static_cast<int>(timeout.count()));
        if (n <= 0) return n == 0;
        char buf[65536];
        for (int i = 0; i < 2; ++i) {
            if (fds[i].fd < 0 || (fds[i].revents & (POLLIN | POLLHUP | POLLERR)) == 0) continue;
            ssize_t k = read(fds[i].fd, buf, sizeof buf);
            if (k > 0) {
                (i == 0 ? out : err).append(buf, static_cast<std::size_t>(k));
            } else {
                close(fds[i].fd);
                (i == 0 ? out_ : err_) = -1;
            }
        }
        return true;
    }

    pid_t pid_ = -1;
    int out_ = -1, err_ = -1;
    int exited_ = 0;
    Clock::time_point start_;
};

std::vector<std::string> withBinary(std::vector<std::string> args) {
    args.insert(args.begin(), PNP_BINARY);
    return args;
}

Result run(std::vector<std::string> args, milliseconds timeout = milliseconds(20000)) {
    Child c(withBinary(std::move(args)));
    return c.wait(timeout);
}

// A TCP port nothing listens on right now.
int freePort() {
    int s = socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = 0;
    socklen_t len = sizeof a;
    int port = 0;
    if (bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0 &&
        getsockname(s, reinterpret_cast<sockaddr*>(&a), &len) == 0)
        port = ntohs(a.sin_port);
    close(s);
    return port;
}

std::string describe(const Result& r) {
    return "exit " + std::to_string(r.exitCode) + "\n--- stdout:\n" + r.out + "--- stderr:\n" +
           r.err;
}

json parseJson(const Result& r) {
    try {
        return json::parse(r.out);
    } catch (const std::exception& e) {
        ADD_FAILURE() << "not JSON: " << e.what() << "\n" << describe(r);
        return json();
    }
}

// ---- the server fixture -------------------------------------------------------------------
class CliTest : public ::testing::Test {
  protected:
    static void SetUpTestSuite() {
        for (int attempt = 0; attempt < 3 && !server_; ++attempt) {
            port_ = freePort();
            auto c = std::make_unique<Child>(
                withBinary({"ua", "serve", "--host", "127.0.0.1", "--port", std::to_string(port_),
                            "--user", "operator:secret"}));
            auto line = c->waitForLine("listening on", milliseconds(10000));
            if (line) {
                listeningLine_ = *line;
                server_ = std::move(c);
            } else {
                std::fprintf(stderr, "pnp ua serve did not start (attempt %d): %s\n", attempt + 1,
                             c->err.c_str());
            }
        }
        url_ = "opc.tcp://127.0.0.1:" + std::to_string(port_);
    }
    static void TearDownTestSuite() {
        if (server_) server_->terminate();
        server_.reset();
    }
    void SetUp() override {
        ASSERT_TRUE(server_) << "pnp ua serve is not running";
        ASSERT_TRUE(server_->running()) << "pnp ua serve exited";
    }

    static std::string demo(const std::string& id) { return "nsu=urn:pnp:demo;s=" + id; }

    static std::unique_ptr<Child> server_;
    static int port_;
    static std::string url_;
    static std::string listeningLine_;
};
std::unique_ptr<Child> CliTest::server_;
int CliTest::port_ = 0;
std::string CliTest::url_;
std::string CliTest::listeningLine_;

TEST_F(CliTest, ServePrintsTheListeningLine) {
    EXPECT_NE(listeningLine_.find("listening on opc.tcp://127.0.0.1:" + std::to_string(port_)),
              std::string::npos)
        << listeningLine_;
}

TEST_F(CliTest, Endpoints) {
    Result r = run({"ua", "endpoints", url_});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("opc.tcp://"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("Anonymous"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("UserName"), std::string::npos) << r.out;

    r = run({"ua", "endpoints", url_, "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    ASSERT_TRUE(j["endpoints"].is_array()) << r.out;
    ASSERT_GE(j["endpoints"].size(), 1u);
    // Secure by default: the most secure endpoint first, and no None endpoint for sessions.
    const json& e = j["endpoints"][0];
    EXPECT_EQ(e["securityMode"], "SignAndEncrypt");
    EXPECT_EQ(e["securityPolicyUri"],
              "http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss");
    for (const auto& any : j["endpoints"]) EXPECT_NE(any["securityMode"], "None") << r.out;
    std::vector<std::string> tokens;
    for (const auto& t : e["userIdentityTokens"]) tokens.push_back(t["tokenType"]);
    EXPECT_NE(std::find(tokens.begin(), tokens.end(), "Anonymous"), tokens.end());
    EXPECT_NE(std::find(tokens.begin(), tokens.end(), "UserName"), tokens.end());
}

TEST_F(CliTest, BrowseObjectsShowsServerAndDemo) {
    Result r = run({"ua", "browse", url_, "i=85"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("Server"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("Demo"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("BROWSE NAME"), std::string::npos) << r.out;

    r = run({"ua", "browse", url_, "--json"});  // default node: Objects
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    EXPECT_EQ(j["nodeId"], "i=85");
    bool server = false, demoObj = false;
    for (const auto& ref : j["references"]) {
        if (ref["nodeId"] == "i=2253" && ref["browseName"] == "Server") server = true;
        if (ref["browseName"].get<std::string>().ends_with(":Demo") &&
            ref["nodeId"].get<std::string>().ends_with(";s=Demo")) {
            demoObj = true;
            EXPECT_EQ(ref["nodeClass"], "Object");
            EXPECT_EQ(ref["referenceType"], "Organizes");
        }
    }
    EXPECT_TRUE(server) << r.out;
    EXPECT_TRUE(demoObj) << r.out;
}

TEST_F(CliTest, BrowseDepthTwoDescendsIntoDemo) {
    Result r = run({"ua", "browse", url_, demo("Demo"), "--depth", "2", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    std::set<std::string> names;
    for (const auto& ref : j["references"]) names.insert(ref["nodeId"]);
    // 25 types x scalar + array, and the three methods.
    EXPECT_GE(j["references"].size(), 53u) << r.out;
    bool nested = false;
    for (const auto& ref : j["references"])
        if (ref["nodeId"].get<std::string>().ends_with(";s=Demo.Add") && ref.contains("references"))
            for (const auto& p : ref["references"])
                if (p["browseName"] == "InputArguments") nested = true;
    EXPECT_TRUE(nested) << "Demo.Add's InputArguments not listed at depth 2";
}

TEST_F(CliTest, ReadServerStatusState) {
    Result r = run({"ua", "read", url_, "i=2259"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("Running"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("Good"), std::string::npos) << r.out;

    r = run({"ua", "read", url_, "/Objects/Server/ServerStatus/State", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    ASSERT_EQ(j["results"].size(), 1u);
    const json& x = j["results"][0];
    EXPECT_EQ(x["nodeId"], "i=2259");
    EXPECT_EQ(x["status"], "Good");
    EXPECT_EQ(x["statusCode"], 0);
    EXPECT_EQ(x["type"], "Int32");
    EXPECT_EQ(x["value"], 0);
    EXPECT_EQ(x["valueName"], "Running");
    EXPECT_TRUE(x.contains("serverTimestamp"));
}

TEST_F(CliTest, ReadServerStatusIsDecoded) {
    Result r = run({"ua", "read", url_, "i=2256", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json v = parseJson(r)["results"][0]["value"];
    EXPECT_EQ(v["Type"], "ServerStatusDataType") << r.out;
    EXPECT_EQ(v["Body"]["State"], "Running") << r.out;
}

TEST_F(CliTest, ReadOtherAttributes) {
    Result r = run({"ua", "read", url_, demo("Scalar.Double"), demo("Array.String"), "--attribute",
                    "DataType", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    EXPECT_EQ(j["results"][0]["value"], "i=11");
    EXPECT_EQ(j["results"][0]["valueName"], "Double");
    EXPECT_EQ(j["results"][1]["value"], "i=12");

    r = run({"ua", "read", url_, demo("Scalar.Double"), "--attribute", "AccessLevel"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("CurrentRead|CurrentWrite"), std::string::npos) << r.out;

    r = run({"ua", "read", url_, demo("Demo"), "--attribute", "nodeclass"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("Object"), std::string::npos) << r.out;
}

struct WriteCase {
    std::string node;
    std::string text;
    std::string type;  // "" : from the node
    json expected;     // the value as `read --json` shows it
    std::string expectedType;
};

TEST_F(CliTest, WriteAndReadBack) {
    const std::vector<WriteCase> cases = {
        {"Scalar.Int32", "42", "Int32", 42, "Int32"},
        {"Scalar.Int32", "-7", "", -7, "Int32"},
        {"Scalar.Double", "3.25", "", 3.25, "Double"},
        {"Scalar.Boolean", "true", "", true, "Boolean"},
        {"Scalar.Byte", "0xff", "", 255, "Byte"},
        {"Scalar.UInt64", "18446744073709551615", "", 18446744073709551615ull, "UInt64"},
        {"Scalar.String", "h\xc3\xa9llo world", "", "h\xc3\xa9llo world", "String"},
        {"Scalar.DateTime", "2024-05-06T09:08:09.123+02:00", "", "2024-05-06T07:08:09.123Z",
         "DateTime"},
        {"Scalar.ByteString", "0x0001feff", "", "AAH+/w==", "ByteString"},
        {"Scalar.Guid", "72962b91-fa75-4ae6-8d28-b404dc7daf63", "",
         "72962B91-FA75-4AE6-8D28-B404DC7DAF63", "Guid"},
        {"Scalar.NodeId", "nsu=urn:pnp:demo;s=Demo", "", nullptr, "NodeId"},  // checked below
        {"Scalar.LocalizedText",
         "\"hello\"@en-US",
         "",
         {{"Locale", "en-US"}, {"Text", "hello"}},
         "LocalizedText"},
        {"Scalar.QualifiedName", "1:Qn", "", "1:Qn", "QualifiedName"},
        {"Scalar.StatusCode", "BadOutOfRange", "", "BadOutOfRange", "StatusCode"},
        {"Scalar.Variant", "2.5", "", 2.5, "Double"},
        {"Array.Int32", "[1,2,3]", "", json::array({1, 2, 3}), "Int32[3]"},
        {"Array.Int32", "[-2147483648,0,2147483647]", "Int32[]",
         json::array({-2147483648LL, 0, 2147483647}), "Int32[3]"},
        {"Array.String", "[\"a\",\"\",\"\xc3\xbc\"]", "", json::array({"a", "", "\xc3\xbc"}),
         "String[3]"},
        {"Array.Double", "[1.5,-1e300]", "Double", json::array({1.5, -1e300}), "Double[2]"},
        {"Array.Boolean", "[]", "", json::array(), "Boolean[0]"},
    };
    for (const auto& c : cases) {
        SCOPED_TRACE(c.node + " <- " + c.text + (c.type.empty() ? "" : " --type " + c.type));
        std::vector<std::string> args = {"ua", "write", url_, demo(c.node), c.text};
        if (!c.type.empty()) args.insert(args.end(), {"--type", c.type});
        Result w = run(args);
        ASSERT_EQ(w.exitCode, 0) << describe(w);
        EXPECT_NE(w.out.find("Good"), std::string::npos) << w.out;

        Result r = run({"ua", "read", url_, demo(c.node), "--json"});
        ASSERT_EQ(r.exitCode, 0) << describe(r);
        json x = parseJson(r)["results"][0];
        EXPECT_EQ(x["type"], c.expectedType) << r.out;
        if (!c.expected.is_null()) {
            EXPECT_EQ(x["value"], c.expected) << r.out;
        }
        if (c.node == "Scalar.NodeId") {
            std::string v = x["value"];
            EXPECT_TRUE(v.starts_with("ns=") && v.ends_with(";s=Demo")) << v;
        }
    }
}

TEST_F(CliTest, WriteJsonOutputAndTypeMismatch) {
    Result w = run({"ua", "write", url_, demo("Scalar.Int16"), "-1234", "--json"});
    ASSERT_EQ(w.exitCode, 0) << describe(w);
    json j = parseJson(w);
    EXPECT_EQ(j["status"], "Good");
    EXPECT_EQ(j["type"], "Int16");
    EXPECT_EQ(j["value"], -1234);
    // A value of the wrong type (forced with --type) is refused by the server: exit 1.
    w = run({"ua", "write", url_, demo("Scalar.Int16"), "hello", "--type", "String"});
    EXPECT_EQ(w.exitCode, 1) << describe(w);
    EXPECT_NE(w.out.find("BadTypeMismatch"), std::string::npos) << describe(w);
}

TEST_F(CliTest, ReadJsonCanBeWrittenBack) {
    // read --json output of a value is accepted by write.
    ASSERT_EQ(run({"ua", "write", url_, demo("Array.LocalizedText"),
                   "[{\"Locale\":\"de\",\"Text\":\"hallo\"},\"no locale\"]"})
                  .exitCode,
              0);
    Result r = run({"ua", "read", url_, demo("Array.LocalizedText"), "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json v = parseJson(r)["results"][0]["value"];
    ASSERT_EQ(run({"ua", "write", url_, demo("Array.LocalizedText"), "[]"}).exitCode, 0);
    ASSERT_EQ(run({"ua", "write", url_, demo("Array.LocalizedText"), v.dump()}).exitCode, 0);
    Result again = run({"ua", "read", url_, demo("Array.LocalizedText"), "--json"});
    EXPECT_EQ(parseJson(again)["results"][0]["value"], v);
}

TEST_F(CliTest, WriteDecodedStructures) {
    // A structure given by its fields (encoded from the server's DataTypeDefinition).
    Result w = run({"ua", "write", url_, demo("Scalar.ExtensionObject"),
                    "{\"Type\":\"Range\",\"Body\":{\"Low\":-1.5,\"High\":99.25}}"});
    ASSERT_EQ(w.exitCode, 0) << describe(w);
    Result r = run({"ua", "read", url_, demo("Scalar.ExtensionObject"), "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json v = parseJson(r)["results"][0]["value"];
    EXPECT_EQ(v["TypeId"], "i=886") << r.out;
    EXPECT_EQ(v["Body"]["Low"], -1.5) << r.out;
    EXPECT_EQ(v["Body"]["High"], 99.25) << r.out;

    // What `read --json` printed for ServerStatus (nested BuildInfo, enumeration by name)
    // is written back unchanged.
    r = run({"ua", "read", url_, "i=2256", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json status = parseJson(r)["results"][0]["value"];
    w = run({"ua", "write", url_, demo("Scalar.ExtensionObject"), status.dump()});
    ASSERT_EQ(w.exitCode, 0) << describe(w);
    r = run({"ua", "read", url_, demo("Scalar.ExtensionObject"), "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_EQ(parseJson(r)["results"][0]["value"], status);

    // Arrays of structures, with the element type from the array.
    w = run({"ua", "write", url_, demo("Array.ExtensionObject"),
             "[{\"Type\":\"Range\",\"Body\":{\"Low\":0,\"High\":1}},"
             "{\"Type\":\"Range\",\"Body\":{\"Low\":-10,\"High\":10}}]"});
    ASSERT_EQ(w.exitCode, 0) << describe(w);
    r = run({"ua", "read", url_, demo("Array.ExtensionObject"), "--json"});
    json a = parseJson(r)["results"][0];
    EXPECT_EQ(a["type"], "ExtensionObject[2]");
    EXPECT_EQ(a["value"][1]["Body"]["Low"], -10);

    // A misspelt field is a usage error.
    w = run({"ua", "write", url_, demo("Scalar.ExtensionObject"),
             "{\"Type\":\"Range\",\"Body\":{\"Lo\":1}}"});
    EXPECT_EQ(w.exitCode, 2) << describe(w);
    EXPECT_NE(w.err.find("no field Lo"), std::string::npos) << w.err;
}

TEST_F(CliTest, CallAdd) {
    Result r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Add"), "2", "3"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("Good"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("sum"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("5"), std::string::npos) << r.out;

    r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Add"), "2", "3", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    EXPECT_EQ(j["status"], "Good");
    ASSERT_EQ(j["outputs"].size(), 1u) << r.out;
    EXPECT_EQ(j["outputs"][0]["name"], "sum");
    EXPECT_EQ(j["outputs"][0]["type"], "Int32");
    EXPECT_EQ(j["outputs"][0]["value"], 5);

    // Negative numbers are arguments, not options; --types as in the README.
    r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Add"), "-2", "-3", "--types",
             "Int32,Int32", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_EQ(parseJson(r)["outputs"][0]["value"], -5);
}

TEST_F(CliTest, CallEcho) {
    Result r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Echo"), "0x0050ff", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    ASSERT_EQ(j["outputs"].size(), 1u) << r.out;
    EXPECT_EQ(j["outputs"][0]["type"], "ByteString");
    EXPECT_EQ(j["outputs"][0]["value"], "AFD/");  // base64 of 00 50 ff

    r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Echo"), "AFD/"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("0x0050ff"), std::string::npos) << r.out;
}

TEST_F(CliTest, CallWithWrongArgumentsIsAUsageError) {
    Result r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Add"), "2"});
    EXPECT_EQ(r.exitCode, 2) << describe(r);
    EXPECT_NE(r.err.find("a: Int32, b: Int32"), std::string::npos) << r.err;
    r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Add"), "two", "3"});
    EXPECT_EQ(r.exitCode, 2) << describe(r);
}

TEST_F(CliTest, UnknownNodeIsAnOpcUaError) {
    Result r = run({"ua", "read", url_, demo("Does.Not.Exist")});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_NE(r.out.find("BadNodeIdUnknown"), std::string::npos) << describe(r);

    r = run({"ua", "read", url_, "ns=0;i=999999", "--json"});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_EQ(parseJson(r)["results"][0]["status"], "BadNodeIdUnknown");

    // Several nodes: the good ones are still shown.
    r = run({"ua", "read", url_, "i=2259", demo("Does.Not.Exist")});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_NE(r.out.find("Running"), std::string::npos) << r.out;

    r = run({"ua", "write", url_, demo("Does.Not.Exist"), "1", "--type", "Int32"});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_NE(r.out.find("BadNodeIdUnknown"), std::string::npos) << describe(r);

    r = run({"ua", "read", url_, "/Objects/NoSuchChild"});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_NE((r.out + r.err).find("BadNoMatch"), std::string::npos) << describe(r);
}

TEST_F(CliTest, BadUsageExitsWithTwo) {
    for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
             {},
             {"ua"},
             {"ua", "frobnicate"},
             {"ua", "read"},
             {"ua", "read", url_},
             {"ua", "read", "http://example.com", "i=85"},
             {"ua", "read", url_, "not-a-node"},
             {"ua", "read", url_, "i=85", "--attribute", "Colour"},
             {"ua", "browse", url_, "--depth", "0"},
             {"ua", "write", url_, demo("Scalar.Int32"), "forty-two"},
             {"ua", "write", url_, demo("Scalar.Byte"), "256"},
             {"ua", "write", url_, demo("Scalar.Int32"), "1", "--type", "Int33"},
             {"ua", "read", url_, "i=85", "--timeout", "abc"},
             {"ua", "serve", "--port", "70000"},
             {"ua", "serve", "--no-anonymous"},
             {"ua", "monitor", url_},
             {"ua", "monitor", url_, "not-a-node"},
             {"ua", "monitor", url_, "i=2258", "--interval", "0"},
             {"ua", "events", url_, "not-a-node"},
             {"ua", "events", url_, "--select", ","},
         }) {
        Result r = run(args);
        std::string cmd;
        for (const auto& a : args) cmd += " " + a;
        EXPECT_EQ(r.exitCode, 2) << "pnp" << cmd << "\n" << describe(r);
        EXPECT_FALSE(r.err.empty()) << "pnp" << cmd << ": no message on stderr";
    }
}

TEST_F(CliTest, HelpIsReadable) {
    Result r = run({"--help"});
    EXPECT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("ua"), std::string::npos) << r.out;
    r = run({"ua", "--help"});
    EXPECT_EQ(r.exitCode, 0) << describe(r);
    for (const char* sub :
         {"serve", "endpoints", "browse", "read", "write", "call", "monitor", "events"})
        EXPECT_NE(r.out.find(sub), std::string::npos) << sub << "\n" << r.out;
    r = run({"ua", "write", "--help"});
    EXPECT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("--type"), std::string::npos) << r.out;
}

TEST_F(CliTest, UserIdentity) {
    Result r = run({"ua", "read", url_, "i=2259", "--user", "operator:secret"});
    EXPECT_EQ(r.exitCode, 0) << describe(r);
    r = run({"ua", "read", url_, "i=2259", "--user", "operator:wrong", "--json"});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_NE(r.err.find("BadUserAccessDenied"), std::string::npos) << describe(r);
    EXPECT_EQ(parseJson(r)["error"]["status"], "BadUserAccessDenied") << r.out;
}

TEST_F(CliTest, NoServerIsAnOpcUaError) {
    Result r = run({"ua", "read", "opc.tcp://127.0.0.1:" + std::to_string(freePort()), "i=2259",
                    "--timeout", "2000"});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_NE(r.err.find("Bad"), std::string::npos) << describe(r);
}

// Demo.Sleep completes on a worker thread: while it waits the server keeps answering.
TEST_F(CliTest, SleepDoesNotBlockTheNetworkThread) {
    const auto t0 = Clock::now();
    // A 5 s Sleep: a read blocked behind it would take more than 3.5 s; one answered at once
    // takes a process start and a secured connect (most of a second in a sanitizer build on a
    // loaded machine).
    Child sleeper(withBinary({"ua", "call", url_, demo("Demo"), demo("Demo.Sleep"), "5000"}));
    // Give the call time to be sent (process start + secured connect + Call).
    std::this_thread::sleep_for(milliseconds(1500));
    ASSERT_TRUE(sleeper.running()) << "Sleep call ended early";
    const auto r0 = Clock::now();
    Result read = run({"ua", "read", url_, "i=2258"});  // CurrentTime
    const auto readTime = std::chrono::duration_cast<milliseconds>(Clock::now() - r0);
    ASSERT_EQ(read.exitCode, 0) << describe(read);
    EXPECT_TRUE(sleeper.running()) << "the read should finish while Sleep is still pending";
    EXPECT_LT(readTime.count(), 3000) << "read took " << readTime.count() << " ms";

    Result s = sleeper.wait(milliseconds(20000));
    const auto total = std::chrono::duration_cast<milliseconds>(Clock::now() - t0);
    ASSERT_EQ(s.exitCode, 0) << describe(s);
    EXPECT_NE(s.out.find("Good"), std::string::npos) << s.out;
    EXPECT_GE(total.count(), 5000);
}

// The brief's scenario with a short sleep: several 200 ms sleeps run concurrently (one
// worker, a timer queue) and a read in between is answered at once.
TEST_F(CliTest, ConcurrentShortSleeps) {
    const auto t0 = Clock::now();
    std::vector<std::unique_ptr<Child>> sleepers;
    for (int i = 0; i < 3; ++i)
        sleepers.push_back(std::make_unique<Child>(
            withBinary({"ua", "call", url_, demo("Demo"), demo("Demo.Sleep"), "200"})));
    Result read = run({"ua", "read", url_, "i=2259"});
    EXPECT_EQ(read.exitCode, 0) << describe(read);
    for (auto& s : sleepers) {
        Result r = s->wait(milliseconds(15000));
        EXPECT_EQ(r.exitCode, 0) << describe(r);
    }
    const auto total = std::chrono::duration_cast<milliseconds>(Clock::now() - t0);
    // Serialised sleeps would take >= 600 ms plus process start-up.
    EXPECT_LT(total.count(), 5000);
}

TEST_F(CliTest, SleepLimits) {
    Result r = run({"ua", "call", url_, demo("Demo"), demo("Demo.Sleep"), "600000"});
    EXPECT_EQ(r.exitCode, 1) << describe(r);
    EXPECT_NE(r.out.find("BadOutOfRange"), std::string::npos) << describe(r);
}

TEST(CliServe, StopsCleanlyOnSigint) {
    const int port = freePort();
    Child c(withBinary({"ua", "serve", "--host", "127.0.0.1", "--port", std::to_string(port)}));
    ASSERT_TRUE(c.waitForLine("listening on", milliseconds(10000))) << c.err;
    kill(c.pid(), SIGINT);
    Result r = c.wait(milliseconds(10000));
    EXPECT_EQ(r.exitCode, 0) << describe(r);
}

TEST(CliServe, PortInUseIsAnError) {
    const int port = freePort();
    Child first(withBinary({"ua", "serve", "--host", "127.0.0.1", "--port", std::to_string(port)}));
    ASSERT_TRUE(first.waitForLine("listening on", milliseconds(10000))) << first.err;
    Result second = run({"ua", "serve", "--host", "127.0.0.1", "--port", std::to_string(port)},
                        milliseconds(10000));
    EXPECT_EQ(second.exitCode, 1) << describe(second);
    EXPECT_EQ(first.terminate(), 0);
}

// ---- discovery: pnp lds, pnp ua serve --lds, pnp discover (loopback: no multicast) -------
TEST(CliDiscovery, ServerRegistersWithTheLdsAndDiscoverListsItUntilItStops) {
    const int ldsPort = freePort();
    Child lds(withBinary({"lds", "--host", "127.0.0.1", "--port", std::to_string(ldsPort)}));
    ASSERT_TRUE(lds.waitForLine("listening on", milliseconds(10000))) << lds.err;
    const std::string ldsUrl = "opc.tcp://127.0.0.1:" + std::to_string(ldsPort);
    const int port = freePort();
    auto server = std::make_unique<Child>(
        withBinary({"ua", "serve", "--host", "127.0.0.1", "--port", std::to_string(port), "--lds",
                    ldsUrl, "--name", "robot-7"}));
    ASSERT_TRUE(server->waitForLine("listening on", milliseconds(10000))) << server->err;
    const std::string url = "opc.tcp://127.0.0.1:" + std::to_string(port);

    auto find = [&](const json& list) -> const json* {
        for (const auto& s : list)
            if (s.value("url", "") == url) return &s;
        return nullptr;
    };
    json list;
    const json* robot = nullptr;
    for (int i = 0; i < 10 && !robot; ++i) {  // bounded: registration within ~1 s
        auto r = run(
            {"discover", "--once", "--json", "--no-mdns", "--lds", ldsUrl, "--duration", "600"});
        ASSERT_EQ(r.exitCode, 0) << describe(r);
        list = parseJson(r);
        robot = find(list);
    }
    ASSERT_TRUE(robot) << list.dump(2);
    EXPECT_EQ(robot->value("name", ""), "robot-7");
    EXPECT_EQ(robot->value("applicationUri", ""), "urn:pnp:127.0.0.1:" + std::to_string(port));
    EXPECT_GE(robot->at("endpoints").size(), 1u);
    bool ldsListed = false;  // the LDS lists itself, with the LDS capability
    for (const auto& s : list)
        if (s.value("url", "") == ldsUrl)
            for (const auto& c : s.at("capabilities")) ldsListed |= c == "LDS";
    EXPECT_TRUE(ldsListed) << list.dump(2);

    // A graceful stop unregisters at once.
    server->terminate();
    server.reset();
    auto r =
        run({"discover", "--once", "--json", "--no-mdns", "--lds", ldsUrl, "--duration", "600"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_EQ(find(parseJson(r)), nullptr) << r.out;
    lds.terminate();
}

TEST(CliDiscovery, ARestartedLdsGetsTheRegistrationBackWithinAnInterval) {
    const int ldsPort = freePort();
    const std::vector<std::string> ldsArgs{"lds", "--host", "127.0.0.1", "--port",
                                           std::to_string(ldsPort)};
    auto lds = std::make_unique<Child>(withBinary(ldsArgs));
    ASSERT_TRUE(lds->waitForLine("listening on", milliseconds(10000))) << lds->err;
    const std::string ldsUrl = "opc.tcp://127.0.0.1:" + std::to_string(ldsPort);
    const int port = freePort();
    Child server(withBinary({"ua", "serve", "--host", "127.0.0.1", "--port", std::to_string(port),
                             "--lds", ldsUrl, "--register-interval", "300"}));
    ASSERT_TRUE(server.waitForLine("listening on", milliseconds(10000))) << server.err;
    const std::string url = "opc.tcp://127.0.0.1:" + std::to_string(port);
    auto listed = [&] {
        auto r = run({"discover", "--once", "--json", "--no-mdns", "--no-details", "--lds", ldsUrl,
                      "--duration", "400"});
        if (r.exitCode != 0) return false;
        for (const auto& s : parseJson(r))
            if (s.value("url", "") == url) return true;
        return false;
    };
    bool before = false;
    for (int i = 0; i < 10 && !before; ++i) before = listed();
    ASSERT_TRUE(before);
    lds->terminate();  // the LDS restarts: it knows nothing
    lds = std::make_unique<Child>(withBinary(ldsArgs));
    ASSERT_TRUE(lds->waitForLine("listening on", milliseconds(10000))) << lds->err;
    const auto t0 = Clock::now();
    bool after = false;
    for (int i = 0; i < 10 && !after; ++i) after = listed();
    EXPECT_TRUE(after) << "not registered again";
    EXPECT_LT(Clock::now() - t0, milliseconds(3000));
    server.terminate();
    lds->terminate();
}

// ---- skills: pnp demo-skills, pnp skills, pnp skill run --------------------------------------
TEST(CliSkills, SkillsListsTheDemoSkillsAndSkillRunRunsThem) {
    const int port = freePort();
    Child server(withBinary(
        {"demo-skills", "--host", "127.0.0.1", "--port", std::to_string(port), "--no-register"}));
    ASSERT_TRUE(server.waitForLine("listening on", milliseconds(10000))) << server.err;
    const std::string url = "opc.tcp://127.0.0.1:" + std::to_string(port);

    auto r = run({"skills", "--once", "--json", "--no-mdns", "--url", url, "--duration", "1500"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    std::set<std::string> types;
    for (const auto& s : parseJson(r)) {
        types.insert(s.value("type", ""));
        EXPECT_EQ(s.value("url", ""), url);
        EXPECT_EQ(s.value("component", ""), "DemoGripper");
        EXPECT_EQ(s.at("typeChain").back(), "SkillType");
    }
    EXPECT_EQ(types, (std::set<std::string>{"DelaySkillType", "GraspGripperSkillType",
                                            "ReleaseGripperSkillType", "MoveGripperSkillType"}))
        << r.out;
    // --type keeps subtypes of the type only.
    r = run({"skills", "--once", "--json", "--no-mdns", "--url", url, "--duration", "1500",
             "--type", "GripperSkillType"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_EQ(parseJson(r).size(), 3u) << r.out;

    // A run prints its transitions and its result.
    r = run({"skill", "run", url, "--skill", "MoveGripper", "Width=0.02", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    EXPECT_EQ(j.value("result", ""), "Completed");
    ASSERT_GE(j.at("transitions").size(), 2u) << r.out;
    EXPECT_EQ(j.at("transitions")[0].value("to", ""), "Running");
    EXPECT_EQ(j.at("transitions").back().value("to", ""), "Ready");

    // Failed -> exit 3 with the reason; the next run resets the skill first.
    r = run({"skill", "run", url, "--skill", "Delay", "DurationMs=5", "FailWith=jammed"});
    EXPECT_EQ(r.exitCode, 3) << describe(r);
    EXPECT_NE(r.out.find("Failed: jammed"), std::string::npos) << r.out;
    r = run({"skill", "run", url, "--skill", "Delay", "DurationMs=1", "FailWith="});
    EXPECT_EQ(r.exitCode, 0) << describe(r);
    EXPECT_NE(r.out.find("Completed"), std::string::npos) << r.out;
    // --repeat: runs in a row on one connection, a summary of the results and durations.
    r = run({"skill", "run", url, "--skill", "Delay", "DurationMs=0", "--repeat", "50", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    j = parseJson(r);
    EXPECT_EQ(j.value("runs", 0), 50);
    EXPECT_EQ(j.at("results").value("Completed", 0), 50) << r.out;
    EXPECT_GT(j.at("durationMs").value("median", 0.0), 0.0) << r.out;
    EXPECT_GE(j.at("durationMs").value("max", 0.0), j.at("durationMs").value("median", 0.0));
    r = run({"skill", "run", url, "--skill", "Delay", "DurationMs=1", "FailWith=jammed", "--repeat",
             "3"});
    EXPECT_EQ(r.exitCode, 3) << describe(r);
    EXPECT_NE(r.out.find("3 runs: 3 Failed"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("first problem: run 1: Failed: jammed"), std::string::npos) << r.out;
    r = run({"skill", "run", url, "--skill", "Delay", "DurationMs=1", "FailWith="});
    EXPECT_EQ(r.exitCode, 0) << describe(r);
    // Past the deadline: halted, exit 3. (The deadline also covers connecting, locking and
    // starting: 1.5 s leaves room for a sanitizer build on a loaded machine, where 300 ms ran
    // out before the skill started.)
    r = run({"skill", "run", url, "--skill", "Delay", "DurationMs=10000", "--timeout", "1500"});
    EXPECT_EQ(r.exitCode, 3) << describe(r);
    EXPECT_NE(r.out.find("TimedOut"), std::string::npos) << r.out;
    // Ctrl-C during a run halts the skill and unlocks it: exit 3, and the next run works.
    {
        Child interrupted(
            withBinary({"skill", "run", url, "--skill", "Delay", "DurationMs=10000"}));
        ASSERT_TRUE(interrupted.waitForLine("running ", milliseconds(10000))) << interrupted.err;
        std::this_thread::sleep_for(milliseconds(300));  // locked and started
        kill(interrupted.pid(), SIGINT);
        const auto t0 = Clock::now();
        Result i = interrupted.wait(milliseconds(10000));
        EXPECT_EQ(i.exitCode, 3) << describe(i);
        EXPECT_NE(i.out.find("Aborted"), std::string::npos) << i.out;
        EXPECT_LT(std::chrono::duration_cast<milliseconds>(Clock::now() - t0).count(), 5000);
    }
    r = run({"skill", "run", url, "--skill", "Delay", "DurationMs=1", "FailWith="});
    EXPECT_EQ(r.exitCode, 0) << describe(r);
    // Usage errors: a value of the wrong type, an unknown parameter, several skills without
    // --skill, an unknown type.
    EXPECT_EQ(run({"skill", "run", url, "--skill", "MoveGripper", "Width=wide"}).exitCode, 2);
    EXPECT_EQ(run({"skill", "run", url, "--skill", "MoveGripper", "Speed=1"}).exitCode, 2);
    EXPECT_EQ(run({"skill", "run", url, "DurationMs=1"}).exitCode, 2);
    EXPECT_EQ(run({"skill", "run", "NoSuchSkillType", "--no-mdns", "--lds", url}).exitCode, 2);
    server.terminate();
}

TEST(CliSkills, SkillRunFindsASkillByTypeThroughTheLds) {
    const int ldsPort = freePort();
    Child lds(withBinary({"lds", "--host", "127.0.0.1", "--port", std::to_string(ldsPort)}));
    ASSERT_TRUE(lds.waitForLine("listening on", milliseconds(10000))) << lds.err;
    const std::string ldsUrl = "opc.tcp://127.0.0.1:" + std::to_string(ldsPort);
    const int port = freePort();
    Child server(withBinary(
        {"demo-skills", "--host", "127.0.0.1", "--port", std::to_string(port), "--lds", ldsUrl}));
    ASSERT_TRUE(server.waitForLine("listening on", milliseconds(10000))) << server.err;
    auto r = run({"skill", "run", "ReleaseGripperSkillType", "--no-mdns", "--lds", ldsUrl,
                  "--discover", "5000", "--json"});
    ASSERT_EQ(r.exitCode, 0) << describe(r);
    json j = parseJson(r);
    EXPECT_EQ(j.value("name", ""), "Release");
    EXPECT_EQ(j.value("result", ""), "Completed");
    server.terminate();
    lds.terminate();
}

TEST(CliDiscovery, UsageErrors) {
    EXPECT_EQ(run({"discover", "--no-mdns"}).exitCode, 2);
    EXPECT_EQ(run({"discover", "--poll", "1"}).exitCode, 2);
    EXPECT_EQ(run({"lds", "--discovery-level", "101"}).exitCode, 2);
    EXPECT_EQ(run({"ua", "serve", "--register-interval", "0"}).exitCode, 2);
}

// `pnp bench report DIR` renders report.md from a results directory (a copy of the middleware
// report test's hand-made one) without running anything; a directory without summary.json is
// an error with a message.
TEST(CliBench, ReportRendersAResultsDirectoryAgain) {
    const std::filesystem::path dir =
        std::filesystem::temp_directory_path() / ("pnp-cli-report-" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir);
    std::filesystem::copy(PNP_MW_RESULTS, dir, std::filesystem::copy_options::recursive);
    Result r = run({"bench", "report", dir.string(), "--no-plots"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("report.md"), std::string::npos) << r.err;
    std::ifstream in(dir / "report.md");
    std::stringstream text;
    text << in.rdbuf();
    EXPECT_NE(text.str().find("# Middleware evaluation"), std::string::npos);
    std::filesystem::remove_all(dir);
    Result missing = run({"bench", "report", (dir / "nothing").string()});
    EXPECT_NE(missing.exitCode, 0);
    EXPECT_FALSE(missing.err.empty());
}

}  // namespace
