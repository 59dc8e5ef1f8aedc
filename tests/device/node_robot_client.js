#!/usr/bin/env node
"use strict";
// node-opcua as an independent client of a pnp robot device (src/device/robot): standard
// services only (Read, Write, Browse, TranslateBrowsePathsToNodeIds, Call, an event monitored
// item). Everything is found by browsing and by type: Objects -> DI DeviceSet -> the
// OPC 40010-1 MotionDeviceSystem -> MotionDevices -> the motion device (a skill controller)
// -> Axes (AxisType) with ParameterSet/ActualPosition, and Skills -> the skill of type
// CartesianLinearMoveSkillType, which is run to TARGET (x,y,z,a,b,c: m, rad).
// Prints one line per check, `final-joints: [q1, ..., q6]` (ActualPosition after the move)
// and the summary. Exit 0 only if every check passed; bounded by PNP_CLIENT_DEADLINE_MS.
//
// usage: node tests/device/node_robot_client.js opc.tcp://127.0.0.1:4841 x,y,z,a,b,c

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
const { ThreeDFrame } = require("node-opcua-types");

const url = urlArg("node_robot_client.js");
const target = (process.argv[3] || "").split(",").map(Number);
if (target.length !== 6 || target.some((v) => !Number.isFinite(v))) {
    console.error("usage: node_robot_client.js URL x,y,z,a,b,c");
    process.exit(2);
}
const { check, finish, unexpected, abort } = checks({
    tag: "node_robot_client",
    deadlineMs: parseInt(process.env.PNP_CLIENT_DEADLINE_MS || "40000", 10),
    stepTimeoutMs: 15000,
});

const DI_URI = "http://opcfoundation.org/UA/DI/";
const ROB_URI = "http://opcfoundation.org/UA/Robotics/";
const SKILLS_URI = "urn:pnp:ua:skills";
const SKR_URI = "urn:pnp:ua:skills:robotics";
const HIERARCHICAL = coerceNodeId("i=33");
const PROGRAM_TRANSITION_EVENT_TYPE = coerceNodeId("i=2378");
const READY = 12;
const RUNNING = 13;
const RESULT_COMPLETED = 1;

const sc = (s) => (s ? s.toString() : String(s));
const expectGood = (status, what) => expect(status && status.isGood(), `${what}: ${sc(status)}`);

