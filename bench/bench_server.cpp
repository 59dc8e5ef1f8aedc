// pnp_bench_server: the same server as `pnp ua serve` (full namespace 0 + the demo namespace,
// anonymous access) built only on pnp_ua_server + pnp_ua_demo, without the CLI. Used by the
// benchmark with --server bench (and to tell what the CLI itself adds to start-up and RSS).
//
//   pnp_bench_server [--host 127.0.0.1] [--port N]
//
// Prints "listening on opc.tcp://HOST:PORT" (flushed) once accepting; stops on SIGINT/SIGTERM.
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <exception>
#include <string>

#include "ua/demo/demo.hpp"
#include "ua/server/server.hpp"

int main(int argc, char** argv) {
    using namespace pnp::ua;
    std::string host = "127.0.0.1";
    int port = 0;
    for (int i = 1; i < argc; ++i) {
        std::string a = argv[i];
        if (a == "--host" && i + 1 < argc)
            host = argv[++i];
        else if (a == "--port" && i + 1 < argc)
            port = std::stoi(argv[++i]);
        else {
            std::fprintf(stderr, "usage: %s [--host ADDR] [--port N]\n", argv[0]);
            return 2;
        }
    }
    sigset_t stop;
    sigemptyset(&stop);
    sigaddset(&stop, SIGINT);
    sigaddset(&stop, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop, nullptr);
    try {
        server::ServerConfig config;
        config.host = host;
        config.publicHost = host;
        config.port = static_cast<UInt16>(port);
        server::Server server(config);
        demo::DemoNamespace demoNamespace(server);
        server.start();
        std::printf("listening on %s\n", server.endpointUrl().c_str());
        std::fflush(stdout);
        int sig = 0;
        while (sigwait(&stop, &sig) != 0) {
        }
        server.stop();
    } catch (const std::exception& e) {
        std::fprintf(stderr, "pnp_bench_server: %s\n", e.what());
        return 1;
    }
    return 0;
}
