#include "bench/report/plot.hpp"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <thread>

namespace pnp::bench::report {

namespace fs = std::filesystem;

namespace {

// Colour-blind friendly palette (Okabe–Ito), then greys.
const char* const kColours[] = {"#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9",
                                "#D55E00", "#882255", "#000000", "#999999", "#666666"};

std::string quoted(const std::string& s) {
    // gnuplot single-quoted strings: a quote is doubled.
    std::string out = "'";
    for (char c : s) {
        if (c == '\'')
            out += "''";
        else
            out += c;
    }
    return out + "'";
}

// Runs argv with stdout to /dev/null and stderr appended to `log`; kills it after the timeout.
std::string run(const std::vector<std::string>& argv, const fs::path& log, int timeoutSeconds) {
    const int err = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
    if (err < 0) return "cannot open " + log.string();
    // posix_spawn, not fork: the caller (the runner) may have threads.
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
    posix_spawn_file_actions_adddup2(&actions, err, 2);
    pid_t pid = -1;
    const int rc = ::posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    if (rc != 0) {
        ::close(err);
        return "cannot start " + argv[0] + ": " + std::strerror(rc);
    }
    ::close(err);
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(timeoutSeconds);
    int status = 0;
    for (;;) {
        const pid_t r = ::waitpid(pid, &status, WNOHANG);
        if (r == pid) break;
        if (r < 0) return "waitpid failed";
        if (std::chrono::steady_clock::now() > deadline) {
            ::kill(pid, SIGKILL);
            ::waitpid(pid, &status, 0);
            return "gnuplot did not finish within " + std::to_string(timeoutSeconds) + " s";
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return "";
    if (WIFEXITED(status))
        return "gnuplot exited with " + std::to_string(WEXITSTATUS(status)) + " (see " +
               log.filename().string() + ")";
    return "gnuplot was killed by signal " + std::to_string(WTERMSIG(status));
}

}  // namespace

std::optional<fs::path> findGnuplot() {
    const char* path = std::getenv("PATH");
    if (!path) return std::nullopt;
    std::stringstream ss(path);
    std::string dir;
    while (std::getline(ss, dir, ':')) {
        if (dir.empty()) continue;
        const fs::path p = fs::path(dir) / "gnuplot";
        if (::access(p.c_str(), X_OK) == 0) return p;
    }
    return std::nullopt;
}

std::string renderBoxPlot(const fs::path& gnuplot, const fs::path& plotsDir, const BoxPlot& plot,
                          const fs::path& log, int timeoutSeconds) {
    const std::size_t groups = plot.groups.size(), series = plot.series.size();
    if (groups == 0 || series == 0) return "no data";
    const fs::path dat = plotsDir / (plot.name + ".dat");
    const fs::path gp = plotsDir / (plot.name + ".gp");
    const fs::path png = plotsDir / (plot.name + ".png");

    // Boxes side by side within a group; the group spans 0.8 of the unit on x.
    const double slot = 0.8 / static_cast<double>(series);
    double lo = 0, hi = 0;
    bool any = false;
    {
        std::ofstream d(dat, std::ios::trunc);
        if (!d) return "cannot write " + dat.string();
        d << "# x whisker_lo q1 median q3 whisker_hi p99 n outliers (µs), one block per series\n";
        for (std::size_t s = 0; s < series; ++s) {
            d << "# series " << plot.series[s] << "\n";
            bool wrote = false;
            for (std::size_t g = 0; g < groups; ++g) {
                const auto& b = plot.boxes[s][g];
                if (!b || b->n == 0) continue;
                const double x =
                    static_cast<double>(g) +
                    (static_cast<double>(s) - (static_cast<double>(series) - 1) / 2) * slot;
                d << x << ' ' << b->whiskerLo << ' ' << b->q1 << ' ' << b->median << ' ' << b->q3
                  << ' ' << b->whiskerHi << ' ' << b->p99 << ' ' << b->n << ' ' << b->outliers
                  << '\n';
                // The range follows whiskers and p99, not the maximum: one scheduler hiccup
                // of milliseconds would squash every box (the report gives the maximum).
                const double top = std::max(b->whiskerHi, b->p99);
                lo = any ? std::min(lo, b->whiskerLo) : b->whiskerLo;
                hi = any ? std::max(hi, top) : top;
                any = wrote = true;
            }
            if (!wrote) d << "nan nan nan nan nan nan nan 0 0\n";  // keeps block indices aligned
            d << "\n\n";
        }
    }
    if (!any) return "no data";
    // Log scale when the values span more than a decade (and are all positive).
    const bool logY = lo > 0 && hi / lo > 10;

    std::size_t longest = 0;  // characters of the longest x label
    for (const auto& l : plot.groups) longest = std::max(longest, l.size());
    const int width = std::clamp(
        200 + static_cast<int>(groups * std::max<std::size_t>(series * 16, 56)), 800, 2400);
    // Labels wider than their group's share of the axis (about 10 px per character) slant.
    const bool slant = static_cast<double>(longest) * 10 >
                       static_cast<double>(width - 200) / static_cast<double>(groups);
    std::ofstream g(gp, std::ios::trunc);
    if (!g) return "cannot write " + gp.string();
    g << "set encoding utf8\n"
      << "set terminal pngcairo size " << width << ",600 noenhanced font 'DejaVu Sans,11'\n"
      << "set output " << quoted(png.string()) << "\n"
      << "set title " << quoted(plot.title) << "\n"
      << "set xlabel " << quoted(plot.xlabel) << "\n"
      << "set ylabel " << quoted(plot.ylabel) << "\n"
      << "set grid ytics mytics lc rgb '#dddddd'\n"
      << "set key outside right top vertical Left reverse\n"
      << "set style fill solid 0.35 border\n"
      << "set boxwidth " << slot * 0.85 << " absolute\n"
      << "set xrange [-0.6:" << static_cast<double>(groups) - 0.4 << "]\n";
    if (logY) {
        // A tight range with 1-2-5 ticks reads better than gnuplot's whole decades.
        const double ymin = lo / 1.25, ymax = hi * 1.25;
        g << "set logscale y\nset yrange [" << ymin << ":" << ymax << "]\nset ytics (";
        bool first = true;
        for (double decade = std::pow(10.0, std::floor(std::log10(ymin))); decade <= ymax;
             decade *= 10)
            for (double m : {1.0, 2.0, 5.0})
                if (m * decade >= ymin && m * decade <= ymax) {
                    g << (first ? "" : ", ") << "'" << m * decade << "' " << m * decade;
                    first = false;
                }
        g << ")\n";
    } else {
        g << "set yrange [0:" << hi * 1.1 << "]\n";
    }
    g << "set xtics (";
    for (std::size_t i = 0; i < groups; ++i)
        g << (i ? ", " : "") << quoted(plot.groups[i]) << ' ' << i;
    g << ")\n";
    if (slant) g << "set xtics rotate by -30\n";
    g << "plot ";
    for (std::size_t s = 0; s < series; ++s) {
        const std::string c = kColours[s % std::size(kColours)];
        const std::string src = quoted(dat.string()) + " index " + std::to_string(s);
        if (s) g << ", \\\n     ";
        g << src << " using 1:3:2:6:5 with candlesticks whiskerbars 0.5 lc rgb '" << c
          << "' lw 1.5 title " << quoted(plot.series[s]) << ", \\\n     " << src
          << " using 1:4:4:4:4 with candlesticks lc rgb '" << c << "' lw 2.5 notitle";
    }
    // Medians as crosses (as in the thesis's figures) and the 99th percentile as a circle.
    for (std::size_t s = 0; s < series; ++s) {
        const std::string src = quoted(dat.string()) + " index " + std::to_string(s);
        g << ", \\\n     " << src << " using 1:4 with points pt 2 ps 0.9 lc rgb 'black' "
          << (s == 0 ? "title 'median'" : "notitle") << ", \\\n     " << src
          << " using 1:7 with points pt 6 ps 0.5 lc rgb '#777777' "
          << (s == 0 ? "title '99th percentile'" : "notitle");
    }
    g << "\n";
    g.close();
    if (!g) return "cannot write " + gp.string();

    std::error_code ec;
    fs::remove(png, ec);
    const std::string why = run({gnuplot.string(), gp.string()}, log, timeoutSeconds);
    if (!why.empty()) return why;
    if (!fs::exists(png) || fs::file_size(png, ec) == 0) return "gnuplot wrote no PNG";
    return "";
}

}  // namespace pnp::bench::report
