// The processes the runner starts (adapters, broker, master, load generators, capture): each
// in a process group of its own (stopped as a group by its PID, so that a middleware's forked
// children go too), optionally inside a network namespace and pinned to a CPU, killed by the
// kernel if the runner dies (PR_SET_PDEATHSIG), stderr into a log file.
#pragma once

#include <sys/types.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace pnp::bench::runner {

// Set by the runner's SIGINT / SIGTERM handler; every wait below gives up when it is set.
std::atomic<bool>& stopRequested();

struct Interrupted : std::runtime_error {
    Interrupted() : std::runtime_error("interrupted (SIGINT / SIGTERM)") {}
};
// Throws Interrupted once a stop was requested.
void checkStop();

struct Spawn {
    std::vector<std::string> argv;  // argv[0]: a full path
    std::string log;                // stderr; also stdout unless captureStdout
    bool captureStdout = true;      // stdout through a pipe (lines(), waitForLine())
    std::string netns;              // enter /var/run/netns/NAME before exec
    int cpu = -1;                   // pin (sched_setaffinity) before exec
    std::vector<std::string> env;   // KEY=VALUE added to the environment
};

class Process {
  public:
    // Throws std::runtime_error when fork / exec preparation fails (an exec failure shows as
    // exit code 127, or 126 when the netns cannot be entered).
    static std::unique_ptr<Process> start(const Spawn& spawn);
    Process(const Process&) = delete;
    Process& operator=(const Process&) = delete;
    ~Process();

    pid_t pid() const { return pid_; }
    const std::string& name() const { return name_; }

    // Reads stdout until a line starting with `prefix` arrives (true), the process exits or
    // the timeout passes (false, reason in *error).
    bool waitForLine(const std::string& prefix, std::chrono::milliseconds timeout,
                     std::string& error);
    // Reads what stdout has now (non-blocking) into lines().
    void pump();
    const std::vector<std::string>& lines() const { return lines_; }

    // Has the process exited? Non-blocking; the status is kept (exitCode()).
    bool exited();
    // Exit code, or 128 + signal; -1 while running.
    int exitCode() const { return exitCode_; }
    // Exited but not reaped yet (its /proc entry still readable): for a last sample.
    bool exitedUnreaped();

    // SIGTERM to the process group, up to `grace`, then SIGKILL to the group; reaps.
    // Idempotent.
    void stop(std::chrono::milliseconds grace = std::chrono::milliseconds(5000));

    // The last `max` bytes of the log.
    std::string logTail(std::size_t max = 2000) const;

  private:
    Process() = default;
    void reap(int status);

    pid_t pid_ = -1;
    bool reaped_ = false;
    int out_ = -1;
    int exitCode_ = -1;
    std::string name_;
    std::string log_;
    std::string partial_;
    std::vector<std::string> lines_;
};

// Runs a command to its end (bounded), its stdout and stderr into `log` (appended); returns
// the exit code (or 128 + signal, or -1 on timeout, after killing it).
int runCommand(const std::vector<std::string>& argv, const std::string& log,
               std::chrono::milliseconds timeout = std::chrono::seconds(30),
               const std::string& netns = {});
// The same, its stdout returned in *out.
int runCommandOutput(const std::vector<std::string>& argv, std::string& out, const std::string& log,
                     std::chrono::milliseconds timeout = std::chrono::seconds(60),
                     const std::string& netns = {});

// The full path of an executable found in PATH (or the given absolute path if executable),
// or "".
std::string findExecutable(const std::string& name);

// Marker put into the environment of every process the runner starts (and so of their
// children): PNP_MW_RUNNER=<runner pid>. Tests look for leftovers by it.
std::string markerEnv();

}  // namespace pnp::bench::runner
