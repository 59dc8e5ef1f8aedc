#!/usr/bin/env node
"use strict";
// node-opcua as a secured server for our client (issue 24): the endpoints Basic256Sha256,
// Aes128_Sha256_RsaOaep and Aes256_Sha256_RsaPss x Sign / SignAndEncrypt (no None endpoint
// for sessions), client certificates trusted only when they are in its PKI's trusted/certs
// (unknown ones land in rejected/ and are refused), anonymous, UserName users and X.509 users
// (trusted in the user PKI's trusted/certs). Address space: namespace 0 and the part of the
// demo namespace the interop tests use (urn:pnp:demo: Demo, the writable Scalar.Int32, the
// method Demo.Echo).
//
// usage: node node_secure_server.js --port P --pki DIR [--sign-only-port Q] [--user-pki DIR]
//            [--user NAME:PASSWORD]... [--no-anonymous] [--export-cert FILE.der]
//   DIR: the application PKI (own/, trusted/, rejected/, issuers/; created when missing, its
//   certificate created at first start with the ApplicationUri below, DNS localhost and the
//   host name, IP 127.0.0.1); --user-pki: the PKI of the X.509 users (default DIR-users).
//   --sign-only-port: a second listener whose endpoints offer Sign only (a client that takes
//   the most secure endpoint uses Sign there). --export-cert writes the server's certificate
//   as DER. When ready, prints one JSON line on stdout:
//     {"endpointUrl":URL,"signOnlyUrl":URL|null,"applicationUri":URI,"certificateDer":FILE|null,
//      "thumbprint":HEX}
//   Exits on SIGTERM / SIGINT.

const { out, shutDownOnSignals } = require("./common");
const fs = require("fs");
const os = require("os");
const {
    OPCUAServer,
    OPCUACertificateManager,
    SecurityPolicy,
    MessageSecurityMode,
    DataType,
    Variant,
    StatusCodes,
    makeAccessLevelFlag,
    nodesets,
} = require("node-opcua");
const { convertPEMtoDER, makeSHA1Thumbprint } = require("node-opcua-crypto");

const SCRIPT = "node_secure_server.js";
const APP_URI = "urn:pnp:interop:node-secure-server";
const DEMO_NS_URI = "urn:pnp:demo";

function log(...args) {
    console.error("[node_secure_server]", ...args);
}

function usage(message) {
    console.error(`${SCRIPT}: ${message}`);
    console.error(
        `usage: ${SCRIPT} --port P --pki DIR [--sign-only-port Q] [--user-pki DIR] ` +
            "[--user NAME:PASSWORD]... [--no-anonymous] [--export-cert FILE.der]",
    );
    process.exit(2);
}

function parseArgs(argv) {
    const o = { port: 0, signOnlyPort: 0, pki: null, userPki: null, users: {}, anonymous: true, exportCert: null };
    const value = (i) => {
        if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
        return argv[i + 1];
    };
    for (let i = 0; i < argv.length; i++) {
        const a = argv[i];
        if (a === "--port") o.port = parseInt(value(i++), 10);
        else if (a === "--sign-only-port") o.signOnlyPort = parseInt(value(i++), 10);
        else if (a === "--pki") o.pki = value(i++);
        else if (a === "--user-pki") o.userPki = value(i++);
        else if (a === "--export-cert") o.exportCert = value(i++);
        else if (a === "--no-anonymous") o.anonymous = false;
        else if (a === "--user") {
            const u = value(i++);
            const colon = u.indexOf(":");
            if (colon <= 0) usage(`--user NAME:PASSWORD, got "${u}"`);
            o.users[u.slice(0, colon)] = u.slice(colon + 1);
        } else usage(`unexpected argument "${a}"`);
    }
    if (!Number.isInteger(o.port) || o.port <= 0 || o.port > 65535) usage("--port 1..65535 is required");
    if (!Number.isInteger(o.signOnlyPort) || o.signOnlyPort < 0 || o.signOnlyPort > 65535 || o.signOnlyPort === o.port)
        usage("--sign-only-port: 1..65535, not --port");
    if (!o.pki) usage("--pki DIR is required");
    if (!o.userPki) o.userPki = `${o.pki}-users`;
    return o;
}

