// Process supervision for the cell runner: each device, component and server of the cell is a
// child process (the same executables a user starts by hand). A child is started with an argv,
// its stderr goes to a log file and its stdout through a pipe (kept as lines for
// waitForPrefix(), copied to the same log); it is stopped by its PID, SIGTERM first and
// SIGKILL after a grace time. The Supervisor stops its children in reverse start order.
//
// No orphans: every child gets PR_SET_PDEATHSIG(SIGTERM), so a runner killed even with SIGKILL
// takes its children with it; PR_SET_PDEATHSIG fires when the *thread* that forked exits:
// start children from a thread that lives as long as the runner (the main thread). Each child
// runs in a process group of its own, so that a terminal's Ctrl-C reaches the runner only,
// which then stops the children in order (components before the devices, the bus last).
#pragma once

#include <sys/types.h>

#include <chrono>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace pnp::cell {

using Clock = std::chrono::steady_clock;

class ChildProcess {
  public:
    struct Line {
        Clock::time_point time;  // when the runner read it
        std::string text;
    };

    ChildProcess(std::string name, std::filesystem::path logFile);
    ~ChildProcess();  // stop()
    ChildProcess(const ChildProcess&) = delete;
    ChildProcess& operator=(const ChildProcess&) = delete;

    // Starts argv[0] (a full path). netns: enter /var/run/netns/NETNS first (root only).
    // Throws std::runtime_error when the process cannot be created.
    void start(const std::vector<std::string>& argv, const std::string& netns = {});

    // The first stdout line starting with `prefix` (from the start of the output); nullopt
    // when the deadline passes or the child exits first (error says which).
    std::optional<Line> waitForPrefix(const std::string& prefix, Clock::time_point deadline,
                                      std::string& error);

    // SIGTERM, then SIGKILL after `grace`; reaps. Idempotent.
    void stop(std::chrono::milliseconds grace = std::chrono::milliseconds(3000));

    bool running();  // not exited yet (reaps it when it has)
    bool stopRequested() const { return stopRequested_; }
    pid_t pid() const { return pid_; }
    const std::string& name() const { return name_; }
    // The command line it was started with (to start it again the same way).
    const std::vector<std::string>& argv() const { return argv_; }
    const std::filesystem::path& logFile() const { return logFile_; }
    Clock::time_point startTime() const { return started_; }
    // Exit status once reaped (waitpid's status), else nullopt.
    std::optional<int> exitStatus() const { return status_; }
    std::string describeExit() const;
    // The last `max` bytes of the log.
    std::string logTail(std::size_t max = 2000) const;

  private:
    void readStdout();

    std::string name_;
    std::filesystem::path logFile_;
    std::vector<std::string> argv_;
    pid_t pid_ = -1;
    int stdoutFd_ = -1;
    Clock::time_point started_{};
    std::optional<int> status_;
    bool stopRequested_ = false;
    std::thread reader_;
    std::mutex mutex_;
    std::condition_variable changed_;
    std::deque<Line> lines_;  // bounded: the first kMaxLines
    bool eof_ = false;
};

class Supervisor {
  public:
    explicit Supervisor(std::filesystem::path logDir);
    ~Supervisor();  // stopAll()
    Supervisor(const Supervisor&) = delete;
    Supervisor& operator=(const Supervisor&) = delete;

    // A new child named `name` (log: <logDir>/<name>.log), started now. The name must be
    // unique; a restarted device gets a new name (e.g. "robotiq-2").
    ChildProcess& start(const std::string& name, const std::vector<std::string>& argv,
                        const std::string& netns = {});
    ChildProcess* find(const std::string& name);
    // Children that exited on their own (not stopped by us), with their exit.
    std::vector<std::string> exitedUnexpectedly();
    // In reverse start order (the last plugged in first: components before the devices
    // they use, the cell bus last).
    void stopAll(std::chrono::milliseconds grace = std::chrono::milliseconds(3000));
    const std::filesystem::path& logDir() const { return logDir_; }
    std::vector<const ChildProcess*> children() const;

  private:
    std::filesystem::path logDir_;
    std::vector<std::unique_ptr<ChildProcess>> children_;
};

// This executable's path (/proc/self/exe).
std::filesystem::path selfExecutable();

}  // namespace pnp::cell
