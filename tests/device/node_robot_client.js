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

const {
    out, urlArg, noneClient, expect, checks, DI_URI, SKILLS_URI, READY, RUNNING,
    RESULT_COMPLETED, expectGood, browseChildren, resolvePath, readValue, namespaceIndexes,
    deviceSet, watchSkillStates,
} = require("../interop/common");
const { AttributeIds, DataType, Variant, coerceNodeId } = require("node-opcua");
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

const ROB_URI = "http://opcfoundation.org/UA/Robotics/";
const SKR_URI = "urn:pnp:ua:skills:robotics";

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

    const ns = {};
    const up = await check("connect; NamespaceArray has DI, Robotics, the skill models", async () => {
        await client.connect(url);
        s = await client.createSession();
        Object.assign(ns, await namespaceIndexes(s,
            { di: DI_URI, rob: ROB_URI, skills: SKILLS_URI, skr: SKR_URI }));
    });
    if (!up) {
        await cleanup();
        abort();
    }

    const n = { axes: [] };
    const found = await check("browse DeviceSet -> MotionDeviceSystem -> MotionDevices -> device " +
        "-> Axes (6 AxisType) and Skills -> CartesianLinearMove", async () => {
        const systems = byType(await browseChildren(s, await deviceSet(s, ns.di)),
            `ns=${ns.rob};i=1002`);
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
        const eu = await readValue(s, await resolvePath(s, n.axes[0], [[0, "EngineeringUnits"]]),
            "EngineeringUnits");
        expect(eu && eu.displayName && eu.displayName.text === "rad",
            `EngineeringUnits ${eu && eu.displayName && eu.displayName.text}`);
    });

    await check("CartesianLinearMove: Write TargetPosition, Start -> Running, Ready; Completed",
        async () => {
            const watch = await watchSkillStates(s, n.skill);
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
            await watch.ended;
            await watch.terminate();
            const states = watch.states;
            expect(states[0] === RUNNING && states[states.length - 1] === READY,
                `states ${JSON.stringify(states)}, expected Running then Ready`);
            const result = await readValue(s, n.result, "FinalResultData/Result");
            const message = await readValue(s, n.message, "FinalResultData/Message");
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
