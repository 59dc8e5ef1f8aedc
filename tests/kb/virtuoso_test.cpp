// The query suite (kb_suite_test.cpp) against a real SPARQL server: Debian's Virtuoso 7,
// started here on loopback ports with its database in a temporary directory, and stopped by
// PID at the end. Virtuoso not starting is a failure, never a skip: CI installs it.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <sstream>
#include <thread>

#include "kb_suite.hpp"

namespace pnp::kb::test {
namespace {

using namespace std::chrono_literals;

int freeLoopbackPort() {
    int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    addr.sin_port = 0;
    socklen_t len = sizeof addr;
    int port = -1;
    if (fd >= 0 && ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0 &&
        ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0) {
        port = ntohs(addr.sin_port);
    }
    if (fd >= 0) ::close(fd);
    return port;
}

std::string tail(const std::filesystem::path& file, std::size_t bytes = 2000) {
    std::ifstream in(file);
    std::stringstream s;
    s << in.rdbuf();
    std::string text = s.str();
    return text.size() > bytes ? text.substr(text.size() - bytes) : text;
}

// Runs `argv` with output to `log`; its exit status, or -1 after `timeout` (then it is killed).
int runFor(const std::vector<std::string>& argv, const std::filesystem::path& log,
           std::chrono::seconds timeout) {
    pid_t pid = ::fork();
    if (pid == 0) {
        int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
        if (fd >= 0) {
            ::dup2(fd, 1);
            ::dup2(fd, 2);
        }
        std::vector<char*> args;
        for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
        args.push_back(nullptr);
        ::execv(args[0], args.data());
        ::_exit(127);
    }
    if (pid < 0) return -1;
    auto end = std::chrono::steady_clock::now() + timeout;
    int status = 0;
    while (std::chrono::steady_clock::now() < end) {
        if (::waitpid(pid, &status, WNOHANG) == pid)
            return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
        std::this_thread::sleep_for(50ms);
    }
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
    return -1;
}

class VirtuosoServer : public ::testing::Environment {
  public:
    static inline std::string url;