async function browseChildren(session, nodeId) {
    const r = await session.browse({
        nodeId,
        browseDirection: BrowseDirection.Forward,
        referenceTypeId: HIERARCHICAL,
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

const byType = (refs, type) => refs.filter((r) => r.typeDefinition.toString() === type);

async function main() {
    const client = noneClient("pnp-node-robot-client", {
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
        return dv.value.value;
    };

    const ns = {};
    const up = await check("connect; NamespaceArray has DI, Robotics, the skill models", async () => {
        await client.connect(url);
        s = await client.createSession();
        const arr = await readValue(coerceNodeId("i=2255"), "NamespaceArray");
        for (const [k, uri] of [["di", DI_URI], ["rob", ROB_URI], ["skills", SKILLS_URI],
            ["skr", SKR_URI]]) {
            ns[k] = arr.indexOf(uri);
            expect(ns[k] > 0, `"${uri}" not in [${arr.join(", ")}]`);
        }
    });
    if (!up) {
        await cleanup();
        abort();
    }

    const n = { axes: [] };
    const found = await check("browse DeviceSet -> MotionDeviceSystem -> MotionDevices -> device " +
        "-> Axes (6 AxisType) and Skills -> CartesianLinearMove", async () => {
        const objects = await browseChildren(s, coerceNodeId("i=85"));
        const deviceSet = objects.find((r) =>
            r.browseName.namespaceIndex === ns.di && r.browseName.name === "DeviceSet");
        expect(deviceSet, "no DI DeviceSet below Objects");
        const systems = byType(await browseChildren(s, deviceSet.nodeId), `ns=${ns.rob};i=1002`);
        expect(systems.length === 1, `${systems.length} MotionDeviceSystemType instances`);
        const motionDevices = await resolvePath(s, systems[0].nodeId, [[ns.rob, "MotionDevices"]]);
        const devices = byType(await browseChildren(s, motionDevices), `ns=${ns.skr};i=1012`);
        expect(devices.length === 1, `${devices.length} SkillMotionDeviceType instances`);
        n.device = coerceNodeId(devices[0].nodeId.toString());
        const axes = await resolvePath(s, n.device, [[ns.rob, "Axes"]]);
        const axisRefs = byType(await browseChildren(s, axes), `ns=${ns.rob};i=16601`);
        expect(axisRefs.length === 6, `${axisRefs.length} axes of AxisType`);
        axisRefs.sort((x, y) => x.browseName.name.localeCompare(y.browseName.name));
        for (const a of axisRefs)
            n.axes.push(await resolvePath(s, a.nodeId, [[ns.di, "ParameterSet"],
                [ns.rob, "ActualPosition"]]));
        const skills = await resolvePath(s, n.device, [[ns.skills, "Skills"]]);
        const linear = byType(await browseChildren(s, skills), `ns=${ns.skr};i=1007`);
        expect(linear.length === 1, `${linear.length} CartesianLinearMoveSkillType skills`);
        n.skill = coerceNodeId(linear[0].nodeId.toString());
        n.target = await resolvePath(s, n.skill, [[ns.di, "ParameterSet"], [ns.skr, "TargetPosition"]]);
        n.start = await resolvePath(s, n.skill, [[0, "Start"]]);
        n.result = await resolvePath(s, n.skill, [[0, "FinalResultData"], [ns.skills, "Result"]]);
        n.message = await resolvePath(s, n.skill, [[0, "FinalResultData"], [ns.skills, "Message"]]);
    });
    if (!found) {
        await cleanup();
        abort();
    }

    const readAxes = async () => {
        const dvs = await s.read(n.axes.map((nodeId) => ({ nodeId, attributeId: AttributeIds.Value })));
        return dvs.map((dv, i) => {
            expectGood(dv.statusCode, `read Axis${i + 1} ActualPosition`);
            expect(dv.value.dataType === DataType.Double, `Axis${i + 1}: not a Double`);
            return dv.value.value;
        });
    };
    let before = null;
    await check("Axes: ActualPosition (Double) and EngineeringUnits rad", async () => {
        before = await readAxes();
        const eu = await readValue(await resolvePath(s, n.axes[0], [[0, "EngineeringUnits"]]),
            "EngineeringUnits");
        expect(eu && eu.displayName && eu.displayName.text === "rad",
            `EngineeringUnits ${eu && eu.displayName && eu.displayName.text}`);
    });

    await check("CartesianLinearMove: Write TargetPosition, Start -> Running, Ready; Completed",
        async () => {
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
            const [x, y, z, a, b, c] = target;
            const frame = new ThreeDFrame({
                cartesianCoordinates: { x, y, z },
                orientation: { a, b, c },
            });
            const w = await s.write({
                nodeId: n.target,
                attributeId: AttributeIds.Value,
                value: { value: new Variant({ dataType: DataType.ExtensionObject, value: frame }) },
            });
            expectGood(w, "write TargetPosition");
            const st = await s.call({ objectId: n.skill, methodId: n.start, inputArguments: [] });
            expectGood(st.statusCode, "call Start");
            await done;
            await subscription.terminate().catch(() => {});
            expect(states[0] === RUNNING && states[states.length - 1] === READY,
                `states ${JSON.stringify(states)}, expected Running then Ready`);
            const result = await readValue(n.result, "FinalResultData/Result");
            const message = await readValue(n.message, "FinalResultData/Message");
            expect(result === RESULT_COMPLETED, `Result ${result} (${message})`);
        });

    await check("Axes: ActualPosition moved and settles", async () => {
        // Written at a bounded rate: the last values arrive within a few periods.
        let last = null;
        for (let i = 0; i < 50; i++) {
            const now = await readAxes();
            if (last && now.every((v, k) => v === last[k])) break;
            last = now;
            await new Promise((r) => setTimeout(r, 100));
        }
        expect(before && last.some((v, k) => Math.abs(v - before[k]) > 1e-3),
            `ActualPosition did not change: ${JSON.stringify(before)} -> ${JSON.stringify(last)}`);
        out(`final-joints: ${JSON.stringify(last)}`);
    });

    await cleanup();
    finish();
}

main().catch(unexpected);
