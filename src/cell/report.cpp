#include "cell/report.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <sstream>

namespace pnp::cell {

using nlohmann::json;

namespace {

std::string str(const json& j, const char* key) {
    const auto it = j.find(key);
    if (it == j.end()) return {};
    if (it->is_string()) return it->get<std::string>();
    if (it->is_null()) return {};
    return it->dump();
}

double num(const json& j, const char* key, double fallback = -1) {
    const auto it = j.find(key);
    return it != j.end() && it->is_number() ? it->get<double>() : fallback;
}

std::string fixed(double v, int decimals) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
    return buf;
}

// Gaps (ms) between consecutive [start, end] intervals: end of one -> start of the next.
std::vector<double> gapsMs(const std::vector<std::pair<double, double>>& intervals) {
    std::vector<double> out;
    for (std::size_t i = 1; i < intervals.size(); ++i)
        out.push_back((intervals[i].first - intervals[i - 1].second) * 1e3);
    return out;
}

// The composition overhead inside one composite step, from what its component reported:
// `CompositionOverheadMs` if given, else end -> start of its lower skills' records.
std::vector<double> lowerGaps(const json& step) {
    auto fromObject = [](const json& o) -> std::optional<std::vector<double>> {
        if (!o.is_object()) return std::nullopt;
        const auto it = o.find("CompositionOverheadMs");
        if (it != o.end() && it->is_array()) {
            std::vector<double> out;
            for (const auto& v : *it)
                if (v.is_number()) out.push_back(v.get<double>());
            return out;
        }
        const auto s = o.find("StepStart");
        const auto e = o.find("StepEnd");
        if (s != o.end() && e != o.end() && s->is_array() && e->is_array()) {
            std::vector<std::pair<double, double>> iv;
            for (std::size_t i = 0; i < s->size() && i < e->size(); ++i) {
                const auto a =
                    (*s)[i].is_string() ? parseIsoTime((*s)[i].get<std::string>()) : std::nullopt;
                const auto b =
                    (*e)[i].is_string() ? parseIsoTime((*e)[i].get<std::string>()) : std::nullopt;
                if (a && b) iv.emplace_back(*a, *b);
            }
            return gapsMs(iv);
        }
        return std::nullopt;
    };
    if (auto g = fromObject(step)) return *g;
    for (const char* key : {"results", "finalResult", "lower"})
        if (step.contains(key))
            if (auto g = fromObject(step.at(key))) return *g;
    const auto lower = step.find("lower");
    if (lower == step.end() || !lower->is_array()) return {};
    std::vector<std::pair<double, double>> iv;
    for (const auto& l : *lower) {
        if (!l.is_object()) continue;
        const auto a = parseIsoTime(str(l, "start"));
        const auto b = parseIsoTime(str(l, "end"));
        if (a && b) iv.emplace_back(*a, *b);
    }
    return gapsMs(iv);
}

// Every string inside a JSON value (for matching endpoints and ApplicationUris).
void strings(const json& j, std::vector<std::string>& out, int depth = 0) {
    if (depth > 8 || out.size() > 10000) return;
    if (j.is_string()) {
        out.push_back(j.get<std::string>());
    } else if (j.is_array() || j.is_object()) {
        for (const auto& v : j) strings(v, out, depth + 1);
    }
}

json detectionJson(const Detection& d) {
    json j = {{"device", d.device},           {"plugIn", d.plugIn},
              {"occurrence", d.occurrence},   {"applicationUri", d.applicationUri},
              {"endpointUrl", d.endpointUrl}, {"skills", d.skills}};
    auto ms = [&](const char* k, double v) { j[k] = v >= 0 ? json(v) : json(nullptr); };
    ms("listeningMs", d.listeningMs);
    ms("discoveredMs", d.discoveredMs);
    ms("examineMs", d.examineMs);
    ms("detectedMs", d.detectedMs);
    if (!d.error.empty()) j["error"] = d.error;
    return j;
}

json statsJson(const Stats& s) {
    return {{"count", s.count}, {"median", s.median}, {"max", s.max}, {"min", s.min}};
}

}  // namespace

