#!/usr/bin/env node
"use strict";
// node-opcua reference server exposing the same demo namespace as `pnp ua serve`.
//
// usage: node tests/interop/node_server.js PORT
//   - listens on opc.tcp://127.0.0.1:PORT, SecurityPolicy None / MessageSecurityMode None
//   - anonymous, and username "operator" / password "secret"
//   - prints a line "READY" on stdout once listening; exits on SIGTERM / SIGINT

const { out, portArg, certificateManager, shutDownOnSignals } = require("./common");
const {
    OPCUAServer,
    SecurityPolicy,
    MessageSecurityMode,
    DataType,
    Variant,
    ExpandedNodeId,
    StatusCodes,
    UserTokenType,
    UserTokenPolicy,
    makeAccessLevelFlag,
    nodesets,
} = require("node-opcua");
const demo = require("./demo_types");

const port = portArg("node_server.js");

const APP_URI = "urn:pnp:node-opcua-reference-server";

function log(...args) {
    console.error("[node_server]", ...args);
}

// Work-around for a node-opcua bug (seen in 2.186.4): Variant.prototype.clone()
// copies an ExpandedNodeId element as a plain NodeId, dropping NamespaceUri and
// ServerIndex. The server clones every written value, so Scalar.ExpandedNodeId
// would not round-trip. Re-create proper ExpandedNodeIds after the clone.
(function patchExpandedNodeIdClone() {
    const origClone = Variant.prototype.clone;
    const copyX = (x) =>
        x instanceof ExpandedNodeId
            ? new ExpandedNodeId(
                  x.identifierType,
                  Buffer.isBuffer(x.value) ? Buffer.from(x.value) : x.value,
                  x.namespace,
                  x.namespaceUri,
                  x.serverIndex,
              )
            : x;
    Variant.prototype.clone = function clone() {
        const c = origClone.call(this);
        if (this.dataType === DataType.ExpandedNodeId && this.value) {
            c.value = Array.isArray(this.value) ? this.value.map(copyX) : copyX(this.value);
        }
        return c;
    };
})();

// Like `pnp ua serve` (no crypto yet), offer a UserName token policy whose
// SecurityPolicyUri is empty on the None endpoint, i.e. the password travels in
// clear inside the None channel. node-opcua has no public option for that
// (allowUnsecurePassword is not plumbed through OPCUAServer), so add it here.
function addUnsecureUserNamePolicy(server) {
    let added = 0;
    for (const ep of server.endpoints) {
        for (const desc of ep.endpointDescriptions()) {
            const tokens = desc.userIdentityTokens || [];
            if (!tokens.some((t) => t.tokenType === UserTokenType.UserName)) {
                tokens.unshift(
                    new UserTokenPolicy({
                        policyId: "username_none",
                        tokenType: UserTokenType.UserName,
                        securityPolicyUri: null,
                    }),
                );
                desc.userIdentityTokens = tokens;
                added++;
            }
        }
    }
    return added;
}

function buildDemoNamespace(server) {
    const addressSpace = server.engine.addressSpace;
    const ns = addressSpace.registerNamespace(demo.DEMO_NS_URI);

    const demoObj = ns.addObject({
        nodeId: "s=Demo",
        browseName: "Demo",
        organizedBy: addressSpace.rootFolder.objects,
    });

    const rw = makeAccessLevelFlag("CurrentRead | CurrentWrite");
    for (const t of demo.TYPES) {
        for (const kind of ["Scalar", "Array"]) {
            const isArray = kind === "Array";
            const initial = isArray ? demo.arrayDefaultVariant(t) : demo.scalarDefaultVariant(t);
            ns.addVariable({
                componentOf: demoObj,
                nodeId: `s=${kind}.${t.name}`,
                browseName: `${kind}.${t.name}`,
                dataType: `i=${t.typeNodeId}`,
                valueRank: isArray ? 1 : -1,
                arrayDimensions: isArray ? [0] : null,
                accessLevel: rw,
                userAccessLevel: rw,
                value: initial,
            });
        }
    }

    const echo = ns.addMethod(demoObj, {
        nodeId: "s=Demo.Echo",
        browseName: "Echo",
        inputArguments: [{ name: "Data", dataType: DataType.ByteString, description: "bytes to echo" }],
        outputArguments: [{ name: "Data", dataType: DataType.ByteString, description: "the same bytes" }],
    });
    echo.bindMethod(async (inputArguments, _context) => {
        return {
            statusCode: StatusCodes.Good,
            outputArguments: [new Variant({ dataType: DataType.ByteString, value: inputArguments[0].value })],
        };
    });

    const add = ns.addMethod(demoObj, {
        nodeId: "s=Demo.Add",
        browseName: "Add",
        inputArguments: [
            { name: "a", dataType: DataType.Int32 },
            { name: "b", dataType: DataType.Int32 },
        ],
        outputArguments: [{ name: "sum", dataType: DataType.Int32 }],
    });
    add.bindMethod(async (inputArguments, _context) => {
        const a = inputArguments[0].value;
        const b = inputArguments[1].value;
        return {
            statusCode: StatusCodes.Good,
            outputArguments: [new Variant({ dataType: DataType.Int32, value: (a + b) | 0 })],
        };
    });
}

async function main() {
    const serverCertificateManager = certificateManager("server");
    const userCertificateManager = certificateManager("user");

    const server = new OPCUAServer({
        port,
        host: "127.0.0.1",
        hostname: "127.0.0.1",
        nodeset_filename: [nodesets.standard],
        securityPolicies: [SecurityPolicy.None],
        securityModes: [MessageSecurityMode.None],
        allowAnonymous: true,
        disableDiscovery: false,
        serverCertificateManager,
        userCertificateManager,
        userManager: {
            isValidUser: (userName, password) => userName === "operator" && password === "secret",
        },
        serverInfo: {
            applicationUri: APP_URI,
            productUri: "urn:pnp:node-opcua-reference-server",
            applicationName: { text: "pnp node-opcua reference server", locale: "en" },
        },
        buildInfo: {
            productName: "pnp-node-reference",
            buildNumber: "1",
        },
    });

    await server.initialize();
    if (addUnsecureUserNamePolicy(server) === 0) {
        log("warning: could not add a UserName token policy");
    }
    buildDemoNamespace(server);
    await server.start();

    shutDownOnSignals(server, log);

    const ep = server.endpoints[0] && server.endpoints[0].endpointDescriptions()[0];
    log("listening on", ep ? ep.endpointUrl : `opc.tcp://127.0.0.1:${port}`);
    out("READY");
}

main().catch((err) => {
    log("fatal:", err && err.stack ? err.stack : err);
    process.exit(1);
});
