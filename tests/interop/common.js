"use strict";
// What the node-opcua interop scripts share: stdout kept for the script's own lines, the
// command line, PKI folders out of $HOME, a server's shutdown on SIGTERM / SIGINT, the
// TAP-like checks of the client scripts, and the clients' standard-service helpers (browse,
// TranslateBrowsePath, the namespaces, a skill's program state events).

// node-opcua logs warnings with console.log: send all library output to stderr and keep
// stdout for this script's own lines, written with the returned out(line).
const stdoutWrite = process.stdout.write.bind(process.stdout);
const out = (line) => stdoutWrite(line + "\n");
process.stdout.write = process.stderr.write.bind(process.stderr);

const path = require("path");
const os = require("os");
const {
    OPCUACertificateManager,
    OPCUAClient,
    MessageSecurityMode,
    SecurityPolicy,
    AttributeIds,
    BrowseDirection,
    TimestampsToReturn,
    ClientSubscription,
    ClientMonitoredItem,
    EventFilter,
    SimpleAttributeOperand,
    coerceNodeId,
} = require("node-opcua");

function usage(script, what) {
    console.error(`usage: ${script} ${what}`);
    process.exit(2);
}

// argv[2] as a TCP port (exits with a usage line otherwise).
function portArg(script) {
    const port = parseInt(process.argv[2] || "", 10);
    if (!Number.isInteger(port) || port <= 0 || port > 65535) usage(script, "PORT");
    return port;
}

// argv[2] as an opc.tcp URL (exits with a usage line otherwise).
function urlArg(script) {
    const url = process.argv[2];
    if (!url || !url.startsWith("opc.tcp://")) usage(script, "opc.tcp://HOST:PORT");
    return url;
}

// A certificate manager accepting every certificate, in $PNP_NODE_PKI_DIR (default: a
// folder under the temporary directory) / kind: the PKI is created even for
// SecurityPolicy None, and runs stay self-contained and repeatable.
function certificateManager(kind) {
    const pkiRoot = process.env.PNP_NODE_PKI_DIR || path.join(os.tmpdir(), "pnp-node-opcua-pki");
    return new OPCUACertificateManager({
        automaticallyAcceptUnknownCertificate: true,
        rootFolder: path.join(pkiRoot, kind),
    });
}

// An OPCUAClient of the client scripts: SecurityPolicy None, a few quick reconnect attempts,
// the PKI of certificateManager("client"); `extra` adds or overrides options.
function noneClient(applicationName, extra = {}) {
    return OPCUAClient.create({
        applicationName,
        clientCertificateManager: certificateManager("client"),
        endpointMustExist: false,
        securityMode: MessageSecurityMode.None,
        securityPolicy: SecurityPolicy.None,
        connectionStrategy: { maxRetry: 2, initialDelay: 250, maxDelay: 1000 },
        ...extra,
    });
}

// Shuts the server down on SIGTERM / SIGINT (beforeShutdown() first; the process exits
// within 3 s whatever happens).
function shutDownOnSignals(server, log, beforeShutdown = () => {}) {
    let stopping = false;
    const stop = async (sig) => {
        if (stopping) return;
        stopping = true;
        log(`received ${sig}, shutting down`);
        beforeShutdown();
        const hard = setTimeout(() => process.exit(0), 3000);
        hard.unref();
        try {
            await server.shutdown(0);
        } catch (err) {
            log("shutdown error:", err && err.message);
        }
        process.exit(0);
    };
    process.on("SIGTERM", () => stop("SIGTERM"));
    process.on("SIGINT", () => stop("SIGINT"));
}

function oneLine(s) {
    s = String(s).replace(/\s+/g, " ").trim();
    return s.length > 300 ? s.slice(0, 297) + "..." : s;
}

function withTimeout(promise, ms, what) {
    let timer;
    const t = new Promise((_, reject) => {
        timer = setTimeout(() => reject(new Error(`timeout after ${ms} ms (${what})`)), ms);
    });
    return Promise.race([promise, t]).finally(() => clearTimeout(timer));
}

function expect(cond, msg) {
    if (!cond) throw new Error(msg);
}

// Thrown by a check to report a skip.
class Skip extends Error {}

