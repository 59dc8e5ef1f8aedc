#include "cell/supervisor.hpp"

#include <fcntl.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace pnp::cell {

namespace {
constexpr std::size_t kMaxLines = 2000;         // stdout lines kept for waitForPrefix()
constexpr std::size_t kMaxLineBytes = 1 << 20;  // a longer line is cut there
}  // namespace

std::filesystem::path selfExecutable() {
    std::error_code ec;
    auto p = std::filesystem::read_symlink("/proc/self/exe", ec);
    if (ec) throw std::runtime_error("cannot read /proc/self/exe: " + ec.message());
    return p;
}

ChildProcess::ChildProcess(std::string name, std::filesystem::path logFile)
    : name_(std::move(name)), logFile_(std::move(logFile)) {}

ChildProcess::~ChildProcess() { stop(); }

void ChildProcess::start(const std::vector<std::string>& argv, const std::string& netns) {
    if (argv.empty()) throw std::runtime_error(name_ + ": empty command line");
    if (pid_ > 0) throw std::runtime_error(name_ + ": already started");
    // Everything the child needs is prepared here: between fork and exec it may only make
    // async-signal-safe calls (another thread may hold the malloc lock).
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const std::string nsPath = netns.empty() ? std::string() : "/var/run/netns/" + netns;
    const std::string log = logFile_.string();
    int fds[2];
    if (::pipe2(fds, O_CLOEXEC) != 0)
        throw std::runtime_error(name_ + ": pipe: " + std::strerror(errno));
    const pid_t parent = ::getpid();
    started_ = Clock::now();
    const pid_t pid = ::fork();
    if (pid < 0) {
        ::close(fds[0]);
        ::close(fds[1]);
        throw std::runtime_error(name_ + ": fork: " + std::strerror(errno));
    }
    if (pid == 0) {
        ::prctl(PR_SET_PDEATHSIG, SIGTERM);
        if (::getppid() != parent) ::_exit(127);  // the runner died before the prctl
        ::setpgid(0, 0);
        // The runner blocks SIGINT / SIGTERM in its threads; the mask is inherited.
        sigset_t none;
        sigemptyset(&none);
        ::sigprocmask(SIG_SETMASK, &none, nullptr);
        if (!nsPath.empty()) {
            const int ns = ::open(nsPath.c_str(), O_RDONLY | O_CLOEXEC);
            if (ns < 0 || ::setns(ns, CLONE_NEWNET) != 0) ::_exit(126);
        }
        const int logFd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_APPEND, 0644);
        if (logFd >= 0) ::dup2(logFd, STDERR_FILENO);
        ::dup2(fds[1], STDOUT_FILENO);
        const int devnull = ::open("/dev/null", O_RDONLY);
        if (devnull >= 0) ::dup2(devnull, STDIN_FILENO);
        ::execv(args[0], args.data());
        ::_exit(127);
    }
    ::close(fds[1]);
    pid_ = pid;
    argv_ = argv;
    stdoutFd_ = fds[0];
    reader_ = std::thread([this] { readStdout(); });
}

// Copies stdout into the log (prefixed, so the log reads in order) and keeps its lines.
void ChildProcess::readStdout() {
    std::ofstream copy(logFile_.string() + ".out", std::ios::trunc);
    std::string buffer;
    char chunk[4096];
    for (;;) {
        const ssize_t n = ::read(stdoutFd_, chunk, sizeof chunk);
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) break;
        buffer.append(chunk, static_cast<std::size_t>(n));
        std::size_t nl;
        while ((nl = buffer.find('\n')) != std::string::npos || buffer.size() >= kMaxLineBytes) {
            const std::size_t end = nl == std::string::npos ? kMaxLineBytes : nl;
            std::string text = buffer.substr(0, end);
            buffer.erase(0, nl == std::string::npos ? end : end + 1);
            if (!text.empty() && text.back() == '\r') text.pop_back();
            copy << text << '\n' << std::flush;
            std::lock_guard lock(mutex_);
            if (lines_.size() < kMaxLines) lines_.push_back({Clock::now(), std::move(text)});
            changed_.notify_all();
        }
    }
    std::lock_guard lock(mutex_);
    eof_ = true;
    changed_.notify_all();
}

