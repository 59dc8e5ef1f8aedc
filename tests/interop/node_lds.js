"use strict";
// node-opcua's Local Discovery Server (node-opcua-server-discovery, OPCUADiscoveryServer) for
// the discovery interop tests (tests/discovery/discovery_interop_netns_test.cpp), or a
// node-opcua server registering itself with an LDS.
//
//   node node_lds.js lds PORT HOST
//       the LDS on PORT, endpoint URL opc.tcp://HOST:PORT; announces itself by mDNS (bonjour,
//       UDP 5353, caps=LDS, path=/DiscoveryServer) and browses _opcua-tcp._tcp for its
//       FindServersOnNetwork; RegisterServer(2) accepted over SecurityPolicy None
//       (allowUnsecuredRegistration).
//   node node_lds.js server PORT HOST LDS_URL
//       an OPCUAServer on PORT (ApplicationUri urn:pnp:node-opcua-registering-server) that
//       registers with LDS_URL (RegisterServerMethod.LDS).
//
// Prints `listening on opc.tcp://HOST:PORT` once ready; stops on SIGTERM / SIGINT (the LDS
// sends its mDNS goodbyes, the server unregisters).
const { out, certificateManager, shutDownOnSignals } = require("./common");
const { OPCUADiscoveryServer } = require("node-opcua-server-discovery");
const { OPCUAServer, RegisterServerMethod, MessageSecurityMode, SecurityPolicy } = require("node-opcua");

const log = (...a) => console.error("[node_lds]", ...a);

function usage() {
    console.error("usage: node_lds.js lds PORT HOST | node_lds.js server PORT HOST LDS_URL");
    process.exit(2);
}

async function main() {
    const [mode, portText, host, ldsUrl] = process.argv.slice(2);
    const port = parseInt(portText || "", 10);
    if (!Number.isInteger(port) || port <= 0 || port > 65535 || !host) usage();
    // SecurityPolicy None only, a PKI of its own under $PNP_NODE_PKI_DIR.
    const common = (kind) => ({
        port,
        hostname: host,
        serverCertificateManager: certificateManager(kind),
        securityModes: [MessageSecurityMode.None],
        securityPolicies: [SecurityPolicy.None],
    });
    let server;
    if (mode === "lds") {
        server = new OPCUADiscoveryServer({
            ...common("lds"),
            allowUnsecuredRegistration: true,
            automaticallyAcceptUnknownCertificate: true,
        });
        server.on("onRegisterServer", (s, first) => log("registered", s.serverUri, first));
        server.on("onUnregisterServer", (s, forced) => log("unregistered", s.serverUri, forced));
        server.on("onRegistrationRefused", (s, info) => log("refused", s.serverUri, info.statusCode.toString()));
    } else if (mode === "server") {
        if (!ldsUrl || !ldsUrl.startsWith("opc.tcp://")) usage();
        server = new OPCUAServer({
            ...common("registering-server"),
            serverInfo: {
                applicationUri: "urn:pnp:node-opcua-registering-server",
                applicationName: { text: "node-opcua-registering-server" },
            },
            registerServerMethod: RegisterServerMethod.LDS,
            discoveryServerEndpointUrl: ldsUrl,
        });
        server.on("serverRegistered", () => log("serverRegistered"));
        server.on("serverRegistrationPending", () => log("serverRegistrationPending"));
    } else {
        usage();
    }
    shutDownOnSignals(server, log);
    await server.start();
    out(`listening on opc.tcp://${host}:${port}`);
}

main().catch((err) => {
    log("failed:", err && err.stack ? err.stack : err);
    process.exit(1);
});
