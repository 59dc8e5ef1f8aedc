// What the process-level tests share: a temporary path per test process, and running a
// command line (bounded by the caller's `timeout -k ...`) for its exit status and stdout.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <string>

namespace pnp::testing {

// <TempDir>/pnp_<prefix>_<pid>_<name>.
inline std::string tmpPath(const std::string& prefix, const std::string& name) {
    return ::testing::TempDir() + "pnp_" + prefix + "_" + std::to_string(::getpid()) + "_" + name;
}

// Runs `command` with /bin/sh, appends its stdout to `out`; its exit status, -1 if it did not
// exit normally.
inline int runShell(const std::string& command, std::string& out) {
    FILE* p = ::popen(command.c_str(), "r");
    if (p == nullptr) return -1;
    char buf[4096];
    while (std::fgets(buf, sizeof buf, p)) out += buf;
    const int status = ::pclose(p);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace pnp::testing
