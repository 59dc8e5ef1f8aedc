#!/usr/bin/env node
"use strict";
// node-opcua as an independent skill client: drives the Delay skill of `pnp demo-skills` with
// standard OPC UA services only (Read, Write, Browse, TranslateBrowsePathsToNodeIds, Call,
// CreateSubscription / CreateMonitoredItems with an EventFilter) — no pnp library involved.
// Everything is found by browsing from the ObjectsFolder and the NamespaceArray (see
// /work/notes/skill_contract.md): DeviceSet (DI) -> the device with a HasInterface reference
// to ISkillControllerType -> Skills -> the skill whose TypeDefinition is DelaySkillType.
// Checks: (a) a successful run (events Running, Ready; Result Completed), (b) a failing run
// (event to Halted with the reason; Result Failed; Reset), (c) DI locking by a second session
// (BadLocked for Write and Start, InitLock -1, ExitLock, then Good), (d) Start while Running
// is refused. One line per check (ok - / not ok - NAME: reason), then the summary line.
// Exit 0 only if every check passed; the whole run is bounded by PNP_CLIENT_DEADLINE_MS
// (default 30 s).
//
// usage: node tests/interop/node_skill_client.js opc.tcp://127.0.0.1:4840

const {
    urlArg, noneClient, expect, checks, DI_URI, SKILLS_URI, BASE_EVENT_TYPE,
    PROGRAM_TRANSITION_EVENT_TYPE, HALTED, READY, RUNNING, RESULT_COMPLETED, RESULT_FAILED,
    statusText: sc, expectGood, browseChildren, resolvePath, namespaceIndexes,
    devicesWithInterface, startSubscription,
} = require("./common");
const {
    AttributeIds,
    DataType,
    TimestampsToReturn,
    ClientMonitoredItem,
    ContentFilter,
    ContentFilterElement,
    EventFilter,
    FilterOperator,
    LiteralOperand,
    SimpleAttributeOperand,
    Variant,
    StatusCodes,
    coerceNodeId,
} = require("node-opcua");

const url = urlArg("node_skill_client.js");
const { check, finish, unexpected, abort } = checks({
    tag: "node_skill_client",
    deadlineMs: parseInt(process.env.PNP_CLIENT_DEADLINE_MS || "30000", 10),
    stepTimeoutMs: 8000,
});

const DEMO_URI = "urn:pnp:ua:skills:demo";

// Part 10 ProgramStateMachineType transition numbers.
const HALTED_TO_READY = 1;
const READY_TO_RUNNING = 2;
const RUNNING_TO_HALTED = 3;
const RUNNING_TO_READY = 4;

function expectStatus(status, want, what) {
    expect(status && status.value === want.value, `${what}: ${sc(status)}, expected ${want.name}`);
}

// An EventFilter selecting `paths` (typeDefinitionId, [names]) with OfType(eventType).
function eventFilter(selects, eventType) {
    const selectClauses = selects.map(([typeDefinitionId, names]) => new SimpleAttributeOperand({
        typeDefinitionId,
        browsePath: names.map((name) => ({ namespaceIndex: 0, name })),
        attributeId: AttributeIds.Value,
    }));
    const whereClause = new ContentFilter({
        elements: [new ContentFilterElement({
            filterOperator: FilterOperator.OfType,
            filterOperands: [new LiteralOperand({
                value: new Variant({ dataType: DataType.NodeId, value: eventType }),
            })],
        })],
    });
    return new EventFilter({ selectClauses, whereClause });
}