Stats statsOf(std::vector<double> values) {
    Stats s;
    s.count = values.size();
    if (values.empty()) return s;
    std::sort(values.begin(), values.end());
    const std::size_t n = values.size();
    s.median = n % 2 ? values[n / 2] : (values[n / 2 - 1] + values[n / 2]) / 2;
    s.min = values.front();
    s.max = values.back();
    return s;
}

std::optional<double> parseIsoTime(const std::string& text) {
    int Y, M, D, h, m;
    double sec;
    int used = 0;
    if (std::sscanf(text.c_str(), "%4d-%2d-%2dT%2d:%2d:%lf%n", &Y, &M, &D, &h, &m, &sec, &used) !=
        6)
        return std::nullopt;
    if (M < 1 || M > 12 || D < 1 || D > 31 || h > 23 || m > 59 || sec < 0 || sec >= 61)
        return std::nullopt;
    std::string rest = text.substr(static_cast<std::size_t>(used));
    double offset = 0;
    if (rest == "Z" || rest.empty()) {
    } else {
        int oh = 0, om = 0;
        char sign = 0;
        if (std::sscanf(rest.c_str(), "%c%2d:%2d", &sign, &oh, &om) != 3 ||
            (sign != '+' && sign != '-'))
            return std::nullopt;
        offset = (sign == '+' ? 1 : -1) * (oh * 3600.0 + om * 60.0);
    }
    std::tm tm{};
    tm.tm_year = Y - 1900;
    tm.tm_mon = M - 1;
    tm.tm_mday = D;
    tm.tm_hour = h;
    tm.tm_min = m;
    tm.tm_sec = 0;
    return static_cast<double>(::timegm(&tm)) + sec - offset;
}

std::optional<std::vector<double>> parseFrameText(const std::string& text) {
    std::vector<double> v;
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, ',')) {
        try {
            std::size_t used = 0;
            const double d = std::stod(item, &used);
            if (!std::isfinite(d)) return std::nullopt;
            v.push_back(d);
        } catch (...) {
            return std::nullopt;
        }
    }
    if (v.size() != 6) return std::nullopt;
    return v;
}

RoundReport roundFromRecord(const json& recordIn, int round, const DeviceIndex& devices) {
    RoundReport r;
    r.round = round;
    json record = recordIn;
    if (record.is_string()) record = json::parse(record.get<std::string>(), nullptr, false);
    if (!record.is_object()) {
        r.result = "Unreadable";
        r.reason = "the MES's record is not a JSON object";
        return r;
    }
    r.record = record;
    r.result = str(record, "result");
    if (r.result.empty()) r.result = "Unknown";
    r.reason = str(record, "reason");
    const auto steps = record.find("steps");
    std::vector<std::pair<double, double>> intervals;
    std::optional<double> first, last;
    if (steps != record.end() && steps->is_array()) {
        for (const auto& s : *steps) {
            if (!s.is_object()) continue;
            StepReport st;
            st.index = static_cast<int>(num(s, "index", static_cast<double>(r.steps.size() + 1)));
            st.step = str(s, "step");
            st.skillType = str(s, "skillType");
            st.skill = str(s, "skill");
            st.component = str(s, "component");
            st.endpoint = str(s, "endpoint");
            if (s.contains("parameters")) st.parameters = s.at("parameters");
            st.result = str(s, "result");
            st.message = str(s, "message");
            st.durationS = num(s, "durationS");
            st.dispatchMs = num(s, "dispatchMs");
            st.lowerGapsMs = lowerGaps(s);
            const auto a = parseIsoTime(str(s, "start"));
            const auto b = parseIsoTime(str(s, "end"));
            if (a && b) {
                intervals.emplace_back(*a, *b);
                if (!first) first = *a;
                last = *b;
                if (st.durationS < 0) st.durationS = *b - *a;
            }
            // The devices it used: its own component, and those named in its parameters
            // (e.g. ToolSkillControllerEndpoint) and lower skills ("Grasp@opc.tcp://...").
            std::vector<std::string> texts = {st.component, st.endpoint};
            strings(st.parameters, texts);
            if (s.contains("lower")) strings(s.at("lower"), texts);
            for (const auto& t : texts) {
                for (const auto& [key, device] : devices) {
                    if (key.empty() || t.find(key) == std::string::npos) continue;
                    if (std::find(st.devices.begin(), st.devices.end(), device) == st.devices.end())
                        st.devices.push_back(device);
                }
            }
            r.steps.push_back(std::move(st));
        }
    }
    r.stepGapsMs = gapsMs(intervals);
    if (first && last) r.durationS = *last - *first;
    return r;
}

