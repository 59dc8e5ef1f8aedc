#include "bench/runner/resources.hpp"

#include <dirent.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace pnp::bench::runner {

namespace {

struct Stat {
    pid_t pgrp = 0;
    long ticks = 0;
};

bool readStat(pid_t pid, Stat& s) {
    std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
    std::string text;
    if (!std::getline(f, text)) return false;
    // The command name (field 2) may contain spaces and parentheses: fields after the last ')'.
    const auto close = text.rfind(')');
    if (close == std::string::npos) return false;
    std::istringstream in(text.substr(close + 2));
    std::string field;
    std::vector<std::string> fields;
    while (in >> field && fields.size() < 14) fields.push_back(field);
    if (fields.size() < 14) return false;
    // fields[0] = state (3), [2] = pgrp (5), [11] = utime (14), [12] = stime (15)
    s.pgrp = static_cast<pid_t>(std::atol(fields[2].c_str()));
    s.ticks = std::atol(fields[11].c_str()) + std::atol(fields[12].c_str());
    return true;
}

long readRssKib(pid_t pid) {
    std::ifstream f("/proc/" + std::to_string(pid) + "/status");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("VmRSS:", 0) == 0) return std::atol(line.c_str() + 6);
    return 0;  // a zombie, or gone
}

}  // namespace

void ResourceSampler::add(const std::string& name, std::vector<pid_t> leaders) {
    groups_[name].leaders = std::move(leaders);
}

void ResourceSampler::sample() {
    const auto now = std::chrono::steady_clock::now();
    std::map<std::string, long> rss;
    DIR* d = ::opendir("/proc");
    if (!d) return;
    while (dirent* e = ::readdir(d)) {
        const pid_t pid = static_cast<pid_t>(std::atol(e->d_name));
        if (pid <= 0) continue;
        Stat s;
        bool read = false;
        for (auto& [name, g] : groups_) {
            if (!read) {
                if (!readStat(pid, s)) break;
                read = true;
            }
            if (std::find(g.leaders.begin(), g.leaders.end(), s.pgrp) == g.leaders.end()) continue;
            // A process seen in the first sample counts from there; a later one from its start.
            if (!g.baseTicks.count(pid)) g.baseTicks[pid] = samples_ == 0 ? s.ticks : 0;
            g.lastTicks[pid] = s.ticks;
            rss[name] += readRssKib(pid);
            break;
        }
    }
    ::closedir(d);
    long total = 0;
    for (auto& [name, g] : groups_) {
        g.rssMax = std::max(g.rssMax, rss[name]);
        ++g.samples;
        total += rss[name];
    }
    totalRssMax_ = std::max(totalRssMax_, total);
    if (samples_ == 0) first_ = now;
    last_ = now;
    ++samples_;
}

Usage ResourceSampler::usage(const std::string& name) const {
    Usage u;
    auto it = groups_.find(name);
    if (it == groups_.end()) return u;
    const Group& g = it->second;
    u.rssKibMax = g.rssMax;
    const double wall = std::chrono::duration<double>(last_ - first_).count();
    if (samples_ < 2 || wall <= 0) return u;
    long ticks = 0;
    for (const auto& [pid, last] : g.lastTicks) ticks += last - g.baseTicks.at(pid);
    u.cpuPct =
        static_cast<double>(ticks) / static_cast<double>(::sysconf(_SC_CLK_TCK)) / wall * 100;
    u.sampled = true;
    return u;
}

}  // namespace pnp::bench::runner
