// What the device and component commands share (`pnp device ur | kelvin-adc | robotiq | wsg
// | ecbpi`, `pnp component toolchanger`): their OPC UA server's options and config, the frame
// options, and the life of a device on its own server until SIGINT / SIGTERM.
#pragma once

#include <signal.h>

#include <Eigen/Geometry>
#include <exception>
#include <iostream>
#include <memory>
#include <string>

#include "commands.hpp"
#include "discovery_commands.hpp"
#include "mdns/mdns.hpp"
#include "output.hpp"
#include "ua/server/server.hpp"

namespace CLI {
class App;
}

namespace pnp::cli {

// The server's options: the OPC UA port (`portNames`, e.g. "--port,--ua-port"), --host and
// the discovery options.
void addServerOptions(CLI::App* cmd, ServeOptions& serve, const std::string& portNames = "--port",
                      const std::string& portHelp = "OPC UA TCP port (0: any free port)");

// The server's config from those options: listen address, ApplicationUri, name, discovery.
ua::server::ServerConfig serverConfig(const ServeOptions& serve);

// "x,y,z,a,b,c": six finite numbers (m, rad about the fixed X, Y, Z axes); a UsageError
// naming `option` otherwise.
Eigen::Isometry3d parseFrame(const std::string& option, const std::string& text);

// A component's own mDNS browser for its skill detector (the server's responder is
// DiscoveryRuntime's): null with --no-mdns, or when mDNS cannot start (said on stderr as
// "`who`: no mDNS (why); only --lds and the given URLs").
std::unique_ptr<mdns::Mdns> componentMdns(bool noMdns, const ServeOptions& serve,
                                          const std::string& who);

// Waits for SIGINT / SIGTERM (blocked by blockStopSignals()) and says "`who`: SIGINT, stopping".
void waitForStopSignal(const sigset_t& stopSignals, const std::string& who);

// A device or component on its own server, until SIGINT / SIGTERM: `make(server)` builds it
// (a unique_ptr; its nodes exist before the server starts), the server starts, then the
// object's start() if it has one (its threads); `listening on URL` on stdout, registration
// with discovery, then `started(object, discovery status)` says what runs. At the end it
// unregisters first (gone everywhere at once), destroys the object (halting what it runs)
// and stops the server. Returns the exit code.
template <class Make, class Started>
int serveUntilStopped(const ServeOptions& serve, const sigset_t& stopSignals,
                      const std::string& who, Make make, Started started) {
    ua::server::ServerConfig config = serverConfig(serve);
    applyUsers(config, serve.discovery.security, true);
    ua::server::Server server(config);
    decltype(make(server)) object;
    try {
        object = make(server);
        finishServerSecurity(server, serve.discovery.security);
        server.start();
        if constexpr (requires { object->start(); }) object->start();
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        object.reset();
        return kExitUaError;
    }
    std::cout << "listening on " << server.endpointUrl() << std::endl;  // flushed: scripts wait
    std::unique_ptr<DiscoveryRuntime> discovery;
    try {
        discovery = std::make_unique<DiscoveryRuntime>(server, serve.discovery);
    } catch (const std::exception& e) {
        std::cerr << "error: discovery: " << e.what() << "\n";
        object.reset();
        server.stop();
        return kExitUaError;
    }
    started(*object, discovery->status());
    waitForStopSignal(stopSignals, who);
    discovery.reset();
    object.reset();
    server.stop();
    return kExitOk;
}

}  // namespace pnp::cli