std::map<std::string, std::vector<double>> placeTargets(const RoundReport& round) {
    std::map<std::string, std::vector<double>> out;
    for (const auto& s : round.steps) {
        if (s.result != "Completed" || !s.parameters.is_object()) continue;
        const std::string object = str(s.parameters, "ObjectId");
        const std::string place = str(s.parameters, "PlacePosition");
        if (object.empty() || place.empty()) continue;
        if (const auto f = parseFrameText(place)) out[object] = {(*f)[0], (*f)[1], (*f)[2]};
    }
    return out;
}

bool CellReport::ok() const {
    if (!problems.empty() || rounds.empty()) return false;
    for (const auto& r : rounds)
        if (r.result != "Completed") return false;
    for (const auto& p : placements)
        if (!p.error.empty() || p.errorMm < 0 || p.errorMm > toleranceMm) return false;
    return true;
}

json CellReport::toJson() const {
    json j;
    j["ok"] = ok();
    j["totalS"] = totalS;
    j["logDir"] = logDir;
    j["logs"] = logs;
    j["problems"] = problems;
    j["toleranceMm"] = toleranceMm;
    json det = json::array();
    std::vector<double> detected;
    for (const auto& d : detections) {
        det.push_back(detectionJson(d));
        if (d.detectedMs >= 0) detected.push_back(d.detectedMs);
    }
    j["detections"] = det;
    j["detectionStats"] = statsJson(statsOf(detected));
    json rounds_ = json::array();
    std::vector<double> allLower, allStep, allDispatch;
    for (const auto& r : rounds) {
        json rj = {{"round", r.round},
                   {"label", r.label},
                   {"result", r.result},
                   {"reason", r.reason},
                   {"durationS", r.durationS}};
        json steps = json::array();
        for (const auto& s : r.steps) {
            json sj = {{"index", s.index},
                       {"step", s.step},
                       {"skillType", s.skillType},
                       {"skill", s.skill},
                       {"component", s.component},
                       {"endpoint", s.endpoint},
                       {"devices", s.devices},
                       {"parameters", s.parameters},
                       {"result", s.result},
                       {"message", s.message},
                       {"durationS", s.durationS},
                       {"dispatchMs", s.dispatchMs},
                       {"lowerGapsMs", s.lowerGapsMs}};
            steps.push_back(sj);
            allLower.insert(allLower.end(), s.lowerGapsMs.begin(), s.lowerGapsMs.end());
            if (s.dispatchMs >= 0) allDispatch.push_back(s.dispatchMs);
        }
        rj["steps"] = steps;
        rj["stepGapsMs"] = r.stepGapsMs;
        allStep.insert(allStep.end(), r.stepGapsMs.begin(), r.stepGapsMs.end());
        rj["record"] = r.record;
        rounds_.push_back(rj);
    }
    j["rounds"] = rounds_;
    j["compositionOverheadMs"] = {{"lowerSkills", statsJson(statsOf(allLower))},
                                  {"processSteps", statsJson(statsOf(allStep))}};
    j["dispatchMs"] = statsJson(statsOf(allDispatch));
    json pl = json::array();
    for (const auto& p : placements) {
        json pj = {{"round", p.round},
                   {"object", p.object},
                   {"target", {p.target[0], p.target[1], p.target[2]}},
                   {"actual", {p.actual[0], p.actual[1], p.actual[2]}},
                   {"errorMm", p.errorMm}};
        if (!p.error.empty()) pj["error"] = p.error;
        pl.push_back(pj);
    }
    j["placements"] = pl;
    return j;
}

