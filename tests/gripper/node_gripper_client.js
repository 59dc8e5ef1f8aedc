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

const {
    out, urlArg, noneClient, expect, checks, DI_URI, SKILLS_URI, RUNNING, RESULT_COMPLETED,
    RESULT_FAILED, expectGood, browseChildren, resolvePath, readValue, namespaceIndexes,
    devicesWithInterface, watchSkillStates,
} = require("../interop/common");
const { AttributeIds, DataType, Variant, coerceNodeId } = require("node-opcua");

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

    const ns = {};
    const up = await check("connect; NamespaceArray has DI and the skill model", async () => {
        await client.connect(url);
        s = await client.createSession();
        Object.assign(ns, await namespaceIndexes(s, { di: DI_URI, skills: SKILLS_URI }));
    });
    if (!up) {
        await cleanup();
        abort();
    }

    const n = {};
    const found = await check("browse DeviceSet -> the IGripperType device -> Skills -> Grasp",
        async () => {
            const grippers = await devicesWithInterface(s, ns.di, `ns=${ns.skills};i=1020`);
            expect(grippers.length === 1, `${grippers.length} devices implement IGripperType`);
            n.device = coerceNodeId(grippers[0].nodeId.toString());
            const skills = await resolvePath(s, n.device, [[ns.skills, "Skills"]]);
            const grasps = (await browseChildren(s, skills)).filter((r) =>
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
            const type = await readValue(s, await resolvePath(s, gp, [[ns.skills, "Type"]]), "Type");
            expect(type === 0, `Type ${type}, expected 0 (Parallel)`);
            const offset = await readValue(s, await resolvePath(s, gp, [[ns.skills, "Offset"]]),
                "Offset");
            expect(offset && offset.cartesianCoordinates,
                `Offset is not a ThreeDFrame: ${JSON.stringify(offset)}`);
            out(`offset-z: ${offset.cartesianCoordinates.z}`);
            const span = await readValue(s, await resolvePath(s, gp, [[ns.skills, "Span"]]),
                "Span");
            expect(span && typeof span.low === "number" && typeof span.high === "number",
                `Span is not a Range: ${JSON.stringify(span)}`);
            out(`span: [${span.low}, ${span.high}]`);
        });

    await check(`Grasp: Write Force ${force}, Start -> Running, then ${expected}`, async () => {
        const watch = await watchSkillStates(s, n.skill);
        const w = await s.write({
            nodeId: n.force,
            attributeId: AttributeIds.Value,
            value: { value: new Variant({ dataType: DataType.Double, value: force }) },
        });
        expectGood(w, "write Force");
        const st = await s.call({ objectId: n.skill, methodId: n.start, inputArguments: [] });
        expectGood(st.statusCode, "call Start");
        await watch.ended;
        await watch.terminate();
        const states = watch.states;
        expect(states[0] === RUNNING, `states ${JSON.stringify(states)}, expected Running first`);
        const result = await readValue(s, n.result, "FinalResultData/Result");
        const message = await readValue(s, n.message, "FinalResultData/Message");
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