std::optional<ChildProcess::Line> ChildProcess::waitForPrefix(const std::string& prefix,
                                                              Clock::time_point deadline,
                                                              std::string& error) {
    std::unique_lock lock(mutex_);
    std::size_t seen = 0;
    for (;;) {
        for (; seen < lines_.size(); ++seen)
            if (lines_[seen].text.rfind(prefix, 0) == 0) return lines_[seen];
        if (eof_) {
            lock.unlock();
            // Give the exit status a moment to be there (stdout closes as the process exits).
            for (int i = 0; i < 50 && running(); ++i)
                std::this_thread::sleep_for(std::chrono::milliseconds(2));
            error = name_ + " exited (" + describeExit() + ") before printing \"" + prefix +
                    "\"; log " + logFile_.string() + ":\n" + logTail();
            return std::nullopt;
        }
        if (changed_.wait_until(lock, deadline) == std::cv_status::timeout &&
            Clock::now() >= deadline) {
            for (; seen < lines_.size(); ++seen)
                if (lines_[seen].text.rfind(prefix, 0) == 0) return lines_[seen];
            error = name_ + " printed no \"" + prefix + "\" in time; log " + logFile_.string() +
                    ":\n" + logTail();
            return std::nullopt;
        }
    }
}

bool ChildProcess::running() {
    if (pid_ <= 0 || status_) return false;
    int status = 0;
    const pid_t r = ::waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
        status_ = status;
        return false;
    }
    return r == 0;
}

void ChildProcess::stop(std::chrono::milliseconds grace) {
    stopRequested_ = true;
    if (pid_ > 0 && running()) {
        ::kill(pid_, SIGTERM);
        const auto end = Clock::now() + grace;
        while (Clock::now() < end && running())
            std::this_thread::sleep_for(std::chrono::milliseconds(5));
        if (running()) {
            ::kill(pid_, SIGKILL);
            int status = 0;
            if (::waitpid(pid_, &status, 0) == pid_) status_ = status;
        }
    }
    if (reader_.joinable()) reader_.join();  // stdout is closed once the child is gone
    if (stdoutFd_ >= 0) {
        ::close(stdoutFd_);
        stdoutFd_ = -1;
    }
}

std::string ChildProcess::describeExit() const {
    if (!status_) return "running";
    if (WIFEXITED(*status_)) return "exit code " + std::to_string(WEXITSTATUS(*status_));
    if (WIFSIGNALED(*status_)) return std::string("signal ") + ::strsignal(WTERMSIG(*status_));
    return "status " + std::to_string(*status_);
}

std::string ChildProcess::logTail(std::size_t max) const {
    std::ifstream f(logFile_);
    std::string s((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    return s.size() > max ? s.substr(s.size() - max) : s;
}

Supervisor::Supervisor(std::filesystem::path logDir) : logDir_(std::move(logDir)) {
    std::filesystem::create_directories(logDir_);
}

Supervisor::~Supervisor() { stopAll(); }

ChildProcess& Supervisor::start(const std::string& name, const std::vector<std::string>& argv,
                                const std::string& netns) {
    if (find(name) != nullptr) throw std::runtime_error("a child named " + name + " exists");
    auto child = std::make_unique<ChildProcess>(name, logDir_ / (name + ".log"));
    child->start(argv, netns);
    children_.push_back(std::move(child));
    return *children_.back();
}

ChildProcess* Supervisor::find(const std::string& name) {
    for (auto& c : children_)
        if (c->name() == name) return c.get();
    return nullptr;
}

std::vector<std::string> Supervisor::exitedUnexpectedly() {
    std::vector<std::string> out;
    for (auto& c : children_)
        if (c->pid() > 0 && !c->stopRequested() && !c->running() && c->exitStatus())
            out.push_back(c->name() + " (" + c->describeExit() + ", log " + c->logFile().string() +
                          ")");
    return out;
}

void Supervisor::stopAll(std::chrono::milliseconds grace) {
    // One after the other, newest first: a device unregisters from the LDS-ME while it is
    // still there (a goodbye instead of an expiry), which takes milliseconds each.
    for (auto it = children_.rbegin(); it != children_.rend(); ++it) (*it)->stop(grace);
}

std::vector<const ChildProcess*> Supervisor::children() const {
    std::vector<const ChildProcess*> out;
    for (const auto& c : children_) out.push_back(c.get());
    return out;
}

}  // namespace pnp::cell
