#include "cell/cell.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "cell/netns.hpp"
#include "cell/supervisor.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/detector/skill_detector.hpp"
#include "ua/client/client.hpp"
#include "ua/spatial/spatial.hpp"
#include "ua/types/extension_object.hpp"
#include "world/cell_file.hpp"

namespace pnp::cell {

using nlohmann::json;
using namespace std::chrono_literals;
namespace detector = skill::detector;

namespace {

constexpr std::string_view kWorldNamespaceUri = "urn:pnp:sim:world";

double msSince(Clock::time_point from, Clock::time_point to) {
    return std::chrono::duration<double, std::milli>(to - from).count();
}

// A TCP port that was free a moment ago (the tool adapters' fixed OPC UA ports: their
// endpoint is then printed at start, not at the first power-up). An address of another
// network namespace (--netns: a device's own) is not ours to bind: any port is free in that
// fresh namespace, so one of ours is taken as the number.
// Whether `port` on `host` can be bound now (SO_REUSEADDR, as a server binds).
bool portFree(const std::string& host, unsigned short port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) return false;
    const int one = 1;
    ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    const bool ok = ::inet_pton(AF_INET, host.c_str(), &a.sin_addr) == 1 &&
                    ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    ::close(fd);
    return ok;
}

unsigned short freePort(const std::string& host) {
    auto tryBind = [](const std::string& address) -> unsigned short {
        const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        sockaddr_in a{};
        a.sin_family = AF_INET;
        ::inet_pton(AF_INET, address.c_str(), &a.sin_addr);
        socklen_t len = sizeof a;
        unsigned short port = 0;
        if (fd >= 0 && ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0 &&
            ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0)
            port = ntohs(a.sin_port);
        if (fd >= 0) ::close(fd);
        return port;
    };
    unsigned short port = tryBind(host);
    if (port == 0 && errno == EADDRNOTAVAIL) port = tryBind("127.0.0.1");
    if (port == 0) throw CellError("no free TCP port on " + host);
    return port;
}

std::string frameText(const Eigen::Isometry3d& pose) {
    const auto f = ua::spatial::toFrame(pose);
    std::ostringstream o;
    o.precision(17);
    o << f.cartesianCoordinates.x << ',' << f.cartesianCoordinates.y << ','
      << f.cartesianCoordinates.z << ',' << f.orientation.a << ',' << f.orientation.b << ','
      << f.orientation.c;
    return o.str();
}

// Which adapter serves a simulated device (the sim's "device" names).
struct AdapterKind {
    const char* simDevice;
    const char* name;  // the runner's name of the child
};
constexpr AdapterKind kToolAdapters[] = {
    {"robotiq-2f85", "robotiq"}, {"schmalz-ecbpi", "ecbpi"}, {"schunk-wsg50", "wsg"}};

}  // namespace

// ---- the world's ground truth, read by the runner (never by the cell's components) -------

class World {
  public:
    void connect(const std::string& url, Clock::time_point deadline) {
        client_.connect(url, ua::client::Anonymous{}, deadline);
        ns_ = client_.namespaceIndex(kWorldNamespaceUri, deadline);
    }
    ua::DataValue read(const std::string& path, Clock::time_point deadline) {
        ua::ReadValueId r;
        r.nodeId = ua::NodeId(ns_, path);
        r.attributeId = 13;
        auto v = client_.read({r}, ua::TimestampsToReturn::Source, deadline);
        if (v.size() != 1) throw CellError("world: no value for " + path);
        return v[0];
    }
    std::vector<ua::DataValue> readMany(const std::vector<std::string>& paths,
                                        Clock::time_point deadline) {
        std::vector<ua::ReadValueId> rs;
        for (const auto& p : paths) {
            ua::ReadValueId r;
            r.nodeId = ua::NodeId(ns_, p);
            r.attributeId = 13;
            rs.push_back(r);
        }
        return client_.read(std::move(rs), ua::TimestampsToReturn::Source, deadline);
    }
    std::string text(const std::string& path, Clock::time_point deadline) {
        const auto v = read(path, deadline);
        const auto* s = v.value ? v.value->scalar<ua::String>() : nullptr;
        return s ? std::string(*s) : std::string();
    }
    std::optional<ua::ThreeDFrame> frame(const std::string& path, Clock::time_point deadline) {
        const auto v = read(path, deadline);
        const auto* x = v.value ? v.value->scalar<ua::ExtensionObject>() : nullptr;
        if (x == nullptr) return std::nullopt;
        return ua::fromExtensionObject<ua::ThreeDFrame>(*x);
    }
    // An operator's method of World; throws CellError with the world's reason.
    void operatorCall(const std::string& method, std::vector<std::string> args,
                      Clock::time_point deadline) {
        std::vector<ua::Variant> in;
        for (auto& a : args) in.emplace_back(ua::String(a));
        const auto r = client_.call(ua::NodeId(ns_, "World"), ua::NodeId(ns_, "World." + method),
                                    std::move(in), deadline);
        if (!r.ok()) throw CellError("world: " + method + ": " + std::string(r.status.name()));
        const auto* e = r.outputs.empty() ? nullptr : r.outputs[0].scalar<ua::String>();
        if (e != nullptr && !e->empty()) throw CellError("world: " + method + ": " + *e);
    }

