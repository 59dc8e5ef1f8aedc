// `pnp ua serve`: namespace 0 plus the demo namespace until SIGINT / SIGTERM.
#include <pthread.h>
#include <signal.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <map>
#include <memory>

#include "commands.hpp"
#include "output.hpp"
#include "ua/demo/demo.hpp"
#include "ua/server/server.hpp"

namespace pnp::cli {

std::pair<std::string, std::string> splitUser(const std::string& text) {
    auto colon = text.find(':');
    if (colon == std::string::npos || colon == 0)
        throw UsageError("--user expects NAME:PASSWORD, got \"" + text + "\"");
    return {text.substr(0, colon), text.substr(colon + 1)};
}

int runServe(const ServeOptions& o) {
    using namespace pnp::ua;
    std::map<std::string, std::string> users;
    for (const auto& u : o.users) {
        auto [name, password] = splitUser(u);
        users[name] = password;
    }
    if (o.noAnonymous && users.empty())
        throw UsageError("--no-anonymous needs at least one --user NAME:PASSWORD");

    // Block the stop signals before any thread exists: every thread inherits the mask and
    // this thread takes them synchronously with sigwait().
    sigset_t stopSignals;
    sigemptyset(&stopSignals);
    sigaddset(&stopSignals, SIGINT);
    sigaddset(&stopSignals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stopSignals, nullptr);

    server::ServerConfig config;
    config.host = o.host;
    config.port = o.port;
    if (o.host != "0.0.0.0" && o.host != "::" && !o.host.empty()) config.publicHost = o.host;
    config.accessControl =
        std::make_shared<server::DefaultAccessControl>(!o.noAnonymous, std::move(users));

    server::Server server(config);
    // Declared after the server, so destroyed first: pending Demo.Sleep calls are completed
    // (BadShutdown) while the transport still exists.
    demo::DemoNamespace demoNamespace(server);
    try {
        server.start();
    } catch (const std::exception& e) {
        std::cerr << "error: cannot listen on " << o.host << ":" << o.port << ": " << e.what()
                  << "\n";
        return kExitUaError;
    }
    std::cout << "listening on " << server.endpointUrl() << std::endl;  // flushed
    std::cerr << "pnp ua serve: namespace " << demo::kNamespaceUri
              << " is ns=" << demoNamespace.namespaceIndex() << "; anonymous "
              << (o.noAnonymous ? "refused" : "allowed") << "; " << o.users.size()
              << " user(s); stop with Ctrl-C or SIGTERM" << std::endl;

    int sig = 0;
    while (sigwait(&stopSignals, &sig) != 0) {
    }
    std::cerr << "pnp ua serve: " << (sig == SIGINT ? "SIGINT" : "SIGTERM") << ", stopping"
              << std::endl;
    server.stop();
    return kExitOk;
}

}  // namespace pnp::cli
