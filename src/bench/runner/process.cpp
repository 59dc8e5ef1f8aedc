#include "bench/runner/process.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <thread>

extern char** environ;

namespace pnp::bench::runner {

std::atomic<bool>& stopRequested() {
    static std::atomic<bool> flag{false};
    return flag;
}

void checkStop() {
    if (stopRequested().load()) throw Interrupted();
}

std::string markerEnv() { return "PNP_MW_RUNNER=" + std::to_string(::getpid()); }

std::string findExecutable(const std::string& name) {
    if (name.find('/') != std::string::npos) return ::access(name.c_str(), X_OK) == 0 ? name : "";
    const char* path = std::getenv("PATH");
    std::stringstream ss(path ? path : "/usr/local/bin:/usr/bin:/bin:/usr/sbin:/sbin");
    std::string dir;
    while (std::getline(ss, dir, ':')) {
        if (dir.empty()) continue;
        const std::string p = dir + "/" + name;
        if (::access(p.c_str(), X_OK) == 0) return p;
    }
    for (const char* dir : {"/usr/sbin", "/sbin"}) {
        const std::string p = std::string(dir) + "/" + name;
        if (::access(p.c_str(), X_OK) == 0) return p;
    }
    return {};
}

std::unique_ptr<Process> Process::start(const Spawn& s) {
    if (s.argv.empty()) throw std::runtime_error("no command");
    // Everything the child needs is prepared before fork: between fork and exec only
    // async-signal-safe calls.
    std::vector<char*> args;
    for (const auto& a : s.argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    std::vector<std::string> envStrings;
    for (char** e = environ; e && *e; ++e) {
        const std::string kv = *e;
        const std::string key = kv.substr(0, kv.find('='));
        bool overridden = key == "PNP_MW_RUNNER";
        for (const auto& add : s.env)
            if (add.substr(0, add.find('=')) == key) overridden = true;
        if (!overridden) envStrings.push_back(kv);
    }
    for (const auto& add : s.env) envStrings.push_back(add);
    envStrings.push_back(markerEnv());
    std::vector<char*> envp;
    for (auto& e : envStrings) envp.push_back(e.data());
    envp.push_back(nullptr);
    const std::string nsPath = s.netns.empty() ? std::string() : "/var/run/netns/" + s.netns;
    cpu_set_t cpus;
    CPU_ZERO(&cpus);
    if (s.cpu >= 0) CPU_SET(s.cpu, &cpus);

    int fds[2] = {-1, -1};
    if (s.captureStdout && ::pipe2(fds, O_CLOEXEC) != 0)
        throw std::runtime_error(std::string("pipe: ") + std::strerror(errno));
    const int log = ::open(s.log.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    if (log < 0) {
        if (fds[0] >= 0) ::close(fds[0]), ::close(fds[1]);
        throw std::runtime_error("cannot write " + s.log + ": " + std::strerror(errno));
    }
    const pid_t parent = ::getpid();
    const pid_t pid = ::fork();
    if (pid < 0) {
        ::close(log);
        if (fds[0] >= 0) ::close(fds[0]), ::close(fds[1]);
        throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
    }
    if (pid == 0) {
        ::setpgid(0, 0);
        ::prctl(PR_SET_PDEATHSIG, SIGKILL);
        if (::getppid() != parent) ::_exit(127);
        sigset_t none;
        sigemptyset(&none);
        ::sigprocmask(SIG_SETMASK, &none, nullptr);
        ::signal(SIGINT, SIG_DFL);
        ::signal(SIGTERM, SIG_DFL);
        ::signal(SIGPIPE, SIG_DFL);
        if (!nsPath.empty()) {
            const int ns = ::open(nsPath.c_str(), O_RDONLY | O_CLOEXEC);
            if (ns < 0 || ::setns(ns, CLONE_NEWNET) != 0) ::_exit(126);
        }
        if (s.cpu >= 0 && ::sched_setaffinity(0, sizeof cpus, &cpus) != 0) ::_exit(125);
        ::dup2(s.captureStdout ? fds[1] : log, STDOUT_FILENO);
        ::dup2(log, STDERR_FILENO);
        const int devnull = ::open("/dev/null", O_RDONLY);
        if (devnull >= 0) ::dup2(devnull, STDIN_FILENO);
        ::execve(args[0], args.data(), envp.data());
        ::_exit(127);
    }
    ::setpgid(pid, pid);  // also here: no race with a stop() right after start()
    ::close(log);
    std::unique_ptr<Process> p(new Process());
    p->pid_ = pid;
    p->log_ = s.log;
    const auto slash = s.argv[0].rfind('/');
    p->name_ = slash == std::string::npos ? s.argv[0] : s.argv[0].substr(slash + 1);
    if (s.captureStdout) {
        ::close(fds[1]);
        p->out_ = fds[0];
        ::fcntl(p->out_, F_SETFL, ::fcntl(p->out_, F_GETFL) | O_NONBLOCK);
    }
    return p;
}

Process::~Process() { stop(); }

void Process::pump() {
    if (out_ < 0) return;
    char buf[4096];
    for (;;) {
        const ssize_t r = ::read(out_, buf, sizeof buf);
        if (r <= 0) break;
        partial_.append(buf, static_cast<std::size_t>(r));
        if (partial_.size() > (16u << 20)) partial_.clear();  // bounded: not our protocol
    }
    std::size_t nl;
    while ((nl = partial_.find('\n')) != std::string::npos) {
        std::string l = partial_.substr(0, nl);
        partial_.erase(0, nl + 1);
        if (!l.empty() && l.back() == '\r') l.pop_back();
        if (lines_.size() < 100000) lines_.push_back(std::move(l));
    }
}

bool Process::waitForLine(const std::string& prefix, std::chrono::milliseconds timeout,
                          std::string& error) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    std::size_t seen = 0;
    for (;;) {
        pump();
        for (; seen < lines_.size(); ++seen)
            if (lines_[seen].rfind(prefix, 0) == 0) return true;
        if (exited()) {
            pump();
            for (; seen < lines_.size(); ++seen)
                if (lines_[seen].rfind(prefix, 0) == 0) return true;
            error = name_ + " exited (code " + std::to_string(exitCode_) + ") before \"" + prefix +
                    "\": " + logTail(600);
            return false;
        }
        if (std::chrono::steady_clock::now() >= end) {
            error = name_ + " printed no \"" + prefix + "\" within " +
                    std::to_string(timeout.count()) + " ms: " + logTail(600);
            return false;
        }
        if (stopRequested()) {
            error = "interrupted";
            return false;
        }
        if (out_ >= 0) {
            pollfd p{out_, POLLIN, 0};
            ::poll(&p, 1, 50);
        } else {
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
    }
}

void Process::reap(int status) {
    reaped_ = true;
    exitCode_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

bool Process::exited() {
    if (reaped_) return true;
    if (pid_ <= 0) return true;
    int status = 0;
    const pid_t r = ::waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
        reap(status);
        return true;
    }
    if (r < 0) {
        reaped_ = true;
        return true;
    }
    return false;
}

bool Process::exitedUnreaped() {
    if (reaped_ || pid_ <= 0) return reaped_;
    siginfo_t info{};
    if (::waitid(P_PID, static_cast<id_t>(pid_), &info, WEXITED | WNOHANG | WNOWAIT) != 0)
        return false;
    return info.si_pid == pid_;
}

void Process::stop(std::chrono::milliseconds grace) {
    if (pid_ > 0) {
        if (!exited()) {
            ::kill(-pid_, SIGTERM);
            ::kill(pid_, SIGTERM);
            const auto end = std::chrono::steady_clock::now() + grace;
            while (!exited() && std::chrono::steady_clock::now() < end)
                std::this_thread::sleep_for(std::chrono::milliseconds(10));
            if (!exited()) {
                ::kill(-pid_, SIGKILL);
                int status = 0;
                if (::waitpid(pid_, &status, 0) == pid_) reap(status);
                reaped_ = true;
            }
        }
        // Children left in its group (a middleware's forked nodes) go too.
        ::kill(-pid_, SIGKILL);
        pump();
        pid_ = -pid_;  // keep for logs; no longer ours
    }
    if (out_ >= 0) {
        ::close(out_);
        out_ = -1;
    }
}

std::string Process::logTail(std::size_t max) const {
    std::ifstream f(log_);
    std::string s((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
    return s.size() > max ? "..." + s.substr(s.size() - max) : s;
}

int runCommandOutput(const std::vector<std::string>& argv, std::string& out, const std::string& log,
                     std::chrono::milliseconds timeout, const std::string& netns) {
    Spawn s;
    s.argv = argv;
    if (!argv.empty() && argv[0].find('/') == std::string::npos) {
        s.argv[0] = findExecutable(argv[0]);
        if (s.argv[0].empty()) throw std::runtime_error(argv[0] + " not found");
    }
    s.log = log;
    s.netns = netns;
    {
        std::ofstream l(log, std::ios::app);
        l << "$";
        for (const auto& a : argv) l << ' ' << a;
        l << '\n';
    }
    auto p = Process::start(s);
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (!p->exited()) {
        p->pump();
        if (std::chrono::steady_clock::now() >= end) {
            p->stop(std::chrono::milliseconds(500));
            return -1;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    p->pump();
    out.clear();
    for (const auto& l : p->lines()) out += l + "\n";
    const int rc = p->exitCode();
    p->stop();
    return rc;
}

int runCommand(const std::vector<std::string>& argv, const std::string& log,
               std::chrono::milliseconds timeout, const std::string& netns) {
    std::string out;
    const int rc = runCommandOutput(argv, out, log, timeout, netns);
    if (!out.empty()) {
        std::ofstream l(log, std::ios::app);
        l << out;
    }
    return rc;
}

}  // namespace pnp::bench::runner