  private:
    ua::client::Client client_;
    ua::UInt16 ns_ = 0;
};

// ---- Cell ----------------------------------------------------------------------------------

struct Cell::Impl {
    CellOptions options;
    std::stop_token stop;
    world::CellDescription description;
    std::unique_ptr<NetworkNamespaces> namespaces;
    Supervisor supervisor;
    std::unique_ptr<detector::SkillDetector> detector;
    World world;
    std::string host = "127.0.0.1";  // where the runner reaches the cell (loopback / bus)
    std::string lds, mes, worldUrl, dashboardUrl;
    std::string mdnsPort;
    json sim;                                               // the sim's JSON line
    std::vector<std::pair<std::string, std::string>> urls;  // child -> URL
    std::map<std::string, std::string> childUrls;           // child -> its server's URL
    std::map<std::string, std::string> appUris;             // child -> ApplicationUri
    std::vector<Detection> detections;
    std::vector<std::string> problems;  // what did not come up
    std::set<std::string> neverUp;
    DeviceIndex deviceIndex;                         // endpoint / ApplicationUri -> child
    std::map<std::string, std::string> toolAdapter;  // world tool -> adapter child

    // Tool power-ups (from the world) and tool servers appearing (from the detector).
    struct Appearance {
        Clock::time_point time;
        std::string url;
        double examineMs = -1;
        std::size_t skills = 0;
    };
    struct PowerUp {
        std::string tool;
        Clock::time_point time;  // steady, from the ground truth's source timestamp
    };
    mutable std::mutex mutex;
    std::map<std::string, std::size_t> skillCount;               // by ApplicationUri
    std::map<std::string, std::vector<Appearance>> appearances;  // by ApplicationUri
    std::vector<PowerUp> powerUps;
    std::jthread powerWatch;

    Impl(CellOptions o, std::stop_token s)
        : options(std::move(o)),
          stop(std::move(s)),
          supervisor(options.logDir.empty()
                         ? std::filesystem::path("/tmp/pnp-cell-" + std::to_string(::getpid()))
                         : options.logDir) {}

    void say(const std::string& line) const {
        if (!options.quiet) std::cout << "[cell] " << line << std::endl;
    }

    void checkStop() const {
        if (stop.stop_requested()) throw CellError("stopped");
    }

    // argv of a `pnp` child with the network options every server takes.
    std::vector<std::string> serverArgs(std::vector<std::string> argv, const std::string& child,
                                        bool withLds = true) {
        const std::string h = namespaces ? namespaces->address(child) : host;
        std::vector<std::string> a = {options.pnp.string()};
        a.insert(a.end(), argv.begin(), argv.end());
        for (const auto& s : {std::string("--host"), h, std::string("--public-host"), h})
            a.push_back(s);
        if (withLds) {
            a.push_back("--lds");
            a.push_back(lds);
        }
        a.push_back("--mdns-port");
        a.push_back(mdnsPort);
        return a;
    }

    std::string netnsOf(const std::string& child) const {
        return namespaces ? namespaces->name(child) : std::string();
    }

    ChildProcess& spawn(const std::string& name, const std::vector<std::string>& argv) {
        checkStop();
        return supervisor.start(name, argv, netnsOf(name));
    }

    // `pnp dashboard`, a client of the cell bus and the world, in the runner's own network
    // (the page is opened from this machine). One that does not come up is a problem of the
    // run, the cell runs on without it.
    void startDashboard() {
        unsigned short port = options.dashboardPort;
        if (port != 0 && !portFree(host, port)) {
            say("port " + std::to_string(port) + " is taken: the dashboard takes a free one");
            port = 0;
        }
        const std::vector<std::string> argv = {
            options.pnp.string(), "dashboard", "--host", host,      "--port",
            std::to_string(port), "--lds",     lds,      "--world", worldUrl,
            "--no-mdns"};
        auto& child = supervisor.start("dashboard", argv, "");
        try {
            const auto line = waitLine(child, "dashboard on ");
            dashboardUrl = line.text.substr(std::string("dashboard on ").size());
        } catch (const CellError& e) {
            checkStop();
            problems.push_back("dashboard did not come up: " + std::string(e.what()) + " (log " +
                               child.logFile().string() + ")");
            neverUp.insert("dashboard");
            return;
        }
        urls.emplace_back("dashboard", dashboardUrl);
        say("dashboard " + dashboardUrl + " (open it in a browser: the cell live)");
    }