function buildDemoNamespace(server) {
    const addressSpace = server.engine.addressSpace;
    const ns = addressSpace.registerNamespace(DEMO_NS_URI);
    const demo = ns.addObject({
        nodeId: "s=Demo",
        browseName: "Demo",
        organizedBy: addressSpace.rootFolder.objects,
    });
    const rw = makeAccessLevelFlag("CurrentRead | CurrentWrite");
    ns.addVariable({
        componentOf: demo,
        nodeId: "s=Scalar.Int32",
        browseName: "Scalar.Int32",
        dataType: "Int32",
        accessLevel: rw,
        userAccessLevel: rw,
        value: new Variant({ dataType: DataType.Int32, value: 0 }),
    });
    const echo = ns.addMethod(demo, {
        nodeId: "s=Demo.Echo",
        browseName: "Echo",
        inputArguments: [{ name: "Data", dataType: DataType.ByteString }],
        outputArguments: [{ name: "Data", dataType: DataType.ByteString }],
    });
    // node-opcua tells the promise form from the callback form by the arity: two parameters.
    echo.bindMethod(async (inputArguments, _context) => ({
        statusCode: StatusCodes.Good,
        outputArguments: [new Variant({ dataType: DataType.ByteString, value: inputArguments[0].value })],
    }));
}

async function main() {
    const o = parseArgs(process.argv.slice(2));
    const serverCertificateManager = new OPCUACertificateManager({
        rootFolder: o.pki,
        automaticallyAcceptUnknownCertificate: false,
    });
    const userCertificateManager = new OPCUACertificateManager({
        rootFolder: o.userPki,
        automaticallyAcceptUnknownCertificate: false,
    });
    await serverCertificateManager.initialize();
    await userCertificateManager.initialize();

    // The certificate names the loopback address and localhost: a client that checks the
    // endpoint URL's host against the certificate accepts opc.tcp://127.0.0.1:P.
    const certificateFile = `${serverCertificateManager.rootDir}/own/certs/certificate.pem`;
    if (!fs.existsSync(certificateFile)) {
        await serverCertificateManager.createSelfSignedCertificate({
            applicationUri: APP_URI,
            dns: ["localhost", os.hostname()],
            ip: ["127.0.0.1"],
            outputFile: certificateFile,
            subject: "/CN=pnp interop node-opcua secure server/O=pnp",
            startDate: new Date(Date.now() - 24 * 3600 * 1000),
            validity: 365,
        });
    }

    const securityPolicies = [
        SecurityPolicy.Basic256Sha256,
        SecurityPolicy.Aes128_Sha256_RsaOaep,
        SecurityPolicy.Aes256_Sha256_RsaPss,
    ];
    const server = new OPCUAServer({
        port: o.port,
        host: "127.0.0.1",
        hostname: "127.0.0.1",
        nodeset_filename: [nodesets.standard],
        securityPolicies,
        securityModes: [MessageSecurityMode.Sign, MessageSecurityMode.SignAndEncrypt],
        allowAnonymous: o.anonymous,
        alternateEndpoints: o.signOnlyPort
            ? [
                  {
                      port: o.signOnlyPort,
                      host: "127.0.0.1",
                      hostname: "127.0.0.1",
                      securityPolicies,
                      securityModes: [MessageSecurityMode.Sign],
                      allowAnonymous: o.anonymous,
                  },
              ]
            : [],
        serverCertificateManager,
        userCertificateManager,
        certificateFile,
        userManager: {
            isValidUser: (userName, password) =>
                Object.prototype.hasOwnProperty.call(o.users, userName) && o.users[userName] === password,
        },
        serverInfo: {
            applicationUri: APP_URI,
            productUri: APP_URI,
            applicationName: { text: "pnp interop node-opcua secure server", locale: "en" },
        },
        buildInfo: { productName: "pnp-node-secure-server", buildNumber: "1" },
    });
    await server.initialize();
    buildDemoNamespace(server);
    await server.start();
    shutDownOnSignals(server, log);

    const der = convertPEMtoDER(fs.readFileSync(certificateFile, "ascii"));
    if (o.exportCert) fs.writeFileSync(o.exportCert, der);
    const endpointUrl = `opc.tcp://127.0.0.1:${o.port}`;
    log("listening on", endpointUrl);
    out(
        JSON.stringify({
            endpointUrl,
            signOnlyUrl: o.signOnlyPort ? `opc.tcp://127.0.0.1:${o.signOnlyPort}` : null,
            applicationUri: APP_URI,
            certificateDer: o.exportCert,
            thumbprint: makeSHA1Thumbprint(der).toString("hex"),
        }),
    );
}

main().catch((err) => {
    log("fatal:", err && err.stack ? err.stack : err);
    process.exit(1);
});
