#!/usr/bin/env node
"use strict";
// node-opcua server for the subscription and event interop tests of our client.
//
// usage: node tests/interop/node_subscription_server.js PORT
//   - listens on opc.tcp://127.0.0.1:PORT, SecurityPolicy None, anonymous
//   - namespace "urn:pnp:subscription-test":
//       s=Counter       Int32, incremented every 50 ms
//       s=Setpoint      Double, read/write (data changes come from the test's writes)
//       s=PnpTestEventType  subtype of BaseEventType with a property CustomField (String)
//   - every 100 ms the Server object (i=2253) raises a PnpTestEventType event with
//     Message "pnp test event N", Severity 100 + (N % 800) and CustomField "custom-N"
//   - prints "READY" on stdout once listening; exits on SIGTERM / SIGINT

const { out, portArg, certificateManager, shutDownOnSignals } = require("./common");
const {
    OPCUAServer,
    SecurityPolicy,
    MessageSecurityMode,
    DataType,
    Variant,
    makeAccessLevelFlag,
    nodesets,
} = require("node-opcua");

const NS_URI = "urn:pnp:subscription-test";
const port = portArg("node_subscription_server.js");

function log(...args) {
    console.error("[node_subscription_server]", ...args);
}

function build(server) {
    const addressSpace = server.engine.addressSpace;
    const ns = addressSpace.registerNamespace(NS_URI);
    const objects = addressSpace.rootFolder.objects;

    let counter = 0;
    const counterVar = ns.addVariable({
        organizedBy: objects,
        nodeId: "s=Counter",
        browseName: "Counter",
        dataType: "Int32",
        value: new Variant({ dataType: DataType.Int32, value: 0 }),
    });
    const rw = makeAccessLevelFlag("CurrentRead | CurrentWrite");
    ns.addVariable({
        organizedBy: objects,
        nodeId: "s=Setpoint",
        browseName: "Setpoint",
        dataType: "Double",
        accessLevel: rw,
        userAccessLevel: rw,
        value: new Variant({ dataType: DataType.Double, value: 0 }),
    });

    const eventType = ns.addEventType({
        nodeId: "s=PnpTestEventType",
        browseName: "PnpTestEventType",
        subtypeOf: "BaseEventType",
    });
    ns.addVariable({
        propertyOf: eventType,
        browseName: "CustomField",
        dataType: "String",
        modellingRule: "Mandatory",
    });

    const serverObject = objects.server;
    let n = 0;
    const timers = [];
    timers.push(
        setInterval(() => {
            counter = (counter + 1) | 0;
            counterVar.setValueFromSource(new Variant({ dataType: DataType.Int32, value: counter }));
        }, 50),
    );
    timers.push(
        setInterval(() => {
            n++;
            serverObject.raiseEvent(eventType, {
                message: { dataType: DataType.LocalizedText, value: { text: `pnp test event ${n}` } },
                severity: { dataType: DataType.UInt16, value: 100 + (n % 800) },
                customField: { dataType: DataType.String, value: `custom-${n}` },
            });
        }, 100),
    );
    return timers;
}

async function main() {
    const serverCertificateManager = certificateManager("server");
    const server = new OPCUAServer({
        port,
        host: "127.0.0.1",
        hostname: "127.0.0.1",
        nodeset_filename: [nodesets.standard],
        securityPolicies: [SecurityPolicy.None],
        securityModes: [MessageSecurityMode.None],
        allowAnonymous: true,
        serverCertificateManager,
        serverInfo: {
            applicationUri: "urn:pnp:node-opcua-subscription-server",
            productUri: "urn:pnp:node-opcua-subscription-server",
            applicationName: { text: "pnp node-opcua subscription server", locale: "en" },
        },
    });
    await server.initialize();
    const timers = build(server);
    await server.start();

    shutDownOnSignals(server, log, () => {
        for (const t of timers) clearInterval(t);
    });
    log(`listening on opc.tcp://127.0.0.1:${port}`);
    out("READY");
}

main().catch((err) => {
    log("fatal:", err && err.stack ? err.stack : err);
    process.exit(1);
});