    // A line of the child's stdout, in slices so that a stop request is seen.
    ChildProcess::Line waitLine(ChildProcess& child, const std::string& prefix) {
        const auto deadline = Clock::now() + options.startTimeout;
        std::string error;
        for (;;) {
            checkStop();
            const auto slice = std::min(deadline, Clock::now() + 100ms);
            if (auto l = child.waitForPrefix(prefix, slice, error)) return *l;
            if (Clock::now() >= deadline || !child.running())
                throw CellError(error.empty() ? child.name() + ": no \"" + prefix + "\"" : error);
        }
    }

    // Until the runner's detector has examined the server with this ApplicationUri.
    std::optional<detector::ServerState> waitExamined(const std::string& appUri,
                                                      std::chrono::milliseconds timeout) {
        const auto deadline = Clock::now() + timeout;
        std::optional<detector::ServerState> found;
        auto examined = [&](const detector::SkillDetector& d) {
            for (const auto& s : d.servers())
                if (s.applicationUri == appUri &&
                    (s.status == detector::ServerState::Status::Skills ||
                     s.status == detector::ServerState::Status::NoSkills)) {
                    found = s;
                    return true;
                }
            return false;
        };
        while (Clock::now() < deadline) {
            checkStop();
            const auto slice = std::min<std::chrono::milliseconds>(
                100ms,
                std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()) +
                    1ms);
            if (detector->waitUntil(examined, slice)) return found;
        }
        return std::nullopt;
    }

    // Plug-in -> detected of a child that serves from its start. `optional`: one that did
    // not come up is reported (the run then fails), the rest of the cell still starts.
    Detection plugIn(const std::string& name, const std::string& appUri, ChildProcess& child,
                     bool optional = false) {
        Detection d;
        d.device = name;
        d.plugIn = "process start";
        d.applicationUri = appUri;
        ChildProcess::Line line;
        try {
            line = waitLine(child, "listening on ");
        } catch (const CellError& e) {
            if (!optional || stop.stop_requested()) throw;
            d.error = e.what();
            say(name + " did not come up: " + d.error);
            problems.push_back(name + " did not come up (log " + child.logFile().string() + ")");
            neverUp.insert(name);
            detections.push_back(d);
            return d;
        }
        d.endpointUrl = line.text.substr(13);
        d.listeningMs = msSince(child.startTime(), line.time);
        urls.emplace_back(name, d.endpointUrl);
        childUrls[name] = d.endpointUrl;
        appUris[name] = appUri;
        deviceIndex[d.endpointUrl] = name;
        deviceIndex[appUri] = name;
        const auto state = waitExamined(appUri, options.startTimeout);
        const auto now = Clock::now();
        if (!state) {
            d.error = "not examined by the detector within " +
                      std::to_string(options.startTimeout.count()) + " ms";
            say(name + ": " + d.error);
            detections.push_back(d);
            return d;
        }
        // The first skill's callback is the exact moment; a server without skills: now.
        Clock::time_point at = now;
        {
            std::lock_guard lock(mutex);
            const auto it = appearances.find(appUri);
            if (it != appearances.end() && !it->second.empty())
                at = std::min(at, it->second.front().time);
        }
        d.detectedMs = msSince(child.startTime(), at);
        d.examineMs = state->examineMs;
        d.discoveredMs = d.detectedMs - d.examineMs;
        d.skills = state->skills;
        char buf[200];
        std::snprintf(buf, sizeof buf,
                      "%s plugged in -> %zu skills detected in %.1f ms (listening %.1f ms, "
                      "examined in %.1f ms)",
                      name.c_str(), d.skills, d.detectedMs, d.listeningMs, d.examineMs);
        say(buf);
        detections.push_back(d);
        return d;
    }

    void onSkill(const detector::DetectedSkill& s, bool added) {
        const auto now = Clock::now();
        std::lock_guard lock(mutex);
        auto& n = skillCount[s.componentUri];
        if (added) {
            if (n++ == 0) {
                Appearance a{now, s.endpointUrl, -1, 0};
                appearances[s.componentUri].push_back(a);
            }
        } else if (n > 0) {
            --n;
        }
    }

    // Polls the world's Tools/<tool>/Powered (2 ms) and keeps every power-up with the time of
    // the ground truth's update (its source timestamp), not of our read.
    void watchPower(std::stop_token st) {
        World w;
        try {
            w.connect(worldUrl, Clock::now() + 5s);
        } catch (const std::exception& e) {
            say(std::string("power watch: ") + e.what());
            return;
        }
        std::vector<std::string> tools, paths;
        for (const auto& t : description.tools) {
            tools.push_back(t.name);
            paths.push_back("Tools." + t.name + ".Powered");
        }
        std::vector<bool> last(tools.size(), false);
        bool first = true;
        while (!st.stop_requested()) {
            try {
                const auto values = w.readMany(paths, Clock::now() + 1s);
                const auto steadyNow = Clock::now();
                const auto wallNow = ua::DateTime::now().toUnixNanos();
                for (std::size_t i = 0; i < values.size() && i < tools.size(); ++i) {
                    const auto* b =
                        values[i].value ? values[i].value->scalar<ua::Boolean>() : nullptr;
                    const bool on = b != nullptr && *b;
                    if (on && !last[i] && !first) {
                        auto t = steadyNow;
                        if (values[i].sourceTimestamp) {
                            const auto age = std::chrono::nanoseconds(
                                wallNow - values[i].sourceTimestamp->toUnixNanos());
                            if (age > 0ns && age < 1s)
                                t -= std::chrono::duration_cast<Clock::duration>(age);
                        }
                        std::lock_guard lock(mutex);
                        powerUps.push_back({tools[i], t});
                    }
                    last[i] = on;
                }
                first = false;
            } catch (const std::exception&) {
                // The world went (the cell stops): try again until stopped.
            }
            std::this_thread::sleep_for(2ms);
        }
    }

    std::vector<Detection> toolDetections() const {
        std::lock_guard lock(mutex);
        std::vector<Detection> out;
        std::map<std::string, int> occurrence;
        for (const auto& p : powerUps) {
            const auto adapter = toolAdapter.find(p.tool);
            if (adapter == toolAdapter.end()) continue;
            Detection d;
            d.device = adapter->second;
            d.plugIn = "tool power (" + p.tool + " locked)";
            d.occurrence = ++occurrence[adapter->second];
            const auto uri = appUris.find(adapter->second);
            if (uri != appUris.end()) {
                d.applicationUri = uri->second;
                const auto a = appearances.find(uri->second);
                if (a != appearances.end())
                    for (const auto& x : a->second)
                        if (x.time >= p.time - 2ms) {  // the timestamps' conversion: ~µs
                            d.detectedMs = msSince(p.time, x.time);
                            d.endpointUrl = x.url;
                            break;
                        }
            }
            if (d.detectedMs < 0) d.error = "its skills were not seen after the power-up";
            out.push_back(d);
        }
        return out;
    }

    void start() {
        if (options.pnp.empty()) options.pnp = selfExecutable();
        if (options.cellFile.empty())
            options.cellFile = std::filesystem::path(PNP_MODELS_DIR) / "cells" / "thesis.yaml";
        if (options.kbFiles.empty()) {
            std::error_code ec;
            for (const auto& e : std::filesystem::directory_iterator(
                     std::filesystem::path(PNP_MODELS_DIR) / "kb", ec))
                if (e.path().extension() == ".ttl") options.kbFiles.push_back(e.path());
            std::sort(options.kbFiles.begin(), options.kbFiles.end());
        }
        options.kbFiles.insert(options.kbFiles.end(), options.extraKbFiles.begin(),
                               options.extraKbFiles.end());
        auto loaded = world::loadCellFile(options.cellFile);
        if (!loaded) throw CellError(loaded.error().message);
        description = std::move(*loaded);
        if (description.robots.empty()) throw CellError(options.cellFile.string() + ": no robot");
        mdnsPort = options.netns ? "5353" : std::to_string(20000 + ::getpid() % 20000);
        say("logs in " + supervisor.logDir().string());

        if (options.netns) {
            namespaces = std::make_unique<NetworkNamespaces>(
                std::vector<std::string>{"bus", "ur", "kelvin-adc", "robotiq", "ecbpi", "wsg"},
                supervisor.logDir());
            host = namespaces->runnerAddress();
            say("network namespaces " + namespaces->prefix() + "*: the cell bus " +
                namespaces->address("bus") + ", each device its own");
        }

        // 1. The cell bus: the LDS-ME, then the MES registered with it.
        auto& ldsChild = spawn("lds", serverArgs({"lds", "--port", "0"}, "lds", false));
        lds = waitLine(ldsChild, "listening on ").text.substr(13);
        urls.emplace_back("lds", lds);
        childUrls["lds"] = lds;
        say("LDS-ME " + lds);

        detector::DetectorConfig dc;
        dc.watcher.ldsUrls = {lds};
        dc.watcher.pollInterval = options.ldsPoll;
        dc.watcher.followLds = false;  // the cell bus's LDS-ME lists every server of the cell
        detector = std::make_unique<detector::SkillDetector>(nullptr, dc);
        detector->onChange(
            [this](const detector::DetectedSkill& s, bool added) { onSkill(s, added); });
        detector->start();

        const std::string mesUri = "urn:pnp:cell:mes";
        std::vector<std::string> mesArgs = {"mes",
                                            "--port",
                                            "0",
                                            "--application-uri",
                                            mesUri,
                                            "--record",
                                            (supervisor.logDir() / "mes-records.jsonl").string()};
        if (!options.kb.empty()) mesArgs.insert(mesArgs.end(), {"--kb", options.kb});
        for (const auto& f : options.kbFiles) mesArgs.insert(mesArgs.end(), {"--kb-file", f});
        mesArgs.insert(mesArgs.end(), options.mesArgs.begin(), options.mesArgs.end());
        auto& mesChild = spawn("mes", serverArgs(mesArgs, "mes"));
        mes = plugIn("mes", mesUri, mesChild, true).endpointUrl;

        // 2. The simulated world and its devices' controllers.
        std::vector<std::string> simArgs = {
            "sim",          "--cell", options.cellFile.string(), "--ephemeral-ports", "--port", "0",
            "--truth-rate", "1000"};
        if (namespaces)
            simArgs.insert(simArgs.end(), {"--device-host", namespaces->address("sim")});
        auto& simChild = spawn("sim", serverArgs(simArgs, "sim"));
        const auto simLine = waitLine(simChild, "{");
        sim = json::parse(simLine.text, nullptr, false);
        if (!sim.is_object() || !sim.contains("world") || !sim.contains("devices"))
            throw CellError("sim: unexpected first line: " + simLine.text);
        worldUrl = sim.at("world").get<std::string>();
        urls.emplace_back("sim (ground truth)", worldUrl);
        childUrls["sim"] = worldUrl;
        world.connect(worldUrl, Clock::now() + options.startTimeout);
        say("simulator: cell " + sim.value("cell", std::string()) + ", ground truth " + worldUrl);
        powerWatch = std::jthread([this](std::stop_token st) { watchPower(st); });
        if (options.dashboard) startDashboard();

        auto device = [&](const std::string& simDevice) -> const json* {
            for (const auto& d : sim.at("devices"))
                if (d.value("device", "") == simDevice) return &d;
            return nullptr;
        };

        // 3. The devices and components, one at a time.
        const json* ur = device("ur-controller");
        if (ur == nullptr) throw CellError("sim: no ur-controller in " + simLine.text);
        const auto& robot = description.robots.front();
        auto& urChild = spawn(
            "ur", serverArgs({"device", "ur", "--controller", ur->at("address").get<std::string>(),
                              "--model", robot.modelName, "--port", "0", "--world-to-base",
                              frameText(robot.base), "--application-uri", "urn:pnp:cell:ur"},
                             "ur"));
        const std::string robotUrl = plugIn("ur", "urn:pnp:cell:ur", urChild).endpointUrl;

        const json* adc = device("kelvin-adc-input");
        std::string adcUrl;
        if (adc != nullptr) {
            auto& adcChild = spawn(
                "kelvin-adc",
                serverArgs({"device", "kelvin-adc", "--adc", adc->at("address").get<std::string>(),
                            "--port", "0", "--application-uri", "urn:pnp:cell:kelvin-adc"},
                           "kelvin-adc"));
            adcUrl = plugIn("kelvin-adc", "urn:pnp:cell:kelvin-adc", adcChild).endpointUrl;
        }

        // The tools' adapters run from the start, unpowered; they serve once their tool is
        // locked on the changer (the power through its contacts).
        for (const auto& kind : kToolAdapters) {
            const json* d = device(kind.simDevice);
            if (d == nullptr) continue;
            const std::string name = kind.name;
            const std::string uri = "urn:pnp:cell:" + name;
            const std::string h = namespaces ? namespaces->address(name) : host;
            const std::string port = std::to_string(freePort(h));
            const std::string address = d->at("address").get<std::string>();
            std::vector<std::string> a;
            if (name == "robotiq") {
                a = {"device", "robotiq", "--serial",
                     address,  "--slave", std::to_string(d->value("slave", 9))};
            } else if (name == "ecbpi") {
                a = {"device", "ecbpi",  "--iolink",
                     address,  "--port", std::to_string(d->value("iolink-port", 1))};
            } else {
                a = {"device", "wsg", "--address", address};
            }
            // A 5 ms power poll: the adapter sees the power within 5 ms (default 20).
            a.insert(a.end(), {"--ua-port", port, "--application-uri", uri, "--poll-period", "5",
                               "--poll-timeout", "4"});
            auto& child = spawn(name, serverArgs(a, name));
            const auto line = waitLine(child, "{");
            const json info = json::parse(line.text, nullptr, false);
            const std::string endpoint =
                info.is_object() ? info.value("endpointUrl", std::string()) : std::string();
            urls.emplace_back(name + " (served while powered)", endpoint);
            childUrls[name] = endpoint;
            appUris[name] = uri;
            deviceIndex[uri] = name;
            if (!endpoint.empty()) deviceIndex[endpoint] = name;
            toolAdapter[d->value("name", std::string())] = name;
            say(name + " adapter up, unpowered (its tool " + d->value("name", std::string()) +
                "): serves at " + endpoint + " once powered");
        }

        std::vector<std::string> tc = {"component",
                                       "toolchanger",
                                       "--robot",
                                       robotUrl,
                                       "--adc",
                                       adcUrl.empty() ? std::string("auto") : adcUrl,
                                       "--port",
                                       "0",
                                       "--application-uri",
                                       "urn:pnp:cell:toolchanger"};
        // On loopback there is no multicast: the tools are found through the LDS-ME.
        if (!namespaces) tc.push_back("--no-mdns");
        auto& changer = spawn("toolchanger", serverArgs(tc, "toolchanger"));
        plugIn("toolchanger", "urn:pnp:cell:toolchanger", changer);

        std::vector<std::string> pp = {"component", "pick-place",        "--port",
                                       "0",         "--application-uri", "urn:pnp:cell:pick-place"};
        if (!options.kb.empty()) pp.insert(pp.end(), {"--kb", options.kb});
        for (const auto& f : options.kbFiles) pp.insert(pp.end(), {"--kb-file", f});
        pp.insert(pp.end(), options.pickPlaceArgs.begin(), options.pickPlaceArgs.end());
        auto& pickPlace = spawn("pick-place", serverArgs(pp, "pick-place"));
        plugIn("pick-place", "urn:pnp:cell:pick-place", pickPlace, true);
    }

    RoundReport runProcess(int round, const std::string& label) {
        RoundReport failed;
        failed.round = round;
        failed.label = label;
        failed.result = "NotRun";
        // The MES's ExecuteProcess skill, as the detector knows it.
        std::optional<detector::DetectedSkill> skill;
        for (const auto& s : detector->all()) {
            if (s.componentUri != appUris["mes"]) continue;
            for (const auto& t : s.typeChain)
                if (t.name == "ExecuteProcessSkillType") skill = s;
        }
        if (!skill) {
            failed.reason = "the MES offers no ExecuteProcessSkillType skill";
            return failed;
        }
        say("round " + std::to_string(round) + " (" + label + "): ExecuteProcess " +
            options.processIri + " on " + skill->endpointUrl);
        try {
            auto ua = std::make_shared<ua::client::Client>();
            const auto connectBy = Clock::now() + 10s;
            ua->connect(skill->endpointUrl, ua::client::Anonymous{}, connectBy);
            skill::client::GenericSkillClient client(ua, skill->node, connectBy);
            const auto params = client.parse({"ProcessIri=" + options.processIri});
            const auto r = client.run(params, Clock::now() + options.processTimeout, stop);
            const auto& values = r.finalResult.values;
            std::string record;
            for (const auto& [name, value] : values)
                if (name == "Record")
                    if (const auto* s = value.scalar<ua::String>()) record = *s;
            RoundReport report;
            if (!record.empty()) {
                report = roundFromRecord(json::parse(record, nullptr, false), round, deviceIndex);
            } else {
                report.round = round;
                report.result = std::string(skill::toString(r.result));
                report.reason = "no Record in the FinalResultData";
            }
            report.label = label;
            if (r.result != skill::SkillResult::Completed) {
                if (report.result == "Completed")
                    report.result = std::string(skill::toString(r.result));
                if (report.reason.empty())
                    report.reason = r.timedOut ? "timed out (halted)" : r.message;
            }
            say("round " + std::to_string(round) + ": " + report.result +
                (report.reason.empty() ? "" : " - " + report.reason));
            return report;
        } catch (const std::exception& e) {
            failed.result = "Failed";
            failed.reason = std::string("ExecuteProcess: ") + e.what();
            return failed;
        }
    }

    std::string swapTool() {
        const auto deadline = Clock::now() + 5s;
        std::string out;
        for (const auto& t : description.tools) {
            if (t.name == options.swapTool) continue;
            if (world.text("Tools." + t.name + ".Dock", deadline) == options.swapDock) {
                world.operatorCall("TakeToolOut", {t.name}, deadline);
                out = t.name + " taken out of " + options.swapDock + "; ";
            }
        }
        world.operatorCall("PutToolInDock", {options.swapTool, options.swapDock}, deadline);
        out += options.swapTool + " put in " + options.swapDock;
        say("operator: " + out);
        return out;
    }

    std::vector<ObjectPlacement> placements(const RoundReport& round) {
        std::vector<ObjectPlacement> out;
        for (const auto& [object, target] : placeTargets(round)) {
            ObjectPlacement p;
            p.round = round.round;
            p.object = object;
            for (int i = 0; i < 3; ++i) p.target[i] = target[static_cast<std::size_t>(i)];
            const auto* o = description.findObject(object);
            try {
                const auto f = world.frame("Objects." + object + ".Pose", Clock::now() + 5s);
                if (!f) throw CellError("no pose");
                // Its bottom face's centre: the place position is where it stands.
                const auto pose = ua::spatial::toIsometry(*f);
                const double half = o != nullptr ? o->size.z() / 2 : 0.0;
                const Eigen::Vector3d bottom = pose * Eigen::Vector3d(0, 0, -half);
                for (int i = 0; i < 3; ++i) p.actual[i] = bottom[i];
                p.errorMm =
                    1e3 * (bottom - Eigen::Vector3d(target[0], target[1], target[2])).norm();
            } catch (const std::exception& e) {
                p.error = "the world's pose of " + object + ": " + e.what();
            }
            out.push_back(p);
        }
        return out;
    }
};

