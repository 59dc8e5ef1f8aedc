// `pnp ua serve`: namespace 0, the demo namespace and the NodeSet2 files given with
// --nodeset (loaded from XML only when asked: the default start-up path stays XML-free)
// until SIGINT / SIGTERM.
#include <pthread.h>
#include <signal.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <map>
#include <memory>

#include "commands.hpp"
#include "discovery_commands.hpp"
#include "output.hpp"
#include "skill/demo/demo_skills.hpp"
#include "ua/demo/demo.hpp"
#include "ua/server/nodeset_xml.hpp"
#include "ua/server/server.hpp"
#include "ua/types/ns0_ids_objects.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::cli {

sigset_t blockStopSignals() {
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &set, nullptr);
    return set;
}

StopOnSignal::StopOnSignal(std::function<void(int)> onSignal)
    : signals_(blockStopSignals()), onSignal_(std::move(onSignal)) {
    watcher_ = std::jthread([this](std::stop_token done) {
        const timespec tick{0, 100'000'000};
        while (!done.stop_requested()) {
            const int sig = sigtimedwait(&signals_, nullptr, &tick);
            if (sig == SIGINT || sig == SIGTERM) {
                if (onSignal_) onSignal_(sig);
                stop_.request_stop();
            }
        }
    });
}

std::pair<std::string, std::string> splitUser(const std::string& text) {
    auto colon = text.find(':');
    if (colon == std::string::npos || colon == 0)
        throw UsageError("--user expects NAME:PASSWORD, got \"" + text + "\"");
    return {text.substr(0, colon), text.substr(colon + 1)};
}

namespace {

// --nodeset files (reporting the load time of each file) and --instance TYPE=NAME.
void loadModels(ua::server::AddressSpace& space, const ServeOptions& o) {
    using namespace pnp::ua;
    for (const auto& file : o.nodesets)
        for (const auto& r : server::loadNodeSetXml(space, file)) {
            std::cerr << "pnp ua serve: loaded " << r.file.string() << " (" << r.modelUri
                      << "): " << r.nodes << " nodes in " << r.loadMs << " ms";
            if (!r.warnings.empty()) std::cerr << ", " << r.warnings.size() << " warning(s)";
            std::cerr << std::endl;
        }
    for (const auto& spec : o.instances) {
        auto eq = spec.rfind('=');
        if (eq == std::string::npos || eq == 0 || eq + 1 == spec.size())
            throw UsageError("--instance expects TYPE=NAME, got \"" + spec + "\"");
        auto type = ExpandedNodeId::parse(spec.substr(0, eq));
        if (!type) throw UsageError("--instance: bad type NodeId \"" + spec.substr(0, eq) + "\"");
        NodeId typeId = type->nodeId;
        if (!type->namespaceUri.empty()) {
            auto ns = space.namespaceIndex(type->namespaceUri);
            if (!ns)
                throw UsageError("--instance: namespace " + type->namespaceUri + " is not loaded");
            typeId.setNamespaceIndex(*ns);
        }
        const std::string name = spec.substr(eq + 1);
        space.instantiate(NodeId(0, ua::ns0::ObjectsFolder), typeId, NodeId(1, name),
                          QualifiedName{1, name});
    }
}

}  // namespace

int runServe(const ServeOptions& o) {
    using namespace pnp::ua;
    std::map<std::string, std::string> users;
    for (const auto& u : o.users) {
        auto [name, password] = splitUser(u);
        users[name] = password;
    }
    if (o.noAnonymous && users.empty() && o.discovery.security.users.empty())
        throw UsageError("--no-anonymous needs at least one --user NAME:PASSWORD or --users FILE");
    if (!o.discovery.security.users.empty() && !users.empty())
        throw UsageError("--user and --users exclude each other");

    // Block the stop signals before any thread exists: every thread inherits the mask and
    // this thread takes them synchronously with sigwait().
    const sigset_t stopSignals = blockStopSignals();

    server::ServerConfig config;
    config.host = o.host;
    config.port = o.port;
    try {
        applyDiscoveryConfig(config, o.discovery, false);
    } catch (const ua::pki::PkiError& e) {
        std::cerr << "error: PKI folder " << pkiFolder(o.discovery.security) << ": " << e.what()
                  << "\n";
        return kExitUaError;
    }
    if (!applyUsers(config, o.discovery.security, !o.noAnonymous))
        config.accessControl =
            std::make_shared<server::DefaultAccessControl>(!o.noAnonymous, std::move(users));

    server::Server server(config);
    // Declared after the server, so destroyed first: pending Demo.Sleep calls are completed
    // (BadShutdown) while the transport still exists.
    demo::DemoNamespace demoNamespace(server);
    std::unique_ptr<pnp::skill::server::SkillController> skills;
    try {
        loadModels(server.addressSpace(), o);
        if (!o.skillController.empty())
            skills = pnp::skill::demo::addDemoSkills(server, o.skillController);
        finishServerSecurity(server, o.discovery.security);
    } catch (const std::exception& e) {
        std::cerr << "error: " << e.what() << "\n";
        return kExitUaError;
    }
    try {
        server.start();
    } catch (const std::exception& e) {
        std::cerr << "error: cannot listen on " << o.host << ":" << o.port << ": " << e.what()
                  << "\n";
        return kExitUaError;
    }
    std::cout << "listening on " << server.endpointUrl() << std::endl;  // flushed
    std::unique_ptr<DiscoveryRuntime> discovery;
    try {
        discovery = std::make_unique<DiscoveryRuntime>(server, o.discovery);
    } catch (const std::exception& e) {
        std::cerr << "error: discovery: " << e.what() << "\n";
        server.stop();
        return kExitUaError;
    }
    std::cerr << "pnp ua serve: namespace " << demo::kNamespaceUri
              << " is ns=" << demoNamespace.namespaceIndex() << "; anonymous "
              << (o.noAnonymous ? "refused" : "allowed") << "; "
              << (o.discovery.security.users.empty() ? std::to_string(o.users.size()) + " user(s)"
                                                     : "users of " + o.discovery.security.users)
              << (config.security
                      ? "; secured endpoints (PKI " + pkiFolder(o.discovery.security) + ")"
                      : "; SecurityPolicy None only")
              << "; " << discovery->status() << "; stop with Ctrl-C or SIGTERM" << std::endl;
    if (skills)
        std::cerr << "pnp demo-skills: skill controller " << o.skillController
                  << " with the skills Delay, Grasp, Release, MoveGripper (models "
                  << pnp::skill::kBaseUri << ", " << pnp::skill::kDemoUri << ")" << std::endl;

    int sig = 0;
    while (sigwait(&stopSignals, &sig) != 0) {
    }
    std::cerr << "pnp ua serve: " << (sig == SIGINT ? "SIGINT" : "SIGTERM") << ", stopping"
              << std::endl;
    discovery.reset();  // unregisters first: the server disappears everywhere at once
    skills.reset();     // halts running skills and joins their workers
    server.stop();
    return kExitOk;
}

}  // namespace pnp::cli
