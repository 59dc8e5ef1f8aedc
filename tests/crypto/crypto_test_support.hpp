// Helpers of the pnp_ua_crypto tests: hex, RSA keys generated once per test program, a
// temporary directory removed afterwards, and the `openssl` command line run as a child
// process with a deadline (stopped by its PID when it overruns).
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "ua/crypto/crypto.hpp"

namespace pnp::ua::crypto::testing {

inline Bytes hex(std::string_view text) {
    Bytes out;
    int high = -1;
    for (char c : text) {
        int v;
        if (c >= '0' && c <= '9')
            v = c - '0';
        else if (c >= 'a' && c <= 'f')
            v = c - 'a' + 10;
        else if (c >= 'A' && c <= 'F')
            v = c - 'A' + 10;
        else
            continue;  // spaces between bytes
        if (high < 0) {
            high = v;
        } else {
            out.push_back(static_cast<std::uint8_t>(high << 4 | v));
            high = -1;
        }
    }
    if (high >= 0) throw std::invalid_argument("odd number of hex digits");
    return out;
}

inline std::string toHex(ByteView bytes) {
    static const char* digits = "0123456789abcdef";
    std::string s;
    for (auto b : bytes) {
        s += digits[b >> 4];
        s += digits[b & 15];
    }
    return s;
}

// RSA keys are slow to generate (4096 bits: seconds): one per size per test program.
inline const PrivateKey& testKey(int bits) {
    static std::mutex mutex;
    static std::map<int, PrivateKey> keys;
    std::lock_guard lock(mutex);
    auto it = keys.find(bits);
    if (it == keys.end()) it = keys.emplace(bits, PrivateKey::generateRsa(bits)).first;
    return it->second;
}

// A fresh directory under $TMPDIR (or /tmp), removed with everything in it.
class TempDir {
  public:
    TempDir() {
        const char* base = std::getenv("TMPDIR");
        std::string pattern = std::string(base && *base ? base : "/tmp") + "/pnp-crypto-XXXXXX";
        std::vector<char> buf(pattern.begin(), pattern.end());
        buf.push_back('\0');
        if (!::mkdtemp(buf.data())) throw std::runtime_error("mkdtemp failed");
        path_ = buf.data();
    }
    ~TempDir() {
        std::error_code ec;
        std::filesystem::remove_all(path_, ec);
    }
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;

    std::string file(const std::string& name) const { return (path_ / name).string(); }

    void write(const std::string& name, ByteView bytes) const {
        std::ofstream f(file(name), std::ios::binary);
        f.write(reinterpret_cast<const char*>(bytes.data()),
                static_cast<std::streamsize>(bytes.size()));
        if (!f) throw std::runtime_error("cannot write " + name);
    }
    void write(const std::string& name, std::string_view text) const { write(name, view(text)); }
    Bytes read(const std::string& name) const {
        std::ifstream f(file(name), std::ios::binary);
        if (!f) throw std::runtime_error("cannot read " + name);
        return Bytes(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
    }
    std::string readText(const std::string& name) const {
        Bytes b = read(name);
        return std::string(b.begin(), b.end());
    }

  private:
    std::filesystem::path path_;
};

// The `openssl` executable, or "" when it is not installed.
inline std::string opensslPath() {
    const char* path = std::getenv("PATH");
    std::stringstream dirs(path ? path : "/usr/bin:/bin");
    std::string dir;
    while (std::getline(dirs, dir, ':')) {
        if (dir.empty()) continue;
        std::string p = dir + "/openssl";
        if (::access(p.c_str(), X_OK) == 0) return p;
    }
    return {};
}

struct RunResult {
    int exitCode = -1;   // -1: did not exit by itself (killed at the deadline) or not started
    std::string output;  // stdout + stderr
};

// Runs argv (argv[0] a full path) in `dir`, stdout and stderr into one log, and waits at most
// `deadline`; an overrunning child is killed by its PID and reaped.
inline RunResult run(const std::vector<std::string>& argv, const TempDir& dir,
                     std::chrono::milliseconds deadline = std::chrono::seconds(60)) {
    RunResult result;
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const std::string log = dir.file("command.log");
    const pid_t pid = ::fork();
    if (pid < 0) {
        result.output = "fork failed";
        return result;
    }
    if (pid == 0) {
        // Child: async-signal-safe calls only until exec.
        int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
        if (fd >= 0) {
            ::dup2(fd, STDOUT_FILENO);
            ::dup2(fd, STDERR_FILENO);
        }
        int devnull = ::open("/dev/null", O_RDONLY);
        if (devnull >= 0) ::dup2(devnull, STDIN_FILENO);
        ::execv(args[0], args.data());
        ::_exit(127);
    }
    const auto end = std::chrono::steady_clock::now() + deadline;
    int status = 0;
    bool exited = false;
    while (std::chrono::steady_clock::now() < end) {
        const pid_t r = ::waitpid(pid, &status, WNOHANG);
        if (r == pid) {
            exited = true;
            break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    if (!exited) {
        ::kill(pid, SIGKILL);
        ::waitpid(pid, &status, 0);
        result.output = "killed after the deadline\n";
    } else if (WIFEXITED(status)) {
        result.exitCode = WEXITSTATUS(status);
    }
    std::ifstream f(log);
    result.output +=
        std::string(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
    return result;
}

}  // namespace pnp::ua::crypto::testing
