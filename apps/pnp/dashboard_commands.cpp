// `pnp dashboard`: the live web dashboard of the cell (docs/dashboard.md, src/dashboard).
#include <signal.h>

#include <CLI/CLI.hpp>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#ifdef PNP_HAVE_DASHBOARD
#include "dashboard/dashboard.hpp"
#endif

namespace pnp::cli {

namespace {

struct DashboardCliOptions {
    std::uint16_t port = 8080;
    std::string host = "127.0.0.1";
    std::vector<std::string> lds;
    std::vector<std::string> urls;
    std::string world;
    bool noMdns = false;
    std::vector<std::string> mdnsInterfaces;
    int mdnsPort = 5353;
    std::string assets;
    SecurityOptions security;
};

#ifdef PNP_HAVE_DASHBOARD
int runDashboard(const DashboardCliOptions& o) {
    const sigset_t stopSignals = blockStopSignals();  // before any thread exists
    if (o.noMdns && o.lds.empty() && o.urls.empty())
        throw UsageError("--no-mdns needs an --lds or --url");
    secureClients(o.security);  // the dashboard's sessions are secured like every pnp client
    std::unique_ptr<mdns::Mdns> mdns;
    if (!o.noMdns) {
        try {
            mdns = std::make_unique<mdns::Mdns>(mdnsConfig(o.mdnsInterfaces, o.mdnsPort, 120));
            mdns->start();
        } catch (const std::exception& e) {
            if (o.lds.empty() && o.urls.empty()) throw;
            std::cerr << "pnp dashboard: no mDNS (" << e.what() << ")" << std::endl;
            mdns.reset();
        }
    }
    dashboard::DashboardOptions d;
    d.web.host = o.host;
    d.web.port = o.port;
    d.web.assets = o.assets.empty() ? std::string(PNP_DASHBOARD_ASSETS) : o.assets;
    d.cell.ldsUrls = o.lds;
    d.cell.urls = o.urls;
    d.cell.worldUrl = o.world;
    d.cell.discovery = mdns != nullptr || !o.lds.empty();
    dashboard::Dashboard dash(mdns.get(), d);
    try {
        dash.start();
    } catch (const std::runtime_error& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUaError;
    }
    std::error_code ec;
    if (!std::filesystem::exists(d.web.assets / "index.html", ec))
        std::cerr << "pnp dashboard: no page in " << d.web.assets.string()
                  << " (build the web assets or pass --assets DIR)" << std::endl;
    std::cout << "dashboard on http://" << o.host << ":" << dash.port() << "/" << std::endl;
    int sig = 0;
    while (sigwait(&stopSignals, &sig) != 0) {
    }
    dash.stop();
    return kExitOk;
}
#endif

}  // namespace

std::function<int()> addDashboardCommand(CLI::App& app) {
    auto o = std::make_shared<DashboardCliOptions>();
    CLI::App* cmd = app.add_subcommand(
        "dashboard",
        "the live web dashboard: servers, components, skills, the process and a 3D view of the "
        "cell in a browser (docs/dashboard.md)");
    cmd->add_option("--port", o->port, "HTTP + WebSocket port (0: any free port)")
        ->capture_default_str();
    cmd->add_option("--host", o->host, "address to listen on")->capture_default_str();
    cmd->add_option("--lds", o->lds, "poll this LDS-ME (repeatable)");
    cmd->add_option("--url", o->urls, "also watch this server directly (repeatable)");
    cmd->add_option("--world", o->world,
                    "the simulator's ground truth server (urn:pnp:sim:world), for the 3D view");
    cmd->add_flag("--no-mdns", o->noMdns, "no multicast: --lds / --url only");
    cmd->add_option("--mdns-interface", o->mdnsInterfaces,
                    "mDNS on this interface (repeatable; default all)");
    cmd->add_option("--mdns-port", o->mdnsPort, "mDNS UDP port")
        ->capture_default_str()
        ->check(CLI::Range(1, 65535));
    cmd->add_option("--assets", o->assets, "the page's files (default: the build's web/dashboard)");
    addConnectionSecurityOptions(cmd, o->security);
    cmd->footer(
        "Prints `dashboard on http://HOST:PORT/` once ready; stops on SIGINT/SIGTERM.\n"
        "Example: pnp dashboard --lds opc.tcp://127.0.0.1:4840 --world opc.tcp://127.0.0.1:4850");
    return [o, cmd]() -> int {
        if (!*cmd) return -1;
#ifdef PNP_HAVE_DASHBOARD
        return runDashboard(*o);
#else
        std::cerr << "error: this pnp was built without the dashboard (no websocketpp headers)\n";
        return kExitUsage;
#endif
    };
}

}  // namespace pnp::cli
