#!/usr/bin/env node
"use strict";
// node-opcua subscriber: subscribes on a server that exposes the pnp demo namespace with
// its live parts (Demo.Counter, Demo.FireEvent, DemoEventType with the custom field
// Sequence, the Demo.Program state machine; see src/ua/demo/demo.hpp) to data changes and
// to events, transfers the subscription to a second session and back (TransferSubscriptions),
// and prints one TAP-like line per check (the format of node_client.js, so scripts/test.sh
// counts them):
//   ok - <name> | not ok - <name>: <reason> | skip - <name>: <reason>
// then "node_client: N passed, N failed, N skipped" (the summary scripts/test.sh reads).
// Exit 0 only if every check passed. Bounded by PNP_CLIENT_DEADLINE_MS (default 45 s).
//
// usage: node tests/interop/node_subscriber.js opc.tcp://127.0.0.1:4840

const { urlArg, noneClient, expect, checks } = require("./common");
const {
    AttributeIds,
    DataType,
    TimestampsToReturn,
    ClientSubscription,
    ClientMonitoredItem,
    constructEventFilter,
    DataChangeFilter,
    DataChangeTrigger,
    DeadbandType,
    ContentFilterElement,
    FilterOperator,
    LiteralOperand,
    Variant,
    StatusCodes,
    coerceNodeId,
    makeBrowsePath,
} = require("node-opcua");

const url = urlArg("node_subscriber.js");
const { check, finish, unexpected, abort } = checks({
    tag: "node_subscriber",
    deadlineMs: parseInt(process.env.PNP_CLIENT_DEADLINE_MS || "45000", 10),
    stepTimeoutMs: 10000,
});

// Resolves with the first `count` values the predicate accepts (bounded by the check's timeout).
function collect(item, count, accept = () => true) {
    return new Promise((resolve) => {
        const got = [];
        item.on("changed", (v) => {
            if (got.length < count && accept(v)) got.push(v);
            if (got.length === count) resolve(got);
        });
    });
}

// Waits until the server created the item; fails with its status otherwise.
async function created(item) {
    const status = await new Promise((resolve, reject) => {
        item.on("initialized", () => resolve(item.statusCode));
        item.on("err", (e) => reject(new Error(`monitored item: ${e}`)));
    });
    expect(status.isGood(), `CreateMonitoredItems: ${status.toString()}`);
}

