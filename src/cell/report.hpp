// The main job's report (text and JSON): per device the time from plug-in to "skills
// detected", per round and step of the process the skill, component, duration and result
// (from the MES's execution record), the composition overhead between consecutive lower
// skills, and each moved object's final pose error from the world's ground truth.
//
// The MES's record (issue23.md "MES ↔ runner") is read liberally: a field it lacks is left
// out of the report, never invented.
#pragma once

#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

namespace pnp::cell {

// Plug-in -> skills detected of one device or component, as the runner's own SkillDetector
// (polling the LDS-ME) saw it.
struct Detection {
    std::string device;          // "ur", "kelvin-adc", "robotiq", ...
    std::string plugIn;          // "process start" | "tool power (changer locked)"
    std::string applicationUri;  // of its server
    std::string endpointUrl;
    int occurrence = 1;  // tools: the n-th power-up of this tool
    // Milliseconds from the plug-in moment; < 0 when not applicable / not seen.
    double listeningMs = -1;   // the child printed "listening on" (process, connect, server)
    double discoveredMs = -1;  // the detector's examination began (registration + LDS poll)
    double detectedMs = -1;    // examination done: its skills are known
    double examineMs = -1;     // the detector's examination alone (connect included)
    std::size_t skills = 0;
    std::string error;  // why not detected
};

struct Stats {
    std::size_t count = 0;
    double median = 0, max = 0, min = 0;
};
Stats statsOf(std::vector<double> values);

struct StepReport {
    int index = 0;
    std::string step;  // the process step's IRI
    std::string skillType, skill, component, endpoint;
    std::vector<std::string> devices;  // the runner's children this step used (by endpoint/URI)
    nlohmann::json parameters = nlohmann::json::object();
    std::string result, message;
    double durationS = -1, dispatchMs = -1;
    std::vector<double> lowerGapsMs;  // composition overhead inside a composite skill
};

struct RoundReport {
    int round = 0;
    std::string label;  // "thesis cell", "after the swap (WSG 50 in dock 2)"
    std::string result = "NotRun", reason;
    double durationS = -1;
    std::vector<StepReport> steps;
    std::vector<double> stepGapsMs;  // end of one MES step -> start of the next
    nlohmann::json record;           // the MES's record as received
};

struct ObjectPlacement {
    int round = 0;
    std::string object;
    double target[3] = {0, 0, 0};  // where its bottom face's centre should be (PlacePosition)
    double actual[3] = {0, 0, 0};  // its bottom face's centre in the world's ground truth
    double errorMm = -1;
    std::string error;  // could not be read
};

// Who used which endpoint / ApplicationUri: maps a step's endpoints to the runner's devices.
using DeviceIndex = std::map<std::string, std::string>;  // endpoint URL or app URI -> device

// A round's report from the MES's execution record (JSON text or object).
RoundReport roundFromRecord(const nlohmann::json& record, int round, const DeviceIndex& devices);

// Seconds since the Unix epoch of an ISO-8601 UTC time ("2026-11-27T01:02:03.123Z", an
// offset "+01:00" too); nullopt when it is not one.
std::optional<double> parseIsoTime(const std::string& text);

// "x,y,z,a,b,c" -> six numbers; nullopt otherwise.
std::optional<std::vector<double>> parseFrameText(const std::string& text);

// Where each object the round's PickAndPlace steps moved should end: the PlacePosition of the
// last step that moved it (ObjectId -> x,y,z).
std::map<std::string, std::vector<double>> placeTargets(const RoundReport& round);

struct CellReport {
    std::string logDir;
    std::map<std::string, std::string> logs;  // child -> log file
    std::vector<Detection> detections;
    std::vector<RoundReport> rounds;
    std::vector<ObjectPlacement> placements;
    std::vector<std::string> problems;  // what made the run fail, in words
    double totalS = 0;
    double toleranceMm = 1.0;

    bool ok() const;  // no problem, every round Completed, every placement within tolerance
    nlohmann::json toJson() const;
    std::string toText() const;
};

}  // namespace pnp::cell
