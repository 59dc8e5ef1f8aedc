// The `pnp ua ...` subcommands. Each returns the process exit code (see output.hpp) and
// throws UsageError / ValueError for a bad command line and client::Error for OPC UA
// failures (main() turns them into exit codes 2 and 1).
#pragma once

#include <signal.h>

#include <cstdint>
#include <functional>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "security_options.hpp"

namespace CLI {
class App;
}

namespace pnp::cli {

// Discovery (Part 12) of `pnp ua serve` and `pnp lds`.
struct DiscoveryOptions {
    std::string publicHost;                   // host in endpoint URLs (default: --host or hostname)
    std::string applicationUri;               // default urn:pnp:<public host>:<port>
    std::string name;                         // ApplicationName and mDNS instance
    std::string lds;                          // register with this LDS-ME only
    bool noRegister = false;                  // do not register anywhere
    bool ldsMe = false;                       // serve: also be an LDS-ME (a workstation)
    std::string group;                        // discovery group (TXT dg=)
    int level = -1;                           // LDS-ME level (lds: 0, serve --lds-me: 1)
    std::vector<std::string> mdnsInterfaces;  // default: by the listen address
    int mdnsPort = 5353;
    int mdnsTtl = 2;  // s, of our announcements
    // LDS-ME: registration expiry. 1.8 s: a crashed server renewed last up to one
    // register interval before it died, and is gone everywhere within 2 s.
    int expiryMs = 1800;
    int registerIntervalMs = 500;  // re-registration period
    // How the server is secured (and its own connections): docs/security.md.
    SecurityOptions security;
};

struct ServeOptions {
    std::uint16_t port = 4840;
    std::string host = "0.0.0.0";
    DiscoveryOptions discovery;
    std::vector<std::string> users;  // NAME:PASSWORD
    bool noAnonymous = false;
    std::vector<std::string> nodesets;   // NodeSet2 XML files loaded at start (with their deps)
    std::vector<std::string> instances;  // TYPE=NAME: an instance of TYPE below Objects
    // `pnp demo-skills`: a skill controller of this name with the demo skills
    // (src/skill/demo); empty: none.
    std::string skillController;
};

// Options every client subcommand takes.
struct ClientOptions {
    std::string url;
    bool json = false;
    int timeoutMs = 10000;
    std::string user;  // NAME:PASSWORD, empty: anonymous
    SecurityOptions security;
};

struct BrowseOptions {
    std::string node = "i=85";  // Objects folder
    int depth = 1;
};

struct ReadOptions {
    std::vector<std::string> nodes;
    std::string attribute = "Value";
};

struct WriteOptions {
    std::string node;
    std::string value;
    std::string type;  // empty: from the node's DataType and ValueRank
};

struct CallOptions {
    std::string object;
    std::string method;
    std::vector<std::string> args;
    std::string types;  // "Int32,Int32": overrides the InputArguments
};

// Subscriptions: print notifications until Ctrl-C, --count or --duration.
struct MonitorOptions {
    std::vector<std::string> nodes;
    double interval = 100;  // publishing and sampling interval, ms
    int count = 0;          // stop after this many notifications; 0: no limit
    int durationMs = 0;     // stop after this long; 0: no limit
};

struct EventsOptions {
    std::string node = "i=2253";  // the Server object
    std::string select = "EventType,SourceName,Time,Severity,Message";
    double interval = 100;
    int count = 0;
    int durationMs = 0;
};

// `pnp discover`: servers on the network, live.
struct DiscoverOptions {
    bool json = false;
    int durationMs = 0;            // 0: until Ctrl-C
    bool once = false;             // print the list after --duration (default 2 s) and exit
    std::vector<std::string> lds;  // LDS-MEs polled in addition to mDNS
    bool noDetails = false;
    bool noMdns = false;  // poll the --lds LDS-MEs only
    std::vector<std::string> mdnsInterfaces;
    int mdnsPort = 5353;
    int pollMs = 250;
};

// `pnp skills`: the skills on the network (docs/skills.md), live or --once.
struct SkillsOptions {
    bool json = false;
    bool once = false;
    int durationMs = 0;             // 0: until Ctrl-C (--once: until examined, docs/skills.md)
    std::vector<std::string> lds;   // LDS-MEs polled in addition to mDNS
    std::vector<std::string> urls;  // servers examined directly (no discovery needed)
    bool noMdns = false;
    std::vector<std::string> mdnsInterfaces;
    int mdnsPort = 5353;
    std::string type;  // only skills of this type (or a subtype)
    SecurityOptions security;
};

// `pnp skill run URL|TYPE [name=value ...]`: runs one skill and prints its transitions.
struct SkillRunOptions {
    std::string target;                    // opc.tcp://... or a skill type name
    std::vector<std::string> assignments;  // Name=value
    std::string skill;                     // the instance's name (BrowseName), if several
    bool json = false;
    int timeoutMs = 30000;  // the whole run
    std::vector<std::string> lds;
    bool noMdns = false;
    int mdnsPort = 5353;
    int discoverMs = 3000;  // how long to look for a skill of TYPE
    int repeat = 1;         // runs in a row on one connection (a soak test: a summary only)
    SecurityOptions security;
};
// Exit code of a run that ended Failed, Aborted or timed out.
inline constexpr int kExitSkillFailed = 3;

int runSkills(const SkillsOptions& options);
int runSkillRun(const SkillRunOptions& options);
int runServe(const ServeOptions& options);
int runLds(std::uint16_t port, const std::string& host, const DiscoveryOptions& options);
int runDiscover(const DiscoverOptions& options);
int runEndpoints(const ClientOptions& client);
int runBrowse(const ClientOptions& client, const BrowseOptions& options);
int runRead(const ClientOptions& client, const ReadOptions& options);
int runWrite(const ClientOptions& client, const WriteOptions& options);
int runCall(const ClientOptions& client, const CallOptions& options);
int runMonitor(const ClientOptions& client, const MonitorOptions& options);
int runEvents(const ClientOptions& client, const EventsOptions& options);

// `pnp device robotiq | wsg | ecbpi` below `device` (gripper_commands.cpp); the runner
// returns -1 when none of them was chosen.
std::function<int()> addGripperDeviceCommands(CLI::App* device);

// Blocks SIGINT and SIGTERM in the calling thread (call before any thread exists: every
// thread inherits the mask) and returns them, for sigwait() / sigtimedwait().
sigset_t blockStopSignals();

// SIGINT / SIGTERM as a stop request: blocks them (construct before any thread exists) and a
// thread of its own takes them, calling onSignal (if any) for each. For commands that end
// what they are doing cleanly on Ctrl-C (halt a skill, stop a cell's children).
class StopOnSignal {
  public:
    explicit StopOnSignal(std::function<void(int signal)> onSignal = {});
    std::stop_token token() const { return stop_.get_token(); }

  private:
    sigset_t signals_;
    std::stop_source stop_;
    std::function<void(int)> onSignal_;
    std::jthread watcher_;  // last: stopped and joined first
};

// "NAME:PASSWORD" -> {NAME, PASSWORD}; throws UsageError.
std::pair<std::string, std::string> splitUser(const std::string& text);

}  // namespace pnp::cli