Cell::Cell(CellOptions options, std::stop_token stop)
    : impl_(std::make_unique<Impl>(std::move(options), std::move(stop))) {}

Cell::~Cell() {
    if (impl_->powerWatch.joinable()) {
        impl_->powerWatch.request_stop();
        impl_->powerWatch.join();
    }
    if (impl_->detector) impl_->detector->stop();
    impl_->supervisor.stopAll();
    impl_->namespaces.reset();  // after the processes in them
}

void Cell::start() { impl_->start(); }
RoundReport Cell::runProcess(int round, const std::string& label) {
    return impl_->runProcess(round, label);
}
std::string Cell::swapTool() { return impl_->swapTool(); }
std::vector<ObjectPlacement> Cell::placements(const RoundReport& round) {
    return impl_->placements(round);
}
std::vector<Detection> Cell::detections() const {
    auto out = impl_->detections;
    for (auto& d : impl_->toolDetections()) out.push_back(std::move(d));
    return out;
}
std::vector<std::pair<std::string, std::string>> Cell::urls() const { return impl_->urls; }

std::string Cell::dashboardUrl() const { return impl_->dashboardUrl; }
std::map<std::string, std::string> Cell::logs() const {
    std::map<std::string, std::string> out;
    for (const auto* c : impl_->supervisor.children()) out[c->name()] = c->logFile().string();
    return out;
}
const std::filesystem::path& Cell::logDir() const { return impl_->supervisor.logDir(); }
std::vector<std::string> Cell::exitedUnexpectedly() {
    std::vector<std::string> out;
    for (auto& x : impl_->supervisor.exitedUnexpectedly()) {
        bool reported = false;  // one that never came up is in problems() already
        for (const auto& n : impl_->neverUp) reported |= x.rfind(n + " (", 0) == 0;
        if (!reported) out.push_back(std::move(x));
    }
    return out;
}
std::vector<std::string> Cell::problems() const { return impl_->problems; }