std::string CellReport::toText() const {
    std::ostringstream o;
    o << "== pnp cell report ==\n";
    o << "Plug-in -> skills detected (the runner's SkillDetector polling the LDS-ME):\n";
    std::vector<double> detected;
    for (const auto& d : detections) {
        o << "  " << d.device;
        if (d.occurrence > 1) o << " #" << d.occurrence;
        o << " (" << d.plugIn << "): ";
        if (d.detectedMs >= 0) {
            detected.push_back(d.detectedMs);
            o << fixed(d.detectedMs, 1) << " ms";
            if (d.listeningMs >= 0)
                o << " [listening " << fixed(d.listeningMs, 1) << " ms";
            else
                o << " [";
            if (d.discoveredMs >= 0)
                o << (d.listeningMs >= 0 ? ", " : "") << "discovered " << fixed(d.discoveredMs, 1)
                  << " ms";
            if (d.examineMs >= 0) o << ", examined in " << fixed(d.examineMs, 1) << " ms";
            o << "], " << d.skills << " skills";
        } else {
            o << "not detected" << (d.error.empty() ? "" : ": " + d.error);
        }
        o << "\n";
    }
    const Stats ds = statsOf(detected);
    o << "  median " << fixed(ds.median, 1) << " ms, max " << fixed(ds.max, 1) << " ms over "
      << ds.count << " (target: median <= 20 ms; thesis 211-313 ms)\n";
    std::vector<double> allLower, allStep, allDispatch;
    for (const auto& r : rounds) {
        o << "Round " << r.round << (r.label.empty() ? "" : " (" + r.label + ")") << ": "
          << r.result;
        if (!r.reason.empty()) o << " - " << r.reason;
        if (r.durationS >= 0) o << " in " << fixed(r.durationS, 1) << " s";
        o << "\n";
        for (const auto& s : r.steps) {
            o << "  " << s.index << ". " << (s.skillType.empty() ? s.skill : s.skillType);
            if (!s.skill.empty()) o << " " << s.skill;
            if (!s.devices.empty()) {
                o << " [";
                for (std::size_t i = 0; i < s.devices.size(); ++i)
                    o << (i ? ", " : "") << s.devices[i];
                o << "]";
            }
            o << ": " << s.result;
            if (s.durationS >= 0) o << " in " << fixed(s.durationS, 2) << " s";
            if (s.dispatchMs >= 0) o << " (dispatch " << fixed(s.dispatchMs, 2) << " ms)";
            if (!s.lowerGapsMs.empty()) {
                const Stats g = statsOf(s.lowerGapsMs);
                o << " overhead median " << fixed(g.median, 2) << " ms, max " << fixed(g.max, 2)
                  << " ms";
            }
            if (!s.message.empty() && s.result != "Completed") o << " - " << s.message;
            o << "\n";
            allLower.insert(allLower.end(), s.lowerGapsMs.begin(), s.lowerGapsMs.end());
            if (s.dispatchMs >= 0) allDispatch.push_back(s.dispatchMs);
        }
        allStep.insert(allStep.end(), r.stepGapsMs.begin(), r.stepGapsMs.end());
    }
    const Stats lo = statsOf(allLower), st = statsOf(allStep), di = statsOf(allDispatch);
    o << "Composition overhead (end of one lower skill -> start of the next): median "
      << fixed(lo.median, 2) << " ms, max " << fixed(lo.max, 2) << " ms over " << lo.count
      << " (target median <= 2 ms; thesis ~80 ms)\n";
    o << "Between process steps (MES): median " << fixed(st.median, 2) << " ms, max "
      << fixed(st.max, 2) << " ms over " << st.count << "; MES dispatch median "
      << fixed(di.median, 2) << " ms, max " << fixed(di.max, 2) << " ms\n";
    for (const auto& p : placements) {
        o << "Round " << p.round << " " << p.object << ": ";
        if (!p.error.empty()) {
            o << p.error << "\n";
            continue;
        }
        o << "at (" << fixed(p.actual[0], 4) << ", " << fixed(p.actual[1], 4) << ", "
          << fixed(p.actual[2], 4) << "), target (" << fixed(p.target[0], 4) << ", "
          << fixed(p.target[1], 4) << ", " << fixed(p.target[2], 4) << "): error "
          << fixed(p.errorMm, 3) << " mm" << (p.errorMm > toleranceMm ? "  > tolerance!" : "")
          << "\n";
    }
    for (const auto& p : problems) o << "PROBLEM: " << p << "\n";
    o << "Logs: " << logDir << "\n";
    o << (ok() ? "OK" : "FAILED") << " in " << fixed(totalS, 1) << " s\n";
    return o.str();
}

}  // namespace pnp::cell
