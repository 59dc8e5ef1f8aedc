// The dashboard's OPC UA side against in-process servers on loopback: an LDS-ME and a demo
// skill server that registers with it (server + skill messages, transitions with the event's
// Time, the final result, removal when it goes), and the pages' actions over a real
// WebSocket (run with parameters converted by the server's DataTypes, a bad parameter
// refused before any call, halt, a login refused by the server).
#include "dashboard/cell_view.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "dashboard/dashboard.hpp"
#include "robot_rig.hpp"
#include "sim/cell/ground_truth.hpp"
#include "sim/cell/simulator.hpp"
#include "skill/client/generic_client.hpp"
#include "skill/client/typed_clients.hpp"
#include "skill/demo/demo_skills.hpp"
#include "support/inbox.hpp"
#include "support/loopback_server.hpp"
#include "ua/client/client.hpp"
#include "ua/discovery/registrar.hpp"
#include "ua/discovery/watcher.hpp"
#include "ua/server/access_control.hpp"
#include "ua/server/roles.hpp"
#include "ua/server/server.hpp"
#include "ua/server/user_store.hpp"
#include "world/cell_file.hpp"
#include "ws_test_client.hpp"

namespace {

using namespace std::chrono_literals;
using json = nlohmann::json;
using pnp::testing::Inbox;
namespace ua = pnp::ua;

// A demo component (Delay, Grasp, Release, MoveGripper) on its own server.
struct DemoServer {
    explicit DemoServer(const std::string& uri,
                        std::shared_ptr<ua::server::AccessControl> access = {}) {
        auto c = pnp::testing::loopbackConfig();
        c.applicationUri = uri;
        c.applicationName = "demo component";
        if (access) c.accessControl = std::move(access);
        server = std::make_unique<ua::server::Server>(c);
        pnp::skill::demo::loadDemoModels(*server);
        controller = pnp::skill::demo::addDemoSkills(*server, "DemoGripper");
        server->start();
    }
    std::string url() const { return pnp::testing::url(*server); }
    std::unique_ptr<ua::server::Server> server;
    std::unique_ptr<pnp::skill::server::SkillController> controller;
};

std::int64_t nowMs() {
    return std::chrono::duration_cast<std::chrono::milliseconds>(
               std::chrono::system_clock::now().time_since_epoch())
        .count();
}

bool has(const std::vector<json>& messages, const std::function<bool(const json&)>& pred) {
    return std::any_of(messages.begin(), messages.end(), pred);
}

TEST(CellView, ServersSkillsTransitionsAndRemovalFromDiscovery) {
    auto ldsCfg = pnp::testing::loopbackConfig();
    ldsCfg.applicationUri = "urn:pnp:test:dashboard:lds";
    ldsCfg.discovery.localDiscoveryServer = true;
    ua::server::Server lds(ldsCfg);
    lds.start();
    const std::string ldsUrl = pnp::testing::url(lds);

    Inbox<json> inbox;
    pnp::dashboard::CellViewOptions options;
    options.ldsUrls = {ldsUrl};
    options.pollInterval = 20ms;
    pnp::dashboard::CellView view(nullptr, options,
                                  [&](std::string m) { inbox.put(json::parse(m)); });
    view.start();

    auto demo = std::make_unique<DemoServer>("urn:pnp:test:dashboard:demo");
    ua::discovery::RegistrarConfig rc;
    rc.ldsUrl = ldsUrl;
    auto registrar = std::make_unique<ua::discovery::Registrar>(*demo->server, nullptr, rc);
    registrar->start();
    const std::string url = ua::discovery::normaliseUrl(demo->url());

    // The server, with the LDS-ME as its parent; its four skills with parameters and state.
    ASSERT_TRUE(inbox.waitFor(
        [&](const std::vector<json>& v) {
            return has(v, [&](const json& m) {
                return m["type"] == "server" && m["op"] == "add" && m["server"]["url"] == url &&
                       m["server"]["applicationUri"] == "urn:pnp:test:dashboard:demo";
            });
        },
        10s));
    for (const auto& m : inbox.items()) {
        if (m["type"] == "server" && m["server"]["url"] == url) {
            EXPECT_EQ(m["server"]["parent"], ua::discovery::normaliseUrl(ldsUrl));
        }
    }
    std::string delayId;
    ASSERT_TRUE(inbox.waitFor(
        [&](const std::vector<json>& v) {
            int ready = 0;
            for (const auto& m : v)
                if (m["type"] == "skill" && m["op"] == "add" && m["skill"]["state"] == "Ready" &&
                    !m["skill"]["parameters"].empty()) {
                    ++ready;
                    if (m["skill"]["name"] == "Delay") delayId = m["skill"]["id"];
                }
            return ready >= 4 && !delayId.empty();
        },
        10s));
    EXPECT_TRUE(has(inbox.items(), [](const json& m) {
        return m["type"] == "component" && m["op"] == "add" &&
               m["component"]["name"] == "DemoGripper";
    }));
    const json snap = view.snapshot();
    EXPECT_EQ(snap["type"], "snapshot");
    EXPECT_EQ(snap["skills"].size(), 4u);
    const auto delay = std::find_if(snap["skills"].begin(), snap["skills"].end(),
                                    [&](const json& s) { return s["id"] == delayId; });
    ASSERT_NE(delay, snap["skills"].end());
    EXPECT_EQ((*delay)["type"], "DelaySkillType");
    EXPECT_TRUE(std::any_of(
        (*delay)["parameters"].begin(), (*delay)["parameters"].end(),
        [](const json& p) { return p["name"] == "DurationMs" && p["dataType"] == "Double"; }));

    // A run by someone else: its transitions arrive with the event's Time, then the result.
    const auto t0 = nowMs();
    {
        auto client = std::make_shared<ua::client::Client>();
        client->connect(url, ua::client::Anonymous{}, 3s);
        const auto target = view.skill(delayId);
        ASSERT_TRUE(target);
        pnp::skill::client::GenericSkillClient skill(client, target->node, 3s);
        const auto r = skill.run(skill.parse({"DurationMs=50"}), 5s);
        EXPECT_EQ(r.result, pnp::skill::SkillResult::Completed);
    }
    const auto t1 = nowMs();
    ASSERT_TRUE(inbox.waitFor(
        [&](const std::vector<json>& v) {
            return has(v, [&](const json& m) {
                return m["type"] == "transition" && m["skill"] == delayId &&
                       m["from"] == "Running" && m["to"] == "Ready";
            });
        },
        5s));
    for (const auto& m : inbox.items()) {
        if (m["type"] == "transition" && m["skill"] == delayId) {
            EXPECT_GE(m["time"].get<std::int64_t>(), t0 - 1000);
            EXPECT_LE(m["time"].get<std::int64_t>(), t1 + 1000);
        }
    }
    EXPECT_TRUE(has(inbox.items(), [&](const json& m) {
        return m["type"] == "transition" && m["skill"] == delayId && m["from"] == "Ready" &&
               m["to"] == "Running";
    }));
    ASSERT_TRUE(inbox.waitFor(
        [&](const std::vector<json>& v) {
            return has(v, [&](const json& m) {
                return m["type"] == "skill" && m["skill"]["id"] == delayId &&
                       m["skill"]["lastResult"].is_object() &&
                       m["skill"]["lastResult"]["result"] == "Completed";
            });
        },
        5s));
    EXPECT_EQ(view.snapshot()["stats"]["skillDurations"]["DelaySkillType"].size(), 1u);
    EXPECT_GE(view.snapshot()["timeline"].size(), 2u);

    // Unplugged: unregistered and stopped: every skill, the component and the server go.
    registrar->stop();
    demo->server->stop();
    ASSERT_TRUE(inbox.waitFor(
        [&](const std::vector<json>& v) {
            int removed = 0;
            bool server = false;
            for (const auto& m : v) {
                if (m["type"] == "skill" && m["op"] == "remove") ++removed;
                if (m["type"] == "server" && m["op"] == "remove" && m["server"]["url"] == url)
                    server = true;
            }
            return removed == 4 && server;
        },
        10s));
    EXPECT_TRUE(view.snapshot()["skills"].empty());
    view.stop();
}

// The 3D view's data from the simulator's ground truth (in process: the thesis cell): the
// robots' models and bases, the table, the docks with their poses and parked tools, the
// objects' sizes and colours, the tools' TCPs — what web/dashboard/js/view3d.js draws.
TEST(CellView, WorldCarriesWhatTheThreeDViewDraws) {
    auto cell = pnp::world::loadCellFile(pnp::sim::cell::defaultCellFile());
    ASSERT_TRUE(cell.ok()) << cell.error().message;
    pnp::sim::cell::SimulatorConfig simConfig;
    simConfig.ephemeralPorts = true;
    pnp::sim::cell::Simulator sim(cell.value(), simConfig);
    ua::server::Server server(pnp::testing::loopbackConfig());
    pnp::sim::cell::GroundTruth truth(server, sim, {.rate = 100.0});
    sim.start();
    server.start();
    truth.start();

    Inbox<json> inbox;
    pnp::dashboard::CellViewOptions options;
    options.discovery = false;
    options.worldUrl = pnp::testing::url(server);
    pnp::dashboard::CellView view(nullptr, options,
                                  [&](std::string m) { inbox.put(json::parse(m)); });
    view.start();
    auto complete = [](const json& m) {
        return m["type"] == "world" && m["tables"].size() == 1 && m["docks"].size() == 2 &&
               m["objects"].size() == 1 && m["objects"][0]["pose"].is_array() &&
               m["tools"].size() == 3 && m["joints"].contains("ur5");
    };
    ASSERT_TRUE(inbox.waitFor(
        [&](const std::vector<json>& v) { return std::any_of(v.begin(), v.end(), complete); },
        10s));
    json world;
    for (const auto& m : inbox.items())
        if (complete(m)) world = m;
    const auto near = [](const json& a, const std::vector<double>& b) {
        if (!a.is_array() || a.size() < b.size()) return false;
        for (std::size_t i = 0; i < b.size(); ++i)
            if (std::abs(a[i].get<double>() - b[i]) > 1e-9) return false;
        return true;
    };

    EXPECT_EQ(world["models"]["ur5"], "ur5");
    EXPECT_TRUE(near(world["bases"]["ur5"], {-0.3, 0, 0, 0, 0, 0})) << world["bases"];
    EXPECT_EQ(world["tables"][0]["name"], "table");
    EXPECT_TRUE(near(world["tables"][0]["pose"], {0, 0, 0, 0, 0, 0})) << world["tables"];
    EXPECT_TRUE(near(world["tables"][0]["size"], {1.0, 0.8, 0.75})) << world["tables"];
    std::map<std::string, json> docks;
    for (const auto& d : world["docks"]) docks[d["name"].get<std::string>()] = d;
    ASSERT_EQ(docks.size(), 2u);
    EXPECT_EQ(docks["dock-1"]["tool"], "vacuum-gripper");
    EXPECT_EQ(docks["dock-2"]["tool"], "parallel-gripper");
    EXPECT_TRUE(near(docks["dock-1"]["pose"], {-0.125, 0.513, -0.036})) << docks["dock-1"];
    EXPECT_TRUE(near(docks["dock-2"]["pose"], {0.125, 0.513, -0.036})) << docks["dock-2"];
    const json& cube = world["objects"][0];
    EXPECT_EQ(cube["name"], "cube-green");
    EXPECT_TRUE(near(cube["size"], {0.04, 0.04, 0.04})) << cube;
    EXPECT_EQ(cube["color"], "green");
    EXPECT_EQ(cube["holder"], "table");
    std::map<std::string, json> tools;
    for (const auto& t : world["tools"]) tools[t["name"].get<std::string>()] = t;
    EXPECT_TRUE(near(tools["parallel-gripper"]["tcp"], {0, 0, 0.2028, 0, 0, 0}));
    EXPECT_TRUE(near(tools["vacuum-gripper"]["tcp"], {0, 0, 0.1868, 0, 0, 0}));
    EXPECT_TRUE(near(tools["wsg-gripper"]["tcp"], {0, 0, 0.19, 0, 0, 0}));
    EXPECT_TRUE(tools["wsg-gripper"]["dock"].is_null());  // on the shelf

    // A new page gets the same from the snapshot.
    const json snap = view.snapshot()["world"];
    ASSERT_TRUE(snap.is_object());
    EXPECT_EQ(snap["tables"], world["tables"]);
    EXPECT_EQ(snap["bases"], world["bases"]);
    EXPECT_EQ(snap["docks"], world["docks"]);
    view.stop();
    truth.stop();
}

// Real hardware has no ground truth: the 3D view follows the robot's own OPC 40010 nodes
// (Axes/<axis>/ParameterSet/ActualPosition, the DI Model, WorldToRobotBase) while the
// robot's server is there, and the robot leaves the world with its server.
TEST(CellView, WithoutAGroundTruthTheWorldFollowsTheRobotsRoboticsNodes) {
    auto rig = std::make_unique<pnp::testing::Rig>();
    Inbox<json> inbox;
    pnp::dashboard::CellViewOptions options;
    options.discovery = false;
    options.urls = {pnp::testing::url(rig->server)};
    pnp::dashboard::CellView view(nullptr, options,
                                  [&](std::string m) { inbox.put(json::parse(m)); });
    view.start();
    const auto near = [](const json& a, const auto& b, double tolerance) {
        if (!a.is_array() || a.size() != b.size()) return false;
        for (std::size_t i = 0; i < b.size(); ++i)
            if (!a[i].is_number() || std::abs(a[i].get<double>() - b[i]) > tolerance) return false;
        return true;
    };
    auto worldWith = [&](const std::function<bool(const json&)>& pred) {
        return inbox.waitFor(
            [&](const std::vector<json>& v) {
                return std::any_of(v.begin(), v.end(),
                                   [&](const json& m) { return m["type"] == "world" && pred(m); });
            },
            20s);
    };
    ASSERT_TRUE(worldWith([&](const json& m) {
        return near(m["joints"].value("Arm", json()), pnp::testing::kHome, 1e-6) &&
               m["models"].value("Arm", json()) == "FakeArm" &&
               near(m["bases"].value("Arm", json()), std::vector<double>(6, 0.0), 1e-12);
    })) << (inbox.items().empty() ? json() : inbox.items().back()).dump();
    EXPECT_TRUE(view.snapshot()["world"]["joints"].contains("Arm"));

    // A move: the joints in the world follow the arm to its goal.
    pnp::skill::client::JointPtpMoveSkillClient move(
        rig->ua, rig->skill(pnp::device::robot::skill_names::JointPtpMove), 5s);
    pnp::robot::Joints goal = pnp::testing::kHome;
    goal[0] += 0.4;
    goal[5] -= 0.3;
    const auto r = move.run({{goal.begin(), goal.end()}, {}, {}, ""}, 20s);
    ASSERT_EQ(r.result, pnp::skill::SkillResult::Completed) << r.message;
    EXPECT_TRUE(worldWith(
        [&](const json& m) { return near(m["joints"].value("Arm", json()), goal, 1e-4); }));

    // The robot's server goes: so does the robot.
    rig.reset();
    EXPECT_TRUE(worldWith([](const json& m) { return !m["joints"].contains("Arm"); }));
    view.stop();
}

class DashboardActions : public ::testing::Test {
  protected:
    void SetUp() override {
        auto users = std::make_shared<ua::server::UserStore>();
        users->addUser("operator", "secret", {ua::server::role::operator_()},
                       ua::server::UserStore::kMinIterations);
        ua::server::UserAccessConfig a;
        a.users = users;
        a.allowUnencryptedPasswords = true;  // loopback None channel in this test
        demo = std::make_unique<DemoServer>("urn:pnp:test:dashboard:actions",
                                            std::make_shared<ua::server::UserAccessControl>(a));
        pnp::dashboard::DashboardOptions o;
        o.web.port = 0;
        o.cell.discovery = false;
        o.cell.urls = {demo->url()};
        dashboard = std::make_unique<pnp::dashboard::Dashboard>(nullptr, o);
        dashboard->start();
        page = std::make_unique<pnp::dashboard::test::WsTestClient>(dashboard->port(), 3s);
        const auto first = page->next(3s);
        ASSERT_TRUE(first);
        ASSERT_EQ(json::parse(*first)["type"], "snapshot");
        // Until the skills are attached (parameters known).
        const auto until = std::chrono::steady_clock::now() + 10s;
        while (std::chrono::steady_clock::now() < until && delayId.empty()) {
            const json snapshot = dashboard->cell().snapshot();
            for (const auto& s : snapshot["skills"])
                if (s["name"] == "Delay" && !s["parameters"].empty()) delayId = s["id"];
            std::this_thread::sleep_for(20ms);
        }
        ASSERT_FALSE(delayId.empty()) << dashboard->cell().snapshot().dump();
    }
    void TearDown() override {
        page.reset();
        dashboard.reset();
        demo.reset();
    }
    // The reply with this id; other messages are kept in `seen`.
    // The reply to action `id`: replies come in any order (a halted run's may overtake the
    // halt's own), so one that came while waiting for another is taken from `seen`.
    json reply(int id, std::chrono::milliseconds timeout = 10s) {
        for (auto it = seen.begin(); it != seen.end(); ++it)
            if ((*it)["type"] == "reply" && (*it)["id"] == id) {
                json j = std::move(*it);
                seen.erase(it);
                return j;
            }
        const auto until = std::chrono::steady_clock::now() + timeout;
        while (std::chrono::steady_clock::now() < until) {
            const auto m = page->next(200ms);
            if (!m) continue;
            json j = json::parse(*m);
            if (j["type"] == "reply" && j["id"] == id) return j;
            seen.push_back(j);
        }
        return nullptr;
    }
    std::unique_ptr<DemoServer> demo;
    std::unique_ptr<pnp::dashboard::Dashboard> dashboard;
    std::unique_ptr<pnp::dashboard::test::WsTestClient> page;
    std::string delayId;
    std::vector<json> seen;
};

TEST_F(DashboardActions, RunConvertsParametersAndAnswersWithTheResult) {
    page->send(json{
        {"id", 1}, {"action", "run"}, {"skill", delayId}, {"parameters", {{"DurationMs", "30"}}}}
                   .dump());
    const json r = reply(1);
    ASSERT_TRUE(r.is_object());
    EXPECT_TRUE(r["ok"]) << r.dump();
    EXPECT_EQ(r["status"], "Good");
    EXPECT_EQ(r["result"]["result"], "Completed");
    // Its transitions were pushed to the page too.
    const auto until = std::chrono::steady_clock::now() + 3s;
    auto ran = [&] {
        return has(seen, [&](const json& m) {
            return m["type"] == "transition" && m["skill"] == delayId && m["to"] == "Running";
        });
    };
    while (!ran() && std::chrono::steady_clock::now() < until)
        if (auto m = page->next(100ms)) seen.push_back(json::parse(*m));
    EXPECT_TRUE(ran());
}

TEST_F(DashboardActions, BadParameterIsRefusedBeforeAnyCall) {
    page->send(json{
        {"id", 2}, {"action", "run"}, {"skill", delayId}, {"parameters", {{"DurationMs", "fast"}}}}
                   .dump());
    json r = reply(2);
    ASSERT_TRUE(r.is_object());
    EXPECT_FALSE(r["ok"]);
    EXPECT_EQ(r["status"], "BadTypeMismatch") << r.dump();
    EXPECT_NE(r["message"].get<std::string>().find("DurationMs"), std::string::npos);
    page->send(
        json{{"id", 3}, {"action", "run"}, {"skill", delayId}, {"parameters", {{"Nope", "1"}}}}
            .dump());
    r = reply(3);
    EXPECT_FALSE(r["ok"]);
    EXPECT_EQ(r["status"], "BadNotFound") << r.dump();
    // Nothing ran: no transition of the skill reached the page.
    while (auto m = page->next(300ms)) seen.push_back(json::parse(*m));
    EXPECT_FALSE(has(seen, [&](const json& m) { return m["type"] == "transition"; }));
    // Malformed requests get a reply too, and the page stays connected.
    page->send("{not json");
    EXPECT_EQ(json::parse(page->next(2s).value_or("{}"))["status"], "BadDecodingError");
    page->send(json{{"id", 4}, {"action", "explode"}}.dump());
    EXPECT_EQ(reply(4)["status"], "BadNotSupported");
    page->send(json{{"id", 5}, {"action", "halt"}, {"skill", "no such skill"}}.dump());
    EXPECT_EQ(reply(5)["status"], "BadNodeIdUnknown");
}

TEST_F(DashboardActions, HaltStopsARunningSkill) {
    page->send(json{
        {"id", 10}, {"action", "run"}, {"skill", delayId}, {"parameters", {{"DurationMs", "5000"}}}}
                   .dump());
    // Once it runs, halt it from the same page (its session holds the lock).
    const auto until = std::chrono::steady_clock::now() + 5s;
    bool running = false;
    while (!running && std::chrono::steady_clock::now() < until) {
        const auto m = page->next(100ms);
        if (!m) continue;
        const json j = json::parse(*m);
        running = j["type"] == "transition" && j["skill"] == delayId && j["to"] == "Running";
    }
    ASSERT_TRUE(running);
    page->send(json{{"id", 11}, {"action", "halt"}, {"skill", delayId}}.dump());
    const json h = reply(11);
    ASSERT_TRUE(h.is_object()) << "no reply to halt";
    EXPECT_TRUE(h["ok"]) << h.dump();
    const json r = reply(10);
    ASSERT_TRUE(r.is_object() && r.contains("result")) << r.dump();
    EXPECT_EQ(r["result"]["result"], "Aborted") << r.dump();
}

TEST_F(DashboardActions, LoginIsDecidedByTheServer) {
    page->send(
        json{{"id", 20}, {"action", "login"}, {"user", "operator"}, {"password", "wrong"}}.dump());
    const json bad = reply(20);
    EXPECT_FALSE(bad["ok"]);
    EXPECT_EQ(bad["status"], "BadUserAccessDenied") << bad.dump();
    page->send(
        json{{"id", 21}, {"action", "login"}, {"user", "operator"}, {"password", "secret"}}.dump());
    const json good = reply(21);
    EXPECT_TRUE(good["ok"]) << good.dump();
    EXPECT_EQ(good["result"]["user"], "operator");
    // The page's sessions now carry that identity: a run still works (Operator may call).
    page->send(json{
        {"id", 22}, {"action", "run"}, {"skill", delayId}, {"parameters", {{"DurationMs", "10"}}}}
                   .dump());
    EXPECT_EQ(reply(22)["result"]["result"], "Completed");
}

}  // namespace