std::vector<ChildInfo> Cell::children() const {
    std::vector<ChildInfo> out;
    for (const auto* c : impl_->supervisor.children()) {
        ChildInfo i;
        i.name = c->name();
        i.pid = c->pid();
        const auto url = impl_->childUrls.find(c->name());
        if (url != impl_->childUrls.end()) i.url = url->second;
        i.log = c->logFile().string();
        i.argv = c->argv();
        i.netns = impl_->netnsOf(c->name());
        out.push_back(std::move(i));
    }
    return out;
}

json Cell::describe() const {
    json children = json::array();
    for (const auto& c : this->children()) {
        json j = {{"name", c.name}, {"pid", c.pid}, {"log", c.log}, {"argv", c.argv}};
        if (!c.url.empty()) j["url"] = c.url;
        if (!c.netns.empty()) j["netns"] = c.netns;
        // A tool's adapter serves only while its tool is powered (locked on the flange).
        for (const auto& kind : kToolAdapters)
            if (c.name == kind.name) j["servedWhilePowered"] = true;
        children.push_back(std::move(j));
    }
    json out = {{"pid", ::getpid()},
                {"logDir", impl_->supervisor.logDir().string()},
                {"lds", impl_->lds},
                {"world", impl_->worldUrl},
                {"children", std::move(children)}};
    if (!impl_->mes.empty()) out["mes"] = impl_->mes;
    if (!impl_->dashboardUrl.empty()) out["dashboard"] = impl_->dashboardUrl;
    if (impl_->sim.is_object()) out["sim"] = impl_->sim;
    json problems = impl_->problems;
    out["problems"] = std::move(problems);
    return out;
}

