// Shared by the adapter tests: run an adapter's client to its end (bounded) and collect its
// stdout lines and exit code; start its server / chain nodes as child processes.
#pragma once

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "support/child_process.hpp"

namespace pnp::testing {

struct ClientRun {
    int exitCode = -1;
    std::vector<std::string> lines;  // stdout
    std::string log;                 // stderr
};

// The stderr log of one test process's child WHAT: ctest runs tests side by side, each in its
// own process, so the path carries the process id.
inline std::string testLog(const std::string& what) {
    return "/tmp/test_mw_" + what + "_" + std::to_string(::getpid()) + ".log";
}

inline std::string quote(const std::string& s) {
    std::string q = "'";
    for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return q + "'";
}

// Runs `argv` under `timeout -s KILL SECONDS` (so a hung client cannot hang the test).
inline ClientRun runClient(const std::vector<std::string>& argv, int seconds,
                           const std::string& logPath) {
    std::string cmd = "timeout -s KILL " + std::to_string(seconds);
    for (const auto& a : argv) cmd += " " + quote(a);
    cmd += " 2>" + quote(logPath);
    ClientRun r;
    FILE* p = ::popen(cmd.c_str(), "r");
    if (!p) return r;
    std::array<char, 4096> buf{};
    std::string line;
    while (std::fgets(buf.data(), static_cast<int>(buf.size()), p)) {
        line += buf.data();
        if (!line.empty() && line.back() == '\n') {
            line.pop_back();
            r.lines.push_back(line);
            line.clear();
        }
    }
    const int st = ::pclose(p);
    r.exitCode = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
    std::ifstream in(logPath);
    std::stringstream ss;
    ss << in.rdbuf();
    r.log = ss.str();
    return r;
}

// Starts argv and waits (bounded) for its READY line; the reason when it does not come.
inline bool startReady(ChildProcess& p, const std::vector<std::string>& argv,
                       const std::string& logPath, int seconds, std::string& error) {
    return p.start(argv, logPath, error) &&
           p.waitForLine("READY", std::chrono::seconds(seconds), error);
}

// The small chain of a port-based adapter: 3 streams x 4 hops = 12 nodes in two `node`
// processes from a free base port, then a chain client of 10 runs. exitCode -1 and
// `error` when a node process did not get ready.
inline ClientRun runSmallChain(const std::string& exe, const std::string& name, int readySeconds,
                               std::string& error) {
    // Ports base .. base + 13: 12 nodes and the client's sink.
    const std::string base = std::to_string(freeLoopbackPortRange(14));
    ChildProcess nodes[2];
    for (int k = 0; k < 2; ++k)
        if (!startReady(nodes[k],
                        {exe, "node", "--port", base, "--first", std::to_string(k * 6), "--count",
                         "6", "--streams", "3", "--hops", "4"},
                        testLog(name + "_node" + std::to_string(k)), readySeconds, error))
            return {};
    return runClient({exe, "client", "--mode", "chain", "--port", base, "--streams", "3", "--hops",
                      "4", "--runs", "10"},
                     60, testLog(name + "_chain"));
}

}  // namespace pnp::testing
