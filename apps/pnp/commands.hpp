// The `pnp ua ...` subcommands. Each returns the process exit code (see output.hpp) and
// throws UsageError / ValueError for a bad command line and client::Error for OPC UA
// failures (main() turns them into exit codes 2 and 1).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace pnp::cli {

struct ServeOptions {
    std::uint16_t port = 4840;
    std::string host = "0.0.0.0";
    std::vector<std::string> users;  // NAME:PASSWORD
    bool noAnonymous = false;
    std::vector<std::string> nodesets;   // NodeSet2 XML files loaded at start (with their deps)
    std::vector<std::string> instances;  // TYPE=NAME: an instance of TYPE below Objects
};

// Options every client subcommand takes.
struct ClientOptions {
    std::string url;
    bool json = false;
    int timeoutMs = 10000;
    std::string user;  // NAME:PASSWORD, empty: anonymous
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

int runServe(const ServeOptions& options);
int runEndpoints(const ClientOptions& client);
int runBrowse(const ClientOptions& client, const BrowseOptions& options);
int runRead(const ClientOptions& client, const ReadOptions& options);
int runWrite(const ClientOptions& client, const WriteOptions& options);
int runCall(const ClientOptions& client, const CallOptions& options);
int runMonitor(const ClientOptions& client, const MonitorOptions& options);
int runEvents(const ClientOptions& client, const EventsOptions& options);

// "NAME:PASSWORD" -> {NAME, PASSWORD}; throws UsageError.
std::pair<std::string, std::string> splitUser(const std::string& text);

}  // namespace pnp::cli
