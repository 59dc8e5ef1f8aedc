#!/usr/bin/env node
"use strict";
// node-opcua as an independent client of the Pick-and-Place component (`pnp component
// pick-place`): with standard OPC UA services only (Read, Browse, Write, Call) it finds
// DeviceSet -> the device with HasInterface ISkillControllerType -> Skills -> the skill whose
// TypeDefinition is PickAndPlaceSkillType (urn:pnp:ua:skills:composite, i=1001), writes
// ObjectId and PlacePosition (a ThreeDFrame), calls Start and reads CurrentState /
// FinalResultData until the run ended: it must be Completed, with FinalResultData/Steps
// naming the steps. One line per check, then the summary; exit 0 only if all passed.
//
// usage: node tests/interop/node_pickplace_client.js opc.tcp://HOST:PORT OBJECT_ID x,y,z,a,b,c
// (the run is bounded by PNP_CLIENT_DEADLINE_MS, default 120 s: the robot really moves)

const {
    noneClient, expect, checks, DI_URI, SKILLS_URI, READY, HALTED, RESULT_COMPLETED,
    expectGood, browseChildren, resolvePath, readValue, namespaceIndexes, devicesWithInterface,
} = require("./common");
const { AttributeIds, DataType, Variant } = require("node-opcua");
const { ThreeDFrame } = require("node-opcua-types");

const [url, objectId, placeText] = process.argv.slice(2);
if (!url || !objectId || !placeText) {
    console.error("usage: node node_pickplace_client.js opc.tcp://HOST:PORT OBJECT_ID x,y,z,a,b,c");
    process.exit(2);
}
const COMPOSITE_URI = "urn:pnp:ua:skills:composite";
const deadlineMs = parseInt(process.env.PNP_CLIENT_DEADLINE_MS || "120000", 10);
const { check, finish, unexpected } = checks({
    tag: "node_pickplace_client",
    deadlineMs,
    stepTimeoutMs: 10000,
});

async function main() {
    const client = noneClient("pnp-interop-node-pickplace-client", {
        requestedSessionTimeout: 60000,
        keepSessionAlive: true,
    });
    let session = null;
    let ns = null;
    let skill = null;
    const params = {};
    try {
        await check("connect, NamespaceArray has DI, skills, composite", async () => {
            await client.connect(url);
            session = await client.createSession();
            ns = await namespaceIndexes(session, {
                di: DI_URI, skills: SKILLS_URI, composite: COMPOSITE_URI,
            });
        });
        if (!session) return;
        await check("browse to the PickAndPlace skill by its type", async () => {
            const iface = `ns=${ns.skills};i=1002`;  // ISkillControllerType
            const type = `ns=${ns.composite};i=1001`;  // PickAndPlaceSkillType
            for (const d of await devicesWithInterface(session, ns.di, iface)) {
                const skills = await resolvePath(session, d.nodeId, [[ns.skills, "Skills"]])
                    .catch(() => null);
                if (!skills) continue;
                for (const s of await browseChildren(session, skills))
                    if (s.typeDefinition && s.typeDefinition.toString() === type) skill = s.nodeId;
            }
            expect(skill, "no skill of PickAndPlaceSkillType below DeviceSet");
            const set = await resolvePath(session, skill, [[ns.di, "ParameterSet"]]);
            for (const p of await browseChildren(session, set)) params[p.browseName.name] = p.nodeId;
            for (const name of ["ObjectId", "PlacePosition", "ToolSkillControllerEndpoint",
                "MoveSkillControllerEndpoint", "SkillStep"])
                expect(params[name], `no parameter ${name}`);
        });
        if (!skill) return;
        const stateNumber = await resolvePath(session, skill,
            [[0, "CurrentState"], [0, "Number"]]).catch(() => null);
        const result = await resolvePath(session, skill,
            [[0, "FinalResultData"], [ns.skills, "Result"]]).catch(() => null);
        const message = await resolvePath(session, skill,
            [[0, "FinalResultData"], [ns.skills, "Message"]]).catch(() => null);
        await check("write ObjectId and PlacePosition (ThreeDFrame)", async () => {
            const v = placeText.split(",").map(Number);
            expect(v.length === 6 && v.every(Number.isFinite), `bad place ${placeText}`);
            const frame = new ThreeDFrame({
                cartesianCoordinates: { x: v[0], y: v[1], z: v[2] },
                orientation: { a: v[3], b: v[4], c: v[5] },
            });
            const statuses = await session.write([
                { nodeId: params.ObjectId, attributeId: AttributeIds.Value,
                  value: { value: new Variant({ dataType: DataType.String, value: objectId }) } },
                { nodeId: params.PlacePosition, attributeId: AttributeIds.Value,
                  value: { value: new Variant({ dataType: DataType.ExtensionObject, value: frame }) } },
            ]);
            statuses.forEach((s, i) => expectGood(s, `Write ${["ObjectId", "PlacePosition"][i]}`));
        });
        let started = false;
        await check("Start (Call), the skill leaves Ready", async () => {
            const start = await resolvePath(session, skill, [[0, "Start"]]);
            const r = await session.call({ objectId: skill, methodId: start, inputArguments: [] });
            expectGood(r.statusCode, "Call Start");
            started = true;
        });
        if (!started) return;
        await check("the run ends Completed (polled with Read), FinalResultData/Steps set", async () => {
            const until = Date.now() + deadlineMs - 5000;
            let state = null, res = null;
            for (let i = 0; i < 10000 && Date.now() < until; i++) {
                await new Promise((r) => setTimeout(r, 100));
                state = await readValue(session, stateNumber, "CurrentState/Number");
                res = await readValue(session, result, "FinalResultData/Result");
                if ((state === READY || state === HALTED) && res !== 0) break;
            }
            const msg = await readValue(session, message, "FinalResultData/Message");
            expect(res === RESULT_COMPLETED, `Result ${res} (state ${state}): ${msg}`);
            const steps = await resolvePath(session, skill,
                [[0, "FinalResultData"], [ns.composite, "Steps"]]);
            const names = await readValue(session, steps, "FinalResultData/Steps");
            expect(names && names.includes("Grasp") && names.includes("Release"),
                `Steps: ${names}`);
            console.log(`# ${msg}`);
        }, deadlineMs);
    } finally {
        if (session) await session.close().catch(() => {});
        await client.disconnect().catch(() => {});
    }
    finish();
}

main().catch(unexpected);