const SELECTS = [
    [BASE_EVENT_TYPE, ["EventType"]],
    [BASE_EVENT_TYPE, ["SourceNode"]],
    [PROGRAM_TRANSITION_EVENT_TYPE, ["Transition", "Number"]],
    [PROGRAM_TRANSITION_EVENT_TYPE, ["FromState", "Number"]],
    [PROGRAM_TRANSITION_EVENT_TYPE, ["ToState", "Number"]],
    [PROGRAM_TRANSITION_EVENT_TYPE, ["IntermediateResult"]],
    [BASE_EVENT_TYPE, ["Time"]],
    [BASE_EVENT_TYPE, ["Message"]],
    [BASE_EVENT_TYPE, ["Severity"]],
];
function decodeEvent(fields) {
    const v = (i) => (fields[i] ? fields[i].value : null);
    return {
        eventType: v(0),
        sourceNode: v(1),
        transition: v(2),
        from: v(3),
        to: v(4),
        intermediateResult: fields[5],
        time: v(6),
        message: v(7) && typeof v(7) === "object" ? v(7).text : v(7),
        severity: v(8),
    };
}
const describeEvent = (e) =>
    `{transition ${e.transition}, ${e.from}->${e.to}, source ${e.sourceNode}, ` +
    `message ${JSON.stringify(e.message)}}`;

// The events of one monitored item, awaited one by one.
class EventQueue {
    constructor(item) {
        this.events = [];
        this.waiters = [];
        item.on("changed", (fields) => {
            this.events.push(decodeEvent(fields));
            this.flush();
        });
    }
    flush() {
        while (this.waiters.length && this.events.length) this.waiters.shift()(this.events.shift());
    }
    next(ms, what) {
        return new Promise((resolve, reject) => {
            const timer = setTimeout(() => {
                this.waiters = this.waiters.filter((w) => w !== done);
                reject(new Error(`no event within ${ms} ms (${what})`));
            }, ms);
            const done = (e) => {
                clearTimeout(timer);
                resolve(e);
            };
            this.waiters.push(done);
            this.flush();
        });
    }
    clear() {
        this.events = [];
    }
}

