// The main job (`pnp cell run`) and a cell left running for users (`pnp cell up`): the cell
// bus (LDS-ME, semantic MES), the simulator with a cell file, then the devices and
// components plugged in one at a time as child processes — each the same `pnp` command a
// user would start by hand — with the time from plug-in to "skills detected" measured by the
// runner's own SkillDetector; then the MES runs the process (ExecuteProcess), an operator
// swaps the tool in a dock in the simulated world, and the same process runs again.
//
// What "plug-in" is: for a device or component, the fork of its process (so its time
// includes the process start, its connection to the simulated device, its server's start,
// its registration with the LDS-ME, the detector's poll of the LDS-ME and the examination of
// its address space); for a tool, the moment it gets power (the changer locks it: the
// world's ground truth Tools/<tool>/Powered, by its source timestamp), its adapter having
// run unpowered since the start, as a tool's adapter board would.
#pragma once

#include <chrono>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <stop_token>
#include <string>
#include <utility>
#include <vector>

#include "cell/report.hpp"

namespace pnp::cell {

class CellError : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

// One process the runner started: enough to stop it by PID and start it again the same way.
struct ChildInfo {
    std::string name;  // lds, mes, sim, ur, kelvin-adc, robotiq, ecbpi, wsg, toolchanger, ...
    int pid = -1;
    std::string url;  // its server ("" = none); the simulator's: the ground truth
    std::string log;  // its stderr (stdout in <log>.out)
    std::vector<std::string> argv;
    std::string netns;  // --netns: the network namespace it runs in (/var/run/netns/NAME)
};

struct CellOptions {
    std::filesystem::path pnp;       // the children's executable (default: this one)
    std::filesystem::path cellFile;  // default: models/cells/thesis.yaml
    // Turtle files given to the MES and the Pick-and-Place component (--kb-file); default:
    // every models/kb/*.ttl, sorted.
    std::vector<std::filesystem::path> kbFiles;
    // Loaded after those (--add-kb-file): e.g. a test's own process next to the default files.
    std::vector<std::filesystem::path> extraKbFiles;
    std::string kb;  // --kb LOCATION for both ("" = their default, the embedded store)
    std::string processIri = "urn:pnp:kb:process#thesis";
    std::filesystem::path logDir;  // default /tmp/pnp-cell-<pid>
    std::filesystem::path reportFile = "cell-report.json";
    bool swap = true;  // the operator's swap and round 2
    // The operator's swap: the tool now in this dock is taken out, `swapTool` put in.
    std::string swapDock = "dock-2";
    std::string swapTool = "wsg-gripper";
    bool netns = false;                    // every process in a network namespace of its own (root)
    std::chrono::milliseconds ldsPoll{5};  // the detector's LDS-ME polling period
    std::chrono::milliseconds startTimeout{30000};     // a child's readiness, its detection
    std::chrono::milliseconds processTimeout{150000};  // one run of the process
    std::vector<std::string> mesArgs;                  // extra arguments of `pnp mes`
    std::vector<std::string> pickPlaceArgs;            // ... of `pnp component pick-place`
    double toleranceMm = 1.0;
    bool quiet = false;  // no progress lines on stdout
    // The live web dashboard (`pnp dashboard`), started right after the world so that the
    // page shows the devices plugging in; on this port, or on a free one when it is taken.
    bool dashboard = true;
    unsigned short dashboardPort = 8080;
};

// The cell's processes and the runner's view of them. Not thread-safe; start() and the
// destructor run on the thread that lives longest (PR_SET_PDEATHSIG, supervisor.hpp).
class Cell {
  public:
    Cell(CellOptions options, std::stop_token stop);
    ~Cell();  // stops the detector, then every child (newest first)
    Cell(const Cell&) = delete;
    Cell& operator=(const Cell&) = delete;

    // The cell bus, the simulator and every device and component, one at a time. Throws
    // CellError (a child that did not come up: which, why, its log).
    void start();
    // ExecuteProcess on the MES; the round's report from its record.
    RoundReport runProcess(int round, const std::string& label);
    // The operator's swap in the simulated world; returns what was done, in words.
    std::string swapTool();
    // Each object the round placed: where the world's ground truth has it vs. its target.
    std::vector<ObjectPlacement> placements(const RoundReport& round);
    // Plug-in -> detection of every device, and of every tool power-up so far.
    std::vector<Detection> detections() const;
    // The dashboard's page (http://HOST:PORT/), "" without one.
    std::string dashboardUrl() const;
    // name -> URL of every server the runner started.
    std::vector<std::pair<std::string, std::string>> urls() const;
    std::map<std::string, std::string> logs() const;
    const std::filesystem::path& logDir() const;
    // Children that exited on their own (after they came up).
    std::vector<std::string> exitedUnexpectedly();
    // What did not come up at start (the MES or Pick-and-Place: the rest still runs).
    std::vector<std::string> problems() const;
    // Every process the runner started, in start order.
    std::vector<ChildInfo> children() const;
    // The line `pnp cell up` prints (README.md): the URLs, and per child its PID, URL, log
    // and argv.
    nlohmann::json describe() const;

    struct Impl;

  private:
    std::unique_ptr<Impl> impl_;
};

// `pnp cell run`: start, round 1, swap, round 2, report (text on stdout, JSON to the report
// file). Exit code 0 only when every step completed and every placed object is within the
// tolerance; 1 when a step failed or an object is off; 2 for bad options; 130 when stopped.
int runCell(const CellOptions& options, std::stop_token stop);
// `pnp cell up`: start, print every server's URL, wait for `stop`, stop everything.
int upCell(const CellOptions& options, std::stop_token stop);

}  // namespace pnp::cell