// The checks of a client script: one line per check (`ok - NAME`, `not ok - NAME: reason`,
// `skip - NAME: reason`), then the summary `node_client: N passed, N failed, N skipped`
// (scripts/test.sh reads it). The whole run is bounded by deadlineMs; `tag` prefixes
// unhandled rejections on stderr.
function checks({ tag, deadlineMs, stepTimeoutMs }) {
    const counts = { passed: 0, failed: 0, skipped: 0 };
    const summaryAndExit = (code) => {
        out(`node_client: ${counts.passed} passed, ${counts.failed} failed, ${counts.skipped} skipped`);
        process.exit(code);
    };
    // A late failure of an operation that already timed out must not crash the run.
    process.on("unhandledRejection", (err) => {
        console.error(`[${tag}] unhandled rejection:`, err && err.message ? err.message : err);
    });
    setTimeout(() => {
        counts.failed++;
        out(`not ok - overall deadline: run exceeded ${deadlineMs} ms`);
        summaryAndExit(1);
    }, deadlineMs).unref();

    // Runs one check. fn returns/throws; throw Skip to report a skip. Returns true on pass.
    async function check(name, fn, timeoutMs = stepTimeoutMs) {
        try {
            await withTimeout(Promise.resolve().then(fn), timeoutMs, name);
            counts.passed++;
            out(`ok - ${name}`);
            return true;
        } catch (err) {
            if (err instanceof Skip) {
                counts.skipped++;
                out(`skip - ${name}: ${oneLine(err.message)}`);
                return true;
            }
            counts.failed++;
            out(`not ok - ${name}: ${oneLine(err && err.message ? err.message : err)}`);
            return false;
        }
    }
    // The end of the run: exit 0 only if nothing failed.
    const finish = () => summaryAndExit(counts.failed === 0 ? 0 : 1);
    // main()'s rejection handler.
    const unexpected = (err) => {
        counts.failed++;
        out(`not ok - unexpected error: ${oneLine(err && err.stack ? err.stack : err)}`);
        summaryAndExit(1);
    };
    return { check, finish, unexpected, abort: () => summaryAndExit(1) };
}

// ---- the clients' standard-service helpers -------------------------------------------------

const DI_URI = "http://opcfoundation.org/UA/DI/";
const SKILLS_URI = "urn:pnp:ua:skills";
const HIERARCHICAL = coerceNodeId("i=33");
const HAS_INTERFACE = coerceNodeId("i=17603");
const BASE_EVENT_TYPE = coerceNodeId("i=2041");
const PROGRAM_TRANSITION_EVENT_TYPE = coerceNodeId("i=2378");
// StateNumber of ns0 ProgramStateMachineType's states, and the skill model's Result values.
const HALTED = 11;
const READY = 12;
const RUNNING = 13;
const RESULT_COMPLETED = 1;
const RESULT_FAILED = 2;

const statusText = (s) => (s ? s.toString() : String(s));
function expectGood(status, what) {
    expect(status && status.isGood(), `${what}: ${statusText(status)}`);
}

// Forward references of nodeId (hierarchical by default), following at most 100
// continuation points.
async function browseChildren(session, nodeId, referenceTypeId = HIERARCHICAL) {
    const r = await session.browse({
        nodeId,
        browseDirection: BrowseDirection.Forward,
        referenceTypeId,
        includeSubtypes: true,
        nodeClassMask: 0,
        resultMask: 0x3f,
    });
    expectGood(r.statusCode, `Browse ${nodeId.toString()}`);
    const refs = [...(r.references || [])];
    let cp = r.continuationPoint;
    for (let i = 0; cp && cp.length && i < 100; i++) {
        const next = await session.browseNext(cp, false);
        refs.push(...(next.references || []));
        cp = next.continuationPoint;
    }
    return refs;
}

// The node at `path` ([[nsIndex, name], ...], hierarchical references) below `start`, by
// TranslateBrowsePathsToNodeIds; on failure the error lists the children of `start`.
async function resolvePath(session, start, path) {
    const r = await session.translateBrowsePath({
        startingNode: start,
        relativePath: {
            elements: path.map(([ns, name]) => ({
                referenceTypeId: HIERARCHICAL,
                isInverse: false,
                includeSubtypes: true,
                targetName: { namespaceIndex: ns, name },
            })),
        },
    });
    const text = path.map(([ns, name]) => `${ns}:${name}`).join("/");
    if (!r.statusCode.isGood() || !r.targets || r.targets.length === 0) {
        const kids = await browseChildren(session, start).catch(() => []);
        throw new Error(`TranslateBrowsePath ${text}: ${statusText(r.statusCode)} (children of ` +
            `${start.toString()}: ${kids.map((k) => k.browseName.toString()).join(", ")})`);
    }
    return coerceNodeId(r.targets[0].targetId.toString());
}

