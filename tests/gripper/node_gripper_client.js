#!/usr/bin/env node
"use strict";
// node-opcua as an independent client of a pnp gripper device (src/device/gripper): standard
// services only (Read, Write, Browse, TranslateBrowsePathsToNodeIds, Call, an event monitored
// item). Everything is found by browsing and by type: Objects -> DI DeviceSet -> the object
// with HasInterface IGripperType -> GripPoints/GripPoint_1 (Type, Offset, Span), and Skills ->
// the skill of type GraspGripperSkillType, run with Force = FORCE. EXPECT is "completed" or
// "failed:<text>" (the run must fail with FinalResultData/Message = <text>).
// Prints one line per check and the summary. Exit 0 only if every check passed.
//
// usage: node tests/gripper/node_gripper_client.js opc.tcp://127.0.0.1:4841 FORCE EXPECT

const { out, urlArg, noneClient, expect, checks } = require("../interop/common");
const {
    AttributeIds,
    BrowseDirection,
    DataType,
    TimestampsToReturn,
    ClientSubscription,
    ClientMonitoredItem,
    EventFilter,
    SimpleAttributeOperand,
    Variant,
    coerceNodeId,
} = require("node-opcua");

const url = urlArg("node_gripper_client.js");
const force = Number(process.argv[3]);
const expected = process.argv[4] || "";
if (!Number.isFinite(force) || !(expected === "completed" || expected.startsWith("failed:"))) {
    console.error("usage: node_gripper_client.js URL FORCE completed|failed:<message>");
    process.exit(2);
}
const { check, finish, unexpected, abort } = checks({
    tag: "node_gripper_client",
    deadlineMs: parseInt(process.env.PNP_CLIENT_DEADLINE_MS || "40000", 10),
    stepTimeoutMs: 15000,
});

const DI_URI = "http://opcfoundation.org/UA/DI/";
const SKILLS_URI = "urn:pnp:ua:skills";
const HIERARCHICAL = coerceNodeId("i=33");
const HAS_INTERFACE = coerceNodeId("i=17603");
const PROGRAM_TRANSITION_EVENT_TYPE = coerceNodeId("i=2378");
const RUNNING = 13;
const RESULT_COMPLETED = 1;
const RESULT_FAILED = 2;

const sc = (s) => (s ? s.toString() : String(s));
const expectGood = (status, what) => expect(status && status.isGood(), `${what}: ${sc(status)}`);

async function browse(session, nodeId, referenceTypeId = HIERARCHICAL) {
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
    expect(r.statusCode.isGood() && r.targets && r.targets.length > 0,
        `TranslateBrowsePath ${start.toString()} ${text}: ${sc(r.statusCode)}`);
    return coerceNodeId(r.targets[0].targetId.toString());
}

