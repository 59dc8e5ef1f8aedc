#!/usr/bin/env node
"use strict";
// node-opcua against our Local Discovery Server: RegisterServer2 with an
// MdnsDiscoveryConfiguration, FindServersOnNetwork (with a capability filter), FindServers,
// a refused registration and unregistering (isOnline = false). One TAP-like line per check
// (see common.js); exit code 0 only if every check passed.
//
// usage: node tests/interop/node_lds_client.js opc.tcp://127.0.0.1:PORT
// The server must run with the LDS on and list nothing registered yet.

const { urlArg, noneClient, expect, checks } = require("./common");
const {
    ApplicationType,
    RegisterServerRequest,
    RegisterServer2Request,
    MdnsDiscoveryConfiguration,
} = require("node-opcua");

const url = urlArg("node_lds_client.js");
const { check, finish, unexpected, abort } = checks({
    tag: "node_lds_client",
    deadlineMs: 45000,
    stepTimeoutMs: 10000,
});

const device = (isOnline) => ({
    serverUri: "urn:node-opcua:gripper",
    productUri: "urn:node-opcua",
    serverNames: [{ locale: "en", text: "node gripper" }],
    serverType: ApplicationType.Server,
    discoveryUrls: ["opc.tcp://gripper.local:4841"],
    isOnline,
});

// The response, or the status of a ServiceFault as an Error.
function transact(client, request) {
    return new Promise((resolve, reject) => {
        client.performMessageTransaction(request, (err, response) => {
            if (err) reject(err);
            else resolve(response);
        });
    });
}

async function main() {
    const client = noneClient("pnp-interop-node-lds-client", { transportTimeout: 10000 });
    const connected = await check("connect", () => client.connect(url));
    if (!connected) abort();

    await check("RegisterServer2 with an mDNS configuration", async () => {
        const response = await transact(
            client,
            new RegisterServer2Request({
                server: device(true),
                discoveryConfiguration: [
                    new MdnsDiscoveryConfiguration({
                        mdnsServerName: "gripper",
                        serverCapabilities: ["DA", "NA"],
                    }),
                ],
            })
        );
        expect(response.responseHeader.serviceResult.isGood(), "serviceResult not Good");
        const results = response.configurationResults || [];
        expect(results.length === 1 && results[0].isGood(), `configurationResults ${results}`);
    });

    await check("FindServersOnNetwork lists the LDS and the device", async () => {
        const servers = await client.findServersOnNetwork();
        expect(servers.length === 2, `${servers.length} records`);
        const dev = servers.find((s) => s.serverName === "gripper");
        expect(dev, "no record named gripper");
        expect(dev.discoveryUrl === "opc.tcp://gripper.local:4841", dev.discoveryUrl);
        expect(dev.serverCapabilities.join(",") === "DA,NA", dev.serverCapabilities.join(","));
        const lds = servers.find((s) => s.serverCapabilities.includes("LDS"));
        expect(lds && lds.recordId < dev.recordId, "the LDS's own record is missing or later");
    });

    await check("FindServersOnNetwork with a capability filter", async () => {
        const na = await client.findServersOnNetwork({ serverCapabilityFilter: ["na"] });
        expect(na.length === 1 && na[0].serverName === "gripper", `${na.length} records`);
        const none = await client.findServersOnNetwork({ serverCapabilityFilter: ["DA", "XX"] });
        expect(none.length === 0, `${none.length} records`);
    });

    await check("FindServers lists the registered server", async () => {
        const servers = await client.findServers();
        const dev = servers.find((s) => s.applicationUri === "urn:node-opcua:gripper");
        expect(dev, "urn:node-opcua:gripper not listed");
        expect(dev.applicationName.text === "node gripper", dev.applicationName.text);
        expect(dev.discoveryUrls[0] === "opc.tcp://gripper.local:4841", dev.discoveryUrls[0]);
    });

    await check("RegisterServer without a server URI is refused", async () => {
        const bad = device(true);
        bad.serverUri = "";
        let status = "Good";
        try {
            const r = await transact(client, new RegisterServerRequest({ server: bad }));
            status = r.responseHeader.serviceResult.name;
        } catch (err) {
            status = String(err && err.message);
        }
        expect(status.includes("BadServerUriInvalid"), status);
    });

    await check("RegisterServer isOnline=false unregisters", async () => {
        await transact(client, new RegisterServerRequest({ server: device(false) }));
        const servers = await client.findServersOnNetwork();
        expect(servers.length === 1, `${servers.length} records`);
        const found = await client.findServers();
        expect(!found.some((s) => s.applicationUri === "urn:node-opcua:gripper"), "still listed");
    });

    await client.disconnect();
    finish();
}

main().catch(unexpected);