// The Value attribute's value (the Variant's value); fails on a bad status.
async function readValue(session, nodeId, what) {
    const dv = await session.read({ nodeId, attributeId: AttributeIds.Value });
    expectGood(dv.statusCode, `read ${what}`);
    return dv.value.value;
}

// { key: namespace index } for { key: URI }, from the NamespaceArray; fails if one is missing.
async function namespaceIndexes(session, uris) {
    const arr = (await readValue(session, coerceNodeId("i=2255"), "NamespaceArray")) || [];
    const ns = {};
    for (const [key, uri] of Object.entries(uris)) {
        ns[key] = arr.indexOf(uri);
        expect(ns[key] > 0, `"${uri}" not in [${arr.join(", ")}]`);
    }
    return ns;
}

// The DI DeviceSet below Objects (diNs: the DI namespace's index).
async function deviceSet(session, diNs) {
    const objects = await browseChildren(session, coerceNodeId("i=85"));
    const found = objects.find((r) =>
        r.browseName.namespaceIndex === diNs && r.browseName.name === "DeviceSet");
    expect(found, `no DI DeviceSet below Objects (${objects.map((r) => r.browseName.toString())
        .join(", ")})`);
    return found.nodeId;
}

// The references to the objects below DeviceSet with a HasInterface reference to `iface`
// ("ns=N;i=M").
async function devicesWithInterface(session, diNs, iface) {
    const devices = [];
    for (const d of await browseChildren(session, await deviceSet(session, diNs))) {
        const ifaces = await browseChildren(session, d.nodeId, HAS_INTERFACE);
        if (ifaces.some((i) => i.nodeId.toString() === iface)) devices.push(d);
    }
    return devices;
}

// A started subscription publishing every 50 ms (events come within a publish cycle).
async function startSubscription(session) {
    const subscription = ClientSubscription.create(session, {
        requestedPublishingInterval: 50,
        requestedLifetimeCount: 600,
        requestedMaxKeepAliveCount: 20,
        maxNotificationsPerPublish: 100,
        publishingEnabled: true,
        priority: 1,
    });
    await new Promise((resolve, reject) => {
        subscription.on("started", resolve);
        subscription.on("internal_error", reject);
    });
    return subscription;
}

// A subscription to the ProgramTransitionEvents of `skill`: `states` collects each event's
// ToState number, `ended` resolves at the first state other than Running; terminate() ends
// the subscription.
async function watchSkillStates(session, skill) {
    const subscription = await startSubscription(session);
    const terminate = () => subscription.terminate().catch(() => {});
    try {
        const filter = new EventFilter({
            selectClauses: [["Transition", "Number"], ["ToState", "Number"]].map((p) =>
                new SimpleAttributeOperand({
                    typeDefinitionId: PROGRAM_TRANSITION_EVENT_TYPE,
                    browsePath: p.map((name) => ({ namespaceIndex: 0, name })),
                    attributeId: AttributeIds.Value,
                })),
        });
        const item = ClientMonitoredItem.create(subscription,
            { nodeId: skill, attributeId: AttributeIds.EventNotifier },
            { samplingInterval: 0, queueSize: 100, discardOldest: false, filter },
            TimestampsToReturn.Both);
        const states = [];
        let end = null;
        const ended = new Promise((resolve) => (end = resolve));
        item.on("changed", (fields) => {
            const to = fields[1] ? fields[1].value : null;
            states.push(to);
            if (to !== RUNNING) end();
        });
        await new Promise((resolve, reject) => {
            item.on("initialized", resolve);
            item.on("err", (e) => reject(new Error(`CreateMonitoredItems: ${e}`)));
        });
        return { states, ended, terminate };
    } catch (err) {
        await terminate();
        throw err;
    }
}

module.exports = {
    out,
    portArg,
    urlArg,
    certificateManager,
    noneClient,
    shutDownOnSignals,
    oneLine,
    withTimeout,
    expect,
    Skip,
    checks,
    DI_URI,
    SKILLS_URI,
    HIERARCHICAL,
    HAS_INTERFACE,
    BASE_EVENT_TYPE,
    PROGRAM_TRANSITION_EVENT_TYPE,
    HALTED,
    READY,
    RUNNING,
    RESULT_COMPLETED,
    RESULT_FAILED,
    statusText,
    expectGood,
    browseChildren,
    resolvePath,
    readValue,
    namespaceIndexes,
    deviceSet,
    devicesWithInterface,
    startSubscription,
    watchSkillStates,
};