async function main() {
    const clientA = noneClient("pnp-interop-node-skill-client-A", {
        requestedSessionTimeout: 30000,
        keepSessionAlive: false,
    });
    const clientB = noneClient("pnp-interop-node-skill-client-B", {
        requestedSessionTimeout: 30000,
        keepSessionAlive: false,
    });
    let a = null;
    let b = null;
    const cleanup = async () => {
        for (const s of [a, b]) if (s) await s.close().catch(() => {});
        for (const c of [clientA, clientB]) await c.disconnect().catch(() => {});
    };

    let ns = {};
    const up = await check("connect, session A, NamespaceArray has skills, demo, DI", async () => {
        await clientA.connect(url);
        a = await clientA.createSession();
        ns = await namespaceIndexes(a, { skills: SKILLS_URI, demo: DEMO_URI, di: DI_URI });
    });
    if (!up) {
        await cleanup();
        abort();
    }

    // ---- discovery by browsing ---------------------------------------------------------
    let device = null;
    let skill = null;
    const browsePath = "browse Objects -> DeviceSet -> skill controller -> Skills -> Delay";
    const found = await check(browsePath, async () => {
        const iface = `ns=${ns.skills};i=1002`;
        const controllers = await devicesWithInterface(a, ns.di, iface);
        if (controllers.length) device = controllers[0].nodeId;
        expect(device, `no node below DeviceSet has a HasInterface reference to ${iface}`);
        const skills = await resolvePath(a, device, [[ns.skills, "Skills"]]);
        const delayType = `ns=${ns.demo};i=1001`;
        const kids = await browseChildren(a, skills);
        const delay = kids.find((r) => r.typeDefinition.toString() === delayType);
        expect(delay, `no skill of type ${delayType} in Skills (` +
            kids.map((r) => `${r.browseName.toString()}: ${r.typeDefinition.toString()}`)
                .join(", ") + ")");
        skill = coerceNodeId(delay.nodeId.toString());
    });
    if (!found) {
        await cleanup();
        abort();
    }

    const n = {};
    const translate = "TranslateBrowsePath: parameters, methods, FinalResultData, Lock";
    const resolved = await check(translate, async () => {
        const paths = {
            durationMs: [[ns.di, "ParameterSet"], [ns.demo, "DurationMs"]],
            failWith: [[ns.di, "ParameterSet"], [ns.demo, "FailWith"]],
            start: [[0, "Start"]],
            reset: [[0, "Reset"]],
            result: [[0, "FinalResultData"], [ns.skills, "Result"]],
            message: [[0, "FinalResultData"], [ns.skills, "Message"]],
            lock: [[ns.di, "Lock"]],
            initLock: [[ns.di, "Lock"], [ns.di, "InitLock"]],
            exitLock: [[ns.di, "Lock"], [ns.di, "ExitLock"]],
        };
        for (const [k, p] of Object.entries(paths)) n[k] = await resolvePath(a, skill, p);
    });
    if (!resolved) {
        await cleanup();
        abort();
    }

    const write = (session, nodeId, dataType, value) =>
        session.write({
            nodeId,
            attributeId: AttributeIds.Value,
            value: { value: { dataType, value } },
        });
    const call = (session, objectId, methodId, inputArguments = []) =>
        session.call({ objectId, methodId, inputArguments });
    const readValue = async (session, nodeId, what) => {
        const dv = await session.read({ nodeId, attributeId: AttributeIds.Value });
        expectGood(dv.statusCode, `read ${what}`);
        return dv.value.value;
    };

    // ---- the event subscription on the skill node ---------------------------------------
    let queue = null;
    const subscribe = "event monitored item on the skill, OfType SkillTransitionEventType";
    const subscribed = await check(subscribe, async () => {
        const subscription = await startSubscription(a);
        const filter = eventFilter(SELECTS, coerceNodeId(`ns=${ns.skills};i=1003`));
        const item = ClientMonitoredItem.create(
            subscription,
            { nodeId: skill, attributeId: AttributeIds.EventNotifier },
            { samplingInterval: 0, queueSize: 100, discardOldest: false, filter },
            TimestampsToReturn.Both,
        );
        queue = new EventQueue(item);
        const status = await new Promise((resolve, reject) => {
            item.on("initialized", () => resolve(item.statusCode));
            item.on("err", (e) => reject(new Error(`CreateMonitoredItems: ${e}`)));
        });
        expectGood(status, "CreateMonitoredItems");
        const fr = item.filterResult;
        if (fr && fr.selectClauseResults) {
            const bad = fr.selectClauseResults
                .map((s, i) => [s, SELECTS[i][1].join("/")])
                .filter(([s]) => s && !s.isGood());
            const text = bad.map(([s, p]) => `${p} ${sc(s)}`).join(", ");
            expect(bad.length === 0, `select clause results: ${text}`);
        }
    });
    if (!subscribed) {
        await cleanup();
        abort();
    }

    const expectEvent = async (want, what) => {
        const e = await queue.next(3000, what);
        expect(e.transition === want.transition && e.to === want.to,
            `${what}: expected transition ${want.transition} to state ${want.to}, ` +
            `got ${describeEvent(e)}`);
        expect(e.eventType && e.eventType.toString() === `ns=${ns.skills};i=1003`,
            `${what}: EventType ${e.eventType}`);
        expect(e.sourceNode && e.sourceNode.toString() === skill.toString(),
            `${what}: SourceNode ${e.sourceNode}, expected ${skill.toString()}`);
        expect(e.time instanceof Date && !isNaN(e.time.getTime()), `${what}: no Time (${e.time})`);
        expect(typeof e.severity === "number" && e.severity >= 1 && e.severity <= 1000,
            `${what}: Severity ${e.severity}`);
        return e;
    };

    // ---- (a) a successful run -----------------------------------------------------------
    const runA = "(a) DurationMs=50, Start -> events Running (2), Ready (4); Result Completed";
    await check(runA, async () => {
        queue.clear();
        expectGood(await write(a, n.durationMs, DataType.Double, 50), "write DurationMs");
        expectGood((await call(a, skill, n.start)).statusCode, "call Start");
        const running =
            await expectEvent({ transition: READY_TO_RUNNING, to: RUNNING }, "Running event");
        const ready = await expectEvent({ transition: RUNNING_TO_READY, to: READY }, "Ready event");
        expect(ready.time.getTime() >= running.time.getTime(), "Ready event before Running event");
        const result = await readValue(a, n.result, "FinalResultData/Result");
        expect(result === RESULT_COMPLETED, `Result ${result}, expected ${RESULT_COMPLETED}`);
    });

    // ---- (b) a failing run, then Reset --------------------------------------------------
    await check("(b) FailWith, Start -> transition 3 to Halted with reason; Result Failed; Reset",
        async () => {
            const reason = "node says no";
            queue.clear();
            expectGood(await write(a, n.failWith, DataType.String, reason), "write FailWith");
            expectGood((await call(a, skill, n.start)).statusCode, "call Start");
            await expectEvent({ transition: READY_TO_RUNNING, to: RUNNING }, "Running event");
            const halted =
                await expectEvent({ transition: RUNNING_TO_HALTED, to: HALTED }, "Halted event");
            expect(typeof halted.message === "string" && halted.message.includes(reason),
                `Halted event Message ${JSON.stringify(halted.message)} lacks "${reason}"`);
            const result = await readValue(a, n.result, "FinalResultData/Result");
            expect(result === RESULT_FAILED, `Result ${result}, expected ${RESULT_FAILED}`);
            const message = await readValue(a, n.message, "FinalResultData/Message");
            expect(message === reason, `Message ${JSON.stringify(message)}, expected "${reason}"`);
            expectGood((await call(a, skill, n.reset)).statusCode, "call Reset");
            await expectEvent({ transition: HALTED_TO_READY, to: READY }, "Reset event");
            expectGood(await write(a, n.failWith, DataType.String, ""), "write FailWith \"\"");
        });

    // ---- (c) DI locking with a second session -------------------------------------------
    await check("(c) lock by session A: B's Write/Start BadLocked, B's InitLock -1, then Good",
        async () => {
            await clientB.connect(url);
            b = await clientB.createSession();
            const initA = await call(a, n.lock, n.initLock,
                [new Variant({ dataType: DataType.String, value: "node" })]);
            expectGood(initA.statusCode, "A InitLock");
            const initResult = initA.outputArguments[0].value;
            expect(initResult === 0, `A InitLock -> ${initResult}`);
            let released = false;
            try {
                const wB = await write(b, n.durationMs, DataType.Double, 60);
                expectStatus(wB, StatusCodes.BadLocked, "B Write DurationMs");
                expectStatus((await call(b, skill, n.start)).statusCode, StatusCodes.BadLocked,
                    "B Start");
                const initB = await call(b, n.lock, n.initLock,
                    [new Variant({ dataType: DataType.String, value: "other" })]);
                expectGood(initB.statusCode, "B InitLock");
                expect(initB.outputArguments[0].value === -1,
                    `B InitLock -> ${initB.outputArguments[0].value}, expected -1`);
                const exitA = await call(a, n.lock, n.exitLock);
                released = true;
                expectGood(exitA.statusCode, "A ExitLock");
                const exitResult = exitA.outputArguments[0].value;
                expect(exitResult === 0, `A ExitLock -> ${exitResult}`);
                const wB2 = await write(b, n.durationMs, DataType.Double, 60);
                expectGood(wB2, "B Write after ExitLock");
            } finally {
                if (!released) await call(a, n.lock, n.exitLock).catch(() => {});
            }
        });

    // ---- (d) Start while Running ----------------------------------------------------------
    await check("(d) Start while Running -> BadNotExecutable or BadInvalidState", async () => {
        queue.clear();
        expectGood(await write(a, n.durationMs, DataType.Double, 1000), "write DurationMs");
        expectGood((await call(a, skill, n.start)).statusCode, "call Start");
        await expectEvent({ transition: READY_TO_RUNNING, to: RUNNING }, "Running event");
        const again = (await call(a, skill, n.start)).statusCode;
        const ok = [StatusCodes.BadNotExecutable.value, StatusCodes.BadInvalidState.value];
        expect(ok.includes(again.value), `second Start: ${sc(again)}`);
        await expectEvent({ transition: RUNNING_TO_READY, to: READY }, "Ready event of run 1");
    });

    await cleanup();
    finish();
}

main().catch(unexpected);