async function main() {
    const client = noneClient("pnp-node-gripper-client", {
        requestedSessionTimeout: 30000,
        keepSessionAlive: false,
    });
    let s = null;
    const cleanup = async () => {
        if (s) await s.close().catch(() => {});
        await client.disconnect().catch(() => {});
    };
    const readValue = async (nodeId, what) => {
        const dv = await s.read({ nodeId, attributeId: AttributeIds.Value });
        expectGood(dv.statusCode, `read ${what}`);
        return dv.value;
    };

    const ns = {};
    const up = await check("connect; NamespaceArray has DI and the skill model", async () => {
        await client.connect(url);
        s = await client.createSession();
        const arr = (await readValue(coerceNodeId("i=2255"), "NamespaceArray")).value;
        for (const [k, uri] of [["di", DI_URI], ["skills", SKILLS_URI]]) {
            ns[k] = arr.indexOf(uri);
            expect(ns[k] > 0, `"${uri}" not in [${arr.join(", ")}]`);
        }
    });
    if (!up) {
        await cleanup();
        abort();
    }

    const n = {};
    const found = await check("browse DeviceSet -> the IGripperType device -> Skills -> Grasp",
        async () => {
            const objects = await browse(s, coerceNodeId("i=85"));
            const deviceSet = objects.find((r) =>
                r.browseName.namespaceIndex === ns.di && r.browseName.name === "DeviceSet");
            expect(deviceSet, "no DI DeviceSet below Objects");
            const grippers = [];
            for (const d of await browse(s, deviceSet.nodeId)) {
                const ifaces = await browse(s, d.nodeId, HAS_INTERFACE);
                if (ifaces.some((i) => i.nodeId.toString() === `ns=${ns.skills};i=1020`))
                    grippers.push(d);
            }
            expect(grippers.length === 1, `${grippers.length} devices implement IGripperType`);
            n.device = coerceNodeId(grippers[0].nodeId.toString());
            const skills = await resolvePath(s, n.device, [[ns.skills, "Skills"]]);
            const grasps = (await browse(s, skills)).filter((r) =>
                r.typeDefinition.toString() === `ns=${ns.skills};i=1011`);
            expect(grasps.length === 1, `${grasps.length} GraspGripperSkillType skills`);
            n.skill = coerceNodeId(grasps[0].nodeId.toString());
            n.force = await resolvePath(s, n.skill, [[ns.di, "ParameterSet"], [ns.skills, "Force"]]);
            n.start = await resolvePath(s, n.skill, [[0, "Start"]]);
            n.result = await resolvePath(s, n.skill, [[0, "FinalResultData"], [ns.skills, "Result"]]);
            n.message = await resolvePath(s, n.skill, [[0, "FinalResultData"], [ns.skills, "Message"]]);
        });
    if (!found) {
        await cleanup();
        abort();
    }

    await check("GripPoints/GripPoint_1: Type Parallel, Offset (ThreeDFrame), Span (Range)",
        async () => {
            const gp = await resolvePath(s, n.device, [[ns.skills, "GripPoints"],
                [ns.skills, "GripPoint_1"]]);
            const type = await readValue(await resolvePath(s, gp, [[ns.skills, "Type"]]), "Type");
            expect(type.value === 0, `Type ${type.value}, expected 0 (Parallel)`);
            const offset = (await readValue(await resolvePath(s, gp, [[ns.skills, "Offset"]]),
                "Offset")).value;
            expect(offset && offset.cartesianCoordinates,
                `Offset is not a ThreeDFrame: ${JSON.stringify(offset)}`);
            out(`offset-z: ${offset.cartesianCoordinates.z}`);
            const span = (await readValue(await resolvePath(s, gp, [[ns.skills, "Span"]]),
                "Span")).value;
            expect(span && typeof span.low === "number" && typeof span.high === "number",
                `Span is not a Range: ${JSON.stringify(span)}`);
            out(`span: [${span.low}, ${span.high}]`);
        });

    await check(`Grasp: Write Force ${force}, Start -> Running, then ${expected}`, async () => {
        const subscription = ClientSubscription.create(s, {
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
        const filter = new EventFilter({
            selectClauses: [["Transition", "Number"], ["ToState", "Number"]].map((p) =>
                new SimpleAttributeOperand({
                    typeDefinitionId: PROGRAM_TRANSITION_EVENT_TYPE,
                    browsePath: p.map((name) => ({ namespaceIndex: 0, name })),
                    attributeId: AttributeIds.Value,
                })),
        });
        const item = ClientMonitoredItem.create(subscription,
            { nodeId: n.skill, attributeId: AttributeIds.EventNotifier },
            { samplingInterval: 0, queueSize: 100, discardOldest: false, filter },
            TimestampsToReturn.Both);
        const states = [];
        let ended = null;
        const done = new Promise((resolve) => (ended = resolve));
        item.on("changed", (fields) => {
            const to = fields[1] ? fields[1].value : null;
            states.push(to);
            if (to !== RUNNING) ended();
        });
        await new Promise((resolve, reject) => {
            item.on("initialized", resolve);
            item.on("err", (e) => reject(new Error(`CreateMonitoredItems: ${e}`)));
        });
        const w = await s.write({
            nodeId: n.force,
            attributeId: AttributeIds.Value,
            value: { value: new Variant({ dataType: DataType.Double, value: force }) },
        });
        expectGood(w, "write Force");
        const st = await s.call({ objectId: n.skill, methodId: n.start, inputArguments: [] });
        expectGood(st.statusCode, "call Start");
        await done;
        await subscription.terminate().catch(() => {});
        expect(states[0] === RUNNING, `states ${JSON.stringify(states)}, expected Running first`);
        const result = (await readValue(n.result, "FinalResultData/Result")).value;
        const message = (await readValue(n.message, "FinalResultData/Message")).value;
        const text = message && message.text !== undefined ? message.text : message;
        out(`result: ${result} message: ${text}`);
        if (expected === "completed") {
            expect(result === RESULT_COMPLETED, `Result ${result} (${text})`);
        } else {
            expect(result === RESULT_FAILED, `Result ${result}, expected Failed (${text})`);
            const want = expected.slice("failed:".length);
            expect(text === want, `Message "${text}", expected "${want}"`);
        }
    });

    await cleanup();
    finish();
}

main().catch(unexpected);