    void SetUp() override {
        const std::string exe = PNP_VIRTUOSO_EXE, isql = PNP_ISQL_EXE;
        ASSERT_FALSE(exe.empty() || exe.ends_with("NOTFOUND"))
            << "virtuoso-t not found: install virtuoso-opensource (scripts/setup.sh)";
        ASSERT_FALSE(isql.empty() || isql.ends_with("NOTFOUND"))
            << "isql-vt not found: install virtuoso-opensource (scripts/setup.sh)";
        char dirTemplate[] = "/tmp/pnp-kb-virtuoso-XXXXXX";
        ASSERT_NE(::mkdtemp(dirTemplate), nullptr);
        dir_ = dirTemplate;
        sqlPort_ = freeLoopbackPort();
        int httpPort = freeLoopbackPort();
        ASSERT_GT(sqlPort_, 0);
        ASSERT_GT(httpPort, 0);
        writeIni(httpPort);
        url = "http://127.0.0.1:" + std::to_string(httpPort) + "/sparql";

        pid_ = ::fork();
        ASSERT_GE(pid_, 0);
        if (pid_ == 0) {
            int fd = ::open((dir_ / "server.log").c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
            if (fd >= 0) {
                ::dup2(fd, 1);
                ::dup2(fd, 2);
            }
            if (::chdir(dir_.c_str()) != 0) ::_exit(126);
            std::string ini = (dir_ / "virtuoso.ini").string();
            ::execl(exe.c_str(), exe.c_str(), "+foreground", "+configfile", ini.c_str(), nullptr);
            ::_exit(127);
        }
        // Up when its SPARQL endpoint answers (creating a new database takes ~15 s).
        auto kb = open(url);
        auto end = std::chrono::steady_clock::now() + 50s;
        std::string lastError;
        bool up = false;
        while (!up && std::chrono::steady_clock::now() < end) {
            int status = 0;
            if (::waitpid(pid_, &status, WNOHANG) == pid_) {
                pid_ = -1;
                FAIL() << "virtuoso-t exited during start-up:\n" << tail(dir_ / "server.log");
            }
            try {
                up = kb->ask("ASK { }", std::chrono::steady_clock::now() + 1s) || true;
            } catch (const KbError& e) {
                lastError = e.what();
                std::this_thread::sleep_for(200ms);
            }
        }
        ASSERT_TRUE(up) << "virtuoso did not answer at " << url << " within 50 s (" << lastError
                        << "):\n"
                        << tail(dir_ / "server.log");
        // The anonymous SPARQL user may read only: grant it SPARQL Update.
        int rc = runFor({isql, std::to_string(sqlPort_), "dba", "dba",
                         "exec=GRANT SPARQL_UPDATE TO \"SPARQL\";"},
                        dir_ / "isql.log", 20s);
        ASSERT_EQ(rc, 0) << "isql-vt GRANT failed:\n" << tail(dir_ / "isql.log");
    }

    void TearDown() override {
        if (pid_ > 0) {
            ::kill(pid_, SIGTERM);
            int status = 0;
            auto end = std::chrono::steady_clock::now() + 15s;
            bool gone = false;
            while (!gone && std::chrono::steady_clock::now() < end) {
                gone = ::waitpid(pid_, &status, WNOHANG) == pid_;
                if (!gone) std::this_thread::sleep_for(50ms);
            }
            if (!gone) {
                ::kill(pid_, SIGKILL);
                ::waitpid(pid_, &status, 0);
            }
            pid_ = -1;
        }
        if (!dir_.empty()) {
            std::error_code ec;
            std::filesystem::remove_all(dir_, ec);
        }
    }

  private:
    void writeIni(int httpPort) {
        const std::string d = dir_.string();
        std::ofstream ini(dir_ / "virtuoso.ini");
        ini << "[Database]\n"
            << "DatabaseFile = " << d << "/virtuoso.db\n"
            << "ErrorLogFile = " << d << "/virtuoso.log\n"
            << "LockFile = " << d << "/virtuoso.lck\n"
            << "TransactionFile = " << d << "/virtuoso.trx\n"
            << "xa_persistent_file = " << d << "/virtuoso.pxa\n"
            << "Striping = 0\nTempStorage = TempDatabase\n"
            << "[TempDatabase]\n"
            << "DatabaseFile = " << d << "/virtuoso-temp.db\n"
            << "TransactionFile = " << d << "/virtuoso-temp.trx\n"
            << "Striping = 0\n"
            << "[Parameters]\n"
            << "ServerPort = 127.0.0.1:" << sqlPort_ << "\n"
            << "DisableUnixSocket = 1\nCheckpointInterval = 0\n"
            << "NumberOfBuffers = 2000\nMaxDirtyBuffers = 1200\nThreadsPerQuery = 1\n"
            << "DirsAllowed = .\n"
            << "[HTTPServer]\n"
            << "ServerPort = 127.0.0.1:" << httpPort << "\n"
            << "ServerRoot = " << d << "\n"
            << "ServerThreads = 4\nMaxClientConnections = 4\n"
            << "[SPARQL]\n"
            << "ResultSetMaxRows = 100000\nMaxQueryExecutionTime = 30\n";
    }

    std::filesystem::path dir_;
    int sqlPort_ = -1;
    pid_t pid_ = -1;
};

}  // namespace

std::unique_ptr<KnowledgeBase> openBackend(const std::string& name) {
    EXPECT_EQ(name, "virtuoso");
    return open(VirtuosoServer::url);
}

}  // namespace pnp::kb::test

int main(int argc, char** argv) {
    ::testing::InitGoogleTest(&argc, argv);
    ::testing::AddGlobalTestEnvironment(new pnp::kb::test::VirtuosoServer);
    return RUN_ALL_TESTS();
}
