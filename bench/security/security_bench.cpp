// The cost of security on the wire (issue 24's targets), everything measured in one run on
// one machine so that the ratios mean something on a noisy VM:
//   (a) Call Demo.Echo round trip, SignAndEncrypt vs None, at 2 B .. 32 KiB, per policy; next
//       to it the time the same OpenSSL primitives take for the same bytes (both messages of
//       the round trip: sign + encrypt, decrypt + verify, twice), measured here too;
//   (b) OpenSecureChannel + CreateSession + ActivateSession with 2048-bit keys (connect()),
//       next to the same with SecurityPolicy None.
// Server and client in this process on 127.0.0.1 (one connection). Medians of interleaved
// rounds. Usage: pnp_bench_security [--iterations N] [--rounds R] [--policy NAME]
//   [--connects N] [--sizes B,B,..] [--csv FILE] [--serve PORT | --url URL]
//   --policy: one policy only (e.g. Basic256Sha256; also the handshake's policy);
//   --sizes: the Echo sizes (default 2,1024,8192,32768; e.g. 2 alone for a profile);
//   --only none|secured: only these Echo calls, no primitives (to profile one mode);
//   --csv: also append the results as CSV rows (bench/security/compare_open62541.sh);
//   --serve: only the server, on 127.0.0.1:PORT, until SIGINT/SIGTERM; --url: only the client,
//   against such a server in another process (as an open62541 client and server run).
#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "ua/client/client.hpp"
#include "ua/crypto/crypto.hpp"
#include "ua/demo/demo.hpp"
#include "ua/pki/pki.hpp"
#include "ua/server/server.hpp"

using namespace pnp::ua;
using Clock = std::chrono::steady_clock;

namespace {

double median(std::vector<double> v) {
    if (v.empty()) return 0;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
}

pki::Identity identity(const std::string& uri) {
    pki::CertificateRequest r;
    r.applicationUri = uri;
    r.commonName = uri;
    r.dnsNames = {"localhost"};
    return pki::createSelfSigned(r);
}

// Median µs of one Echo round trip with `bytes` bytes, over `n` calls.
double echoRtt(client::Client& c, UInt16 ns, std::size_t bytes, int n) {
    const NodeId object(ns, "Demo");
    const NodeId method(ns, "Demo.Echo");
    ByteString data(std::string(bytes, 'x'));
    std::vector<double> t;
    t.reserve(static_cast<std::size_t>(n));
    for (int i = 0; i < n + 20; ++i) {
        const auto t0 = Clock::now();
        auto r = c.call(object, method, {Variant(data)});
        const auto t1 = Clock::now();
        if (r.status.isBad()) {
            std::fprintf(stderr, "Echo failed: %s\n", r.status.toString().c_str());
            std::exit(1);
        }
        if (i >= 20) t.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    }
    return median(t);
}

// Median µs the primitives of one round trip take: request and response each signed and
// encrypted by one side, decrypted and verified by the other (the message sizes of the Call:
// body + ~100 bytes of headers, padded to the block).
double primitives(const crypto::SecurityPolicy& policy, std::size_t bytes, int n) {
    const auto keys = crypto::deriveKeys(policy, crypto::randomBytes(32), crypto::randomBytes(32));
    crypto::SymmetricCipher sender(policy, keys), receiver(policy, keys);
    const std::size_t size = (bytes + 100 + 33 + 15) / 16 * 16;
    std::vector<std::uint8_t> msg(size + 32, 0x5a);
    std::vector<double> t;
    for (int i = 0; i < n + 20; ++i) {
        const auto t0 = Clock::now();
        for (int dir = 0; dir < 2; ++dir) {
            sender.sign(crypto::ByteView(msg.data(), size - 32), msg.data() + size - 32);
            sender.encrypt(std::span<std::uint8_t>(msg.data(), size));
            receiver.decrypt(std::span<std::uint8_t>(msg.data(), size));
            if (!receiver.verify(crypto::ByteView(msg.data(), size - 32),
                                 crypto::ByteView(msg.data() + size - 32, 32))) {
                std::fprintf(stderr, "primitive round trip did not verify\n");
                std::exit(1);
            }
        }
        const auto t1 = Clock::now();
        if (i >= 20) t.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    }
    return median(t);
}

// The policy named NAME (the part of its URI after '#'), or null.
const crypto::SecurityPolicy* policyNamed(const std::string& name) {
    for (const auto& p : crypto::securityPolicies())
        if (p.uri.substr(p.uri.find('#') + 1) == name) return &p;
    return nullptr;
}

}  // namespace

