// CPU and memory of process groups, sampled from /proc while a client runs (every 100 ms):
// utime + stime from /proc/<pid>/stat and VmRSS from /proc/<pid>/status of every process in
// the group (each process the runner starts leads a process group of its own, so a
// middleware's forked children are counted with it).
#pragma once

#include <sys/types.h>

#include <chrono>
#include <map>
#include <string>
#include <vector>

namespace pnp::bench::runner {

struct Usage {
    double cpuPct = 0;     // CPU time / wall time between the first and last sample, in %
    long rssKibMax = 0;    // largest summed VmRSS of the group in one sample
    bool sampled = false;  // at least two samples
};

class ResourceSampler {
  public:
    // A named group of process groups (their leaders' PIDs).
    void add(const std::string& name, std::vector<pid_t> groupLeaders);
    void sample();
    Usage usage(const std::string& name) const;
    // Largest sum of VmRSS over all groups in one sample.
    long rssKibTotalMax() const { return totalRssMax_; }

  private:
    struct Group {
        std::vector<pid_t> leaders;
        std::map<pid_t, long> baseTicks, lastTicks;  // per process
        long rssMax = 0;
        int samples = 0;
    };
    std::map<std::string, Group> groups_;
    std::chrono::steady_clock::time_point first_, last_;
    int samples_ = 0;
    long totalRssMax_ = 0;
};

}  // namespace pnp::bench::runner