// ---- the commands ------------------------------------------------------------------------

namespace {

void writeReport(const CellReport& report, const std::filesystem::path& file) {
    std::ofstream f(file, std::ios::trunc);
    f << report.toJson().dump(2) << '\n';
    if (!f) std::cerr << "error: cannot write the report to " << file << "\n";
}

}  // namespace

int runCell(const CellOptions& options, std::stop_token stop) {
    const auto t0 = Clock::now();
    CellReport report;
    report.toleranceMm = options.toleranceMm;
    int code = 0;
    {
        Cell cell(options, stop);
        report.logDir = cell.logDir().string();
        try {
            cell.start();
            auto round1 = cell.runProcess(1, "the thesis cell");
            auto p1 = cell.placements(round1);
            report.rounds.push_back(std::move(round1));
            report.placements.insert(report.placements.end(), p1.begin(), p1.end());
            if (options.swap && !stop.stop_requested()) {
                cell.swapTool();
                auto round2 = cell.runProcess(
                    2, options.swapTool + " in " + options.swapDock + " (the operator's swap)");
                auto p2 = cell.placements(round2);
                report.rounds.push_back(std::move(round2));
                report.placements.insert(report.placements.end(), p2.begin(), p2.end());
            }
        } catch (const std::exception& e) {
            report.problems.push_back(e.what());
        }
        for (const auto& r : report.rounds)
            if (r.result != "Completed")
                report.problems.push_back("round " + std::to_string(r.round) + ": " + r.result +
                                          (r.reason.empty() ? "" : " - " + r.reason));
        for (const auto& r : report.rounds)
            if (r.result == "Completed" && placeTargets(r).empty())
                report.problems.push_back("round " + std::to_string(r.round) +
                                          ": no PickAndPlace step with ObjectId and "
                                          "PlacePosition in the MES's record");
        for (const auto& x : cell.problems()) report.problems.push_back(x);
        for (const auto& x : cell.exitedUnexpectedly())
            report.problems.push_back("exited on its own: " + x);
        report.detections = cell.detections();
        report.logs = cell.logs();
    }  // every child stopped here
    report.totalS = std::chrono::duration<double>(Clock::now() - t0).count();
    if (stop.stop_requested()) report.problems.push_back("stopped by a signal");
    std::cout << report.toText();
    writeReport(report, options.reportFile);
    std::cout << "report: " << std::filesystem::absolute(options.reportFile).string() << "\n";
    code = report.ok() ? 0 : 1;
    if (stop.stop_requested()) code = 130;
    return code;
}