int main(int argc, char** argv) {
    int iterations = 2000;
    int rounds = 5;
    int connects = 30;
    std::string policyFilter, csvPath, remoteUrl, onlyMode;
    int servePort = -1;
    std::vector<std::size_t> sizes = {2, 1024, 8192, 32768};
    for (int i = 1; i + 1 < argc; i += 2) {
        if (std::strcmp(argv[i], "--iterations") == 0) iterations = std::stoi(argv[i + 1]);
        if (std::strcmp(argv[i], "--rounds") == 0) rounds = std::stoi(argv[i + 1]);
        if (std::strcmp(argv[i], "--connects") == 0) connects = std::stoi(argv[i + 1]);
        if (std::strcmp(argv[i], "--policy") == 0) policyFilter = argv[i + 1];
        if (std::strcmp(argv[i], "--csv") == 0) csvPath = argv[i + 1];
        if (std::strcmp(argv[i], "--serve") == 0) servePort = std::stoi(argv[i + 1]);
        if (std::strcmp(argv[i], "--url") == 0) remoteUrl = argv[i + 1];
        if (std::strcmp(argv[i], "--only") == 0) onlyMode = argv[i + 1];
        if (std::strcmp(argv[i], "--sizes") == 0) {
            sizes.clear();
            for (const char* p = argv[i + 1]; *p != '\0' && sizes.size() < 16;) {
                char* end = nullptr;
                sizes.push_back(std::strtoul(p, &end, 10));
                p = (*end == ',') ? end + 1 : end;
                if (end == p && *p != '\0') break;  // not a number
            }
        }
    }
    if (!onlyMode.empty() && onlyMode != "none" && onlyMode != "secured") {
        std::fprintf(stderr, "--only: none or secured\n");
        return 2;
    }
    if (sizes.empty()) {
        std::fprintf(stderr, "--sizes: no size\n");
        return 2;
    }
    for (std::size_t bytes : sizes) {
        if (bytes < 1 || bytes > (std::size_t{1} << 20)) {
            std::fprintf(stderr, "--sizes: each 1 .. 1048576 bytes\n");
            return 2;
        }
    }
    if (rounds < 1 || rounds > 1000 || iterations < rounds || iterations > 10'000'000 ||
        connects < 1 || connects > 10'000 || servePort > 65535) {
        std::fprintf(stderr, "bad --iterations / --rounds / --connects / --serve\n");
        return 2;
    }
    const crypto::SecurityPolicy* onlyPolicy = nullptr;
    if (!policyFilter.empty() && !(onlyPolicy = policyNamed(policyFilter))) {
        std::fprintf(stderr, "unknown --policy %s\n", policyFilter.c_str());
        return 2;
    }
    std::FILE* csv = nullptr;
    if (!csvPath.empty() && !(csv = std::fopen(csvPath.c_str(), "a"))) {
        std::perror(csvPath.c_str());
        return 1;
    }
    const auto clientId = identity("urn:pnp:bench:client");

    // SIGINT/SIGTERM blocked before any thread starts, so that --serve waits for them here.
    sigset_t stopSignals;
    sigemptyset(&stopSignals);
    sigaddset(&stopSignals, SIGINT);
    sigaddset(&stopSignals, SIGTERM);
    if (servePort >= 0) pthread_sigmask(SIG_BLOCK, &stopSignals, nullptr);

    std::unique_ptr<server::Server> ownServer;
    std::unique_ptr<demo::DemoNamespace> ownDemo;
    if (remoteUrl.empty()) {
        server::ServerConfig sc;
        sc.host = "127.0.0.1";
        if (servePort >= 0) sc.publicHost = "127.0.0.1";  // the URL printed for the client
        sc.port = static_cast<UInt16>(servePort > 0 ? servePort : 0);
        sc.applicationUri = "urn:pnp:bench:server";
        server::ServerSecurity security;
        security.identity = identity("urn:pnp:bench:server");
        security.offerNone = true;  // the baseline on the same server
        sc.security = security;
        ownServer = std::make_unique<server::Server>(sc);
        ownDemo = std::make_unique<demo::DemoNamespace>(*ownServer);
        ownServer->start();
    }
    const std::string url = remoteUrl.empty() ? ownServer->endpointUrl() : remoteUrl;
    if (servePort >= 0) {
        std::printf("listening on %s\n", url.c_str());
        std::fflush(stdout);
        int received = 0;
        sigwait(&stopSignals, &received);
        ownServer->stop();
        return 0;
    }

    auto makeClient = [&](const crypto::SecurityPolicy* policy) {
        client::ClientConfig cc;
        cc.applicationUri = "urn:pnp:bench:client";
        if (policy) {
            client::ClientSecurity cs;
            cs.identity = clientId;
            cs.policyUri = std::string(policy->uri);
            cc.security = cs;
        }  // else: a client without security, on the server's None endpoint
        return cc;
    };

    std::printf("%-24s %8s %12s %12s %12s %8s %14s\n", "policy (SignAndEncrypt)", "bytes",
                "None µs", "secured µs", "crypto µs", "ratio", "vs None+crypto");
    for (const auto& policy : crypto::securityPolicies()) {
        if (onlyPolicy && onlyPolicy != &policy) continue;
        for (std::size_t bytes : sizes) {
            std::vector<double> none, secured, prim;
            for (int r = 0; r < rounds; ++r) {
                if (onlyMode != "secured") {
                    client::Client c(makeClient(nullptr));
                    c.connect(url);
                    const UInt16 ns = static_cast<UInt16>(c.namespaceIndex(demo::kNamespaceUri));
                    none.push_back(echoRtt(c, ns, bytes, iterations / rounds));
                }
                if (onlyMode != "none") {
                    client::Client c(makeClient(&policy));
                    c.connect(url);
                    const UInt16 ns = static_cast<UInt16>(c.namespaceIndex(demo::kNamespaceUri));
                    secured.push_back(echoRtt(c, ns, bytes, iterations / rounds));
                }
                if (onlyMode.empty())
                    prim.push_back(primitives(policy, bytes, iterations / rounds));
            }
            const double n = median(none), s = median(secured), p = median(prim);
            const std::string name(policy.uri.substr(policy.uri.find('#') + 1));
            std::printf("%-24s %8zu %12.1f %12.1f %12.1f %8.2f %14.2f\n", name.c_str(), bytes, n, s,
                        p, s / n, s / (n + p));
            if (csv)
                std::fprintf(csv, "echo,pnp,%s,%zu,%.2f,%.2f,%.2f\n", name.c_str(), bytes, n, s, p);
        }
    }

    // (b) connect: OpenSecureChannel + CreateSession + ActivateSession (+ GetEndpoints first
    // for the secured one, which a client that knows the endpoint skips; reported apart).
    const crypto::SecurityPolicy& handshakePolicy =
        onlyPolicy ? *onlyPolicy : crypto::securityPolicies()[1];  // default: Basic256Sha256
    const std::string handshakeName(handshakePolicy.uri.substr(handshakePolicy.uri.find('#') + 1));
    std::vector<double> noneConnect, securedConnect, getEndpoints;
    for (int i = 0; i < connects; ++i) {
        {
            client::Client c(makeClient(nullptr));
            const auto t0 = Clock::now();
            c.connect(url);
            noneConnect.push_back(
                std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        }
        {
            client::Client probe(makeClient(nullptr));
            const auto t0 = Clock::now();
            probe.getEndpoints(url);
            getEndpoints.push_back(
                std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        }
        {
            client::Client c(makeClient(&handshakePolicy));
            const auto t0 = Clock::now();
            c.connect(url);
            securedConnect.push_back(
                std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        }
    }
    std::printf("\nconnect (OPN + CreateSession + ActivateSession), median ms:\n");
    std::printf(
        "  None %.2f | %s SignAndEncrypt, 2048-bit keys %.2f (of which "
        "GetEndpoints ~%.2f) -> handshake %.2f ms (target <= 5)\n",
        median(noneConnect), handshakeName.c_str(), median(securedConnect), median(getEndpoints),
        median(securedConnect) - median(getEndpoints));
    if (csv) {
        std::fprintf(csv, "connect,pnp,%s,%.3f,%.3f,%.3f,%.3f\n", handshakeName.c_str(),
                     median(noneConnect), median(securedConnect), median(getEndpoints),
                     median(securedConnect) - median(getEndpoints));
        std::fclose(csv);
    }
    if (ownServer) ownServer->stop();
    return 0;
}
