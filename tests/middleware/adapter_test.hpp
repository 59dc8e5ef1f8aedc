// Shared by the adapter tests: run an adapter's client to its end (bounded) and collect its
// stdout lines and exit code; start its server / chain nodes as child processes.
#pragma once

#include <sys/wait.h>

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

}  // namespace pnp::testing