int upCell(const CellOptions& options, std::stop_token stop) {
    Cell cell(options, stop);
    try {
        cell.start();
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return stop.stop_requested() ? 130 : 1;
    }
    for (const auto& x : cell.problems()) std::cerr << "warning: " << x << "\n";
    // One JSON line first (README.md "pnp cell up"): what a script or test needs to reach
    // every process, stop it by PID and start it again with the same argv.
    std::cout << cell.describe().dump(-1, ' ', false, json::error_handler_t::replace) << "\n";
    std::cout << "The cell is up (logs in " << cell.logDir().string() << "):\n";
    for (const auto& [name, url] : cell.urls()) std::cout << "  " << name << "  " << url << "\n";
    std::cout << "Try: pnp skills --once --no-mdns --lds " << cell.urls().front().second
              << "\nCtrl-C stops everything." << std::endl;
    // A process that exits (a crash, or a test that kills it to see the cell cope) is
    // reported once and the rest keeps running: it can be started again with its argv.
    std::set<std::string> reported;
    while (!stop.stop_requested()) {
        std::this_thread::sleep_for(100ms);
        for (const auto& x : cell.exitedUnexpectedly())
            if (reported.insert(x).second)
                std::cerr << "warning: exited: " << x << "; the rest of the cell keeps running"
                          << std::endl;
    }
    std::cout << "[cell] stopping" << std::endl;
    return 0;
}

}  // namespace pnp::cell