async function main() {
    const client = noneClient("pnp-interop-node-subscriber", {
        requestedSessionTimeout: 30000,
        keepSessionAlive: false,
    });
    let session = null;
    let ns = -1;
    const up = await check("connect and create a session", async () => {
        await client.connect(url);
        session = await client.createSession();
        const dv = await session.read({ nodeId: "i=2255", attributeId: AttributeIds.Value });
        ns = dv.value.value.indexOf("urn:pnp:demo");
        expect(ns > 0, "urn:pnp:demo not in the NamespaceArray");
    });
    if (!up) abort();
    const id = (s) => coerceNodeId(`ns=${ns};s=${s}`);

    let subscription = null;
    await check("CreateSubscription (publishing interval 50 ms)", async () => {
        subscription = ClientSubscription.create(session, {
            requestedPublishingInterval: 50,
            requestedLifetimeCount: 600,
            requestedMaxKeepAliveCount: 20,
            maxNotificationsPerPublish: 1000,
            publishingEnabled: true,
            priority: 1,
        });
        await new Promise((resolve, reject) => {
            subscription.on("started", resolve);
            subscription.on("internal_error", reject);
        });
        expect(subscription.subscriptionId > 0, `subscriptionId ${subscription.subscriptionId}`);
        expect(subscription.publishingInterval >= 10, `revised interval ${subscription.publishingInterval}`);
    });
    if (!subscription) abort();

    await check("data changes of Demo.Counter (live, sampling interval 0)", async () => {
        const item = ClientMonitoredItem.create(
            subscription,
            { nodeId: id("Demo.Counter"), attributeId: AttributeIds.Value },
            { samplingInterval: 0, discardOldest: true, queueSize: 10 },
            TimestampsToReturn.Both,
        );
        const values = (await collect(item, 4)).map((dv) => dv.value.value);
        for (let i = 1; i < values.length; ++i)
            expect(values[i] > values[i - 1], `not increasing: ${values.join(", ")}`);
        await item.terminate();
    });

    await check("data change of Scalar.Double after a Write (sampling 100 ms, absolute deadband)", async () => {
        const nodeId = id("Scalar.Double");
        const item = ClientMonitoredItem.create(
            subscription,
            { nodeId, attributeId: AttributeIds.Value },
            {
                samplingInterval: 100,
                queueSize: 1,
                filter: new DataChangeFilter({
                    trigger: DataChangeTrigger.StatusValue,
                    deadbandType: DeadbandType.Absolute,
                    deadbandValue: 0.5,
                }),
            },
            TimestampsToReturn.Both,
        );
        // The initial value, 12 and 13; 12.25 is within the deadband of 12.
        const seen = collect(item, 3);
        await created(item);
        for (const v of [12.0, 12.25, 13.0]) {
            const st = await session.write({
                nodeId, attributeId: AttributeIds.Value,
                value: { value: new Variant({ dataType: DataType.Double, value: v }) },
            });
            expect(st.isGood(), `write ${v}: ${st.toString()}`);
            await new Promise((r) => setTimeout(r, 150));
        }
        const values = (await seen).map((dv) => dv.value.value);
        expect(values[1] === 12.0 && values[2] === 13.0, `values ${values.join(", ")}`);
        await item.terminate();
    });

    await check("events of DemoEventType on the Server object: Message, Severity, custom field Sequence", async () => {
        const ofType = new ContentFilterElement({
            filterOperator: FilterOperator.OfType,
            filterOperands: [
                new LiteralOperand({ value: new Variant({ dataType: DataType.NodeId, value: id("DemoEventType") }) }),
            ],
        });
        const filter = constructEventFilter(
            ["Message", "Severity", `${ns}:Sequence`, "SourceName", "EventType"], ofType);
        const item = ClientMonitoredItem.create(
            subscription,
            { nodeId: coerceNodeId("i=2253"), attributeId: AttributeIds.EventNotifier },
            { samplingInterval: 0, queueSize: 100, filter },
            TimestampsToReturn.Both,
        );
        await created(item);
        const got = collect(item, 1, (fields) => fields[0].value && fields[0].value.text === "hello interop");
        const result = await session.call({
            objectId: id("Demo"),
            methodId: id("Demo.FireEvent"),
            inputArguments: [
                new Variant({ dataType: DataType.String, value: "hello interop" }),
                new Variant({ dataType: DataType.UInt16, value: 321 }),
            ],
        });
        expect(result.statusCode.isGood(), `FireEvent: ${result.statusCode.toString()}`);
        const [fields] = await got;
        expect(fields[1].dataType === DataType.UInt16 && fields[1].value === 321, `Severity ${fields[1].toString()}`);
        expect(fields[2].dataType === DataType.UInt32 && fields[2].value > 0, `Sequence ${fields[2].toString()}`);
        expect(fields[3].value === "Demo", `SourceName ${fields[3].toString()}`);
        expect(fields[4].value.toString() === id("DemoEventType").toString(), `EventType ${fields[4].toString()}`);
        await item.terminate();
    });

    await check("events on the Demo notifier (the demo's tick events reach it)", async () => {
        const item = ClientMonitoredItem.create(
            subscription,
            { nodeId: id("Demo"), attributeId: AttributeIds.EventNotifier },
            { samplingInterval: 0, queueSize: 100, filter: constructEventFilter(["Message", `${ns}:Sequence`]) },
            TimestampsToReturn.Both,
        );
        const [fields] = await collect(item, 1, (f) => f[0].value && f[0].value.text === "tick");
        expect(fields[1].value > 0, `Sequence ${fields[1].toString()}`);
        await item.terminate();
    });

    await check("TransferSubscriptions to a second session; the first hears Good_SubscriptionTransferred", async () => {
        const heard = new Promise((resolve) => subscription.once("status_changed", resolve));
        const other = await client.createSession();
        try {
            const id = subscription.subscriptionId;
            const r = await other.transferSubscriptions({ subscriptionIds: [id, 0x7ffffff0], sendInitialValues: true });
            const codes = r.results.map((x) => x.statusCode.toString()).join(", ");
            expect(r.results.length === 2 && r.results[0].statusCode.isGood(), `results: ${codes}`);
            expect(r.results[1].statusCode === StatusCodes.BadSubscriptionIdInvalid, `results: ${codes}`);
            const status = await heard;
            expect(status === StatusCodes.GoodSubscriptionTransferred, `status change: ${status.toString()}`);
            // Back to the first session, which deletes it below.
            const back = await session.transferSubscriptions({ subscriptionIds: [id], sendInitialValues: false });
            expect(back.results[0].statusCode.isGood(), `back: ${back.results[0].statusCode.toString()}`);
        } finally {
            await other.close(true);
        }
    });

    await check("Demo.Program (ProgramStateMachineType): CurrentState and a transition event per method call", async () => {
        const program = id("Demo.Program");
        const child = async (name) => {
            const r = await session.translateBrowsePath(makeBrowsePath(program, `/${name}`));
            expect(r.statusCode.isGood() && r.targets.length === 1, `${name}: ${r.statusCode.toString()}`);
            return r.targets[0].targetId;
        };
        const currentState = await child("CurrentState");
        const currentStateId = await child("CurrentState.Id");
        const state = async () => (await session.read({ nodeId: currentState, attributeId: AttributeIds.Value })).value.value.text;
        expect((await state()) === "Ready", `CurrentState ${await state()}`);
        const idValue = (await session.read({ nodeId: currentStateId, attributeId: AttributeIds.Value })).value.value;
        expect(idValue.toString() === "ns=0;i=2400", `CurrentState/Id ${idValue.toString()}`);

        const ofType = new ContentFilterElement({
            filterOperator: FilterOperator.OfType,
            filterOperands: [
                new LiteralOperand({ value: new Variant({ dataType: DataType.NodeId, value: coerceNodeId("i=2311") }) }),
            ],
        });
        const item = ClientMonitoredItem.create(
            subscription,
            { nodeId: id("Demo"), attributeId: AttributeIds.EventNotifier },
            { samplingInterval: 0, queueSize: 100, filter: constructEventFilter(["EventType", "Transition", "FromState", "ToState"], ofType) },
            TimestampsToReturn.Both,
        );
        await created(item);
        const got = collect(item, 3);
        for (const method of ["Start", "Halt", "Reset"]) {
            const result = await session.call({ objectId: program, methodId: await child(method), inputArguments: [] });
            expect(result.statusCode.isGood(), `${method}: ${result.statusCode.toString()}`);
        }
        const again = await session.call({ objectId: program, methodId: await child("Resume"), inputArguments: [] });
        expect(again.statusCode.isBad(), `Resume in Ready: ${again.statusCode.toString()}`);
        const events = await got;
        const seen = events.map((f) => `${f[1].value.text}:${f[2].value.text}->${f[3].value.text}`).join(", ");
        expect(seen === "ReadyToRunning:Ready->Running, RunningToHalted:Running->Halted, HaltedToReady:Halted->Ready",
            `events ${seen}`);
        expect(events[0][0].value.toString() === "ns=0;i=2378", `EventType ${events[0][0].toString()}`);
        expect((await state()) === "Ready", `CurrentState ${await state()}`);
        await item.terminate();
    });

    await check("DeleteSubscriptions and close the session", async () => {
        await subscription.terminate();
        await session.close();
        await client.disconnect();
    });
    finish();
}

main().catch(unexpected);
