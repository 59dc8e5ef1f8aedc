#!/usr/bin/env node
"use strict";
// node-opcua interop client: exercises an OPC UA server that exposes the pnp demo
// namespace (see demo_types.js) and prints one TAP-like line per check:
//   ok - <name>
//   not ok - <name>: <reason>
//   skip - <name>: <reason>
// Exit code 0 only if every (non-skipped) check passed. The whole run is bounded
// by a hard deadline (PNP_CLIENT_DEADLINE_MS, default 55 s).
//
// usage: node tests/interop/node_client.js opc.tcp://127.0.0.1:4840

const { urlArg, noneClient, oneLine, expect, Skip, checks } = require("./common");
const {
    MessageSecurityMode,
    SecurityPolicy,
    UserTokenType,
    AttributeIds,
    BrowseDirection,
    DataType,
    Variant,
    VariantArrayType,
    StatusCodes,
    ServerState,
    ServerStatusDataType,
    BinaryStream,
    coerceNodeId,
    makeAccessLevelFlag,
} = require("node-opcua");
const demo = require("./demo_types");

const url = urlArg("node_client.js");
const DEADLINE_MS = parseInt(process.env.PNP_CLIENT_DEADLINE_MS || "55000", 10);
const STEP_TIMEOUT_MS = parseInt(process.env.PNP_CLIENT_STEP_TIMEOUT_MS || "10000", 10);
const { check, finish, unexpected, abort } = checks({
    tag: "node_client",
    deadlineMs: DEADLINE_MS,
    stepTimeoutMs: STEP_TIMEOUT_MS,
});

function sc(statusCode) {
    return statusCode ? statusCode.toString() : String(statusCode);
}

function expectGood(statusCode, what) {
    expect(statusCode && statusCode.isGood(), `${what}: status ${sc(statusCode)}`);
}

function encodeVariant(v) {
    const stream = new BinaryStream(v.binaryStoreSize());
    v.encode(stream);
    return stream.buffer;
}

function describeVariant(v) {
    try {
        const arr = v.arrayType === VariantArrayType.Scalar ? "" : "[]";
        return `${DataType[v.dataType]}${arr} ${oneLine(v.toString()).slice(0, 120)}`;
    } catch (e) {
        return "<unprintable variant>";
    }
}

// Two variants are equal when their OPC UA binary encodings are byte-identical.
function sameVariant(a, b) {
    return encodeVariant(a).equals(encodeVariant(b));
}

async function main() {
    const client = noneClient("pnp-interop-node-client", {
        requestedSessionTimeout: 30000,
        transportTimeout: 10000,
        defaultTransactionTimeout: 10000,
        keepSessionAlive: false,
    });

    // ---- connection + discovery -----------------------------------------------------
    const connected = await check("connect (Hello/Acknowledge, OpenSecureChannel None)", async () => {
        await client.connect(url);
    });
    if (!connected) {
        abort();
    }

    await check("GetEndpoints returns >=1 endpoint with SecurityPolicy None", async () => {
        const endpoints = await client.getEndpoints();
        expect(Array.isArray(endpoints) && endpoints.length >= 1, "no endpoints returned");
        const none = endpoints.filter(
            (e) => e.securityPolicyUri === SecurityPolicy.None && e.securityMode === MessageSecurityMode.None,
        );
        expect(none.length >= 1, `no None/None endpoint among ${endpoints.map((e) => e.securityPolicyUri).join(",")}`);
    });

    await check("GetEndpoints advertises Anonymous and UserName identity tokens", async () => {
        const endpoints = await client.getEndpoints();
        const tokens = endpoints
            .filter((e) => e.securityPolicyUri === SecurityPolicy.None)
            .flatMap((e) => e.userIdentityTokens || []);
        const types = new Set(tokens.map((t) => t.tokenType));
        expect(types.has(UserTokenType.Anonymous), "no Anonymous token policy");
        expect(types.has(UserTokenType.UserName), "no UserName token policy");
    });

    // ---- anonymous session ------------------------------------------------------------
    let session = null;
    const haveSession = await check("CreateSession + ActivateSession (anonymous)", async () => {
        session = await client.createSession();
        expect(session, "no session object");
    });
    if (!haveSession) {
        await client.disconnect().catch(() => {});
        abort();
    }

    let demoNs = -1;
    await check('NamespaceArray (i=2255) contains "urn:pnp:demo"', async () => {
        const dv = await session.read({ nodeId: "i=2255", attributeId: AttributeIds.Value });
        expectGood(dv.statusCode, "read NamespaceArray");
        const arr = dv.value.value;
        expect(Array.isArray(arr), `NamespaceArray is not an array (${describeVariant(dv.value)})`);
        expect(arr[0] === "http://opcfoundation.org/UA/", `NamespaceArray[0] = ${arr[0]}`);
        demoNs = arr.indexOf(demo.DEMO_NS_URI);
        expect(demoNs > 0, `"${demo.DEMO_NS_URI}" not found in [${arr.join(", ")}]`);
    });
    if (demoNs <= 0) {
        await session.close().catch(() => {});
        await client.disconnect().catch(() => {});
        abort();
    }
    const demoId = (s) => coerceNodeId(`ns=${demoNs};s=${s}`);
    const DEMO = demoId("Demo");

    await check("Browse ObjectsFolder (i=85) contains Server (i=2253) and Demo", async () => {
        const br = await session.browse({
            nodeId: "i=85",
            browseDirection: BrowseDirection.Forward,
            referenceTypeId: "HierarchicalReferences",
            includeSubtypes: true,
            nodeClassMask: 0,
            resultMask: 0x3f,
        });
        expectGood(br.statusCode, "browse i=85");
        const refs = br.references || [];
        const ids = refs.map((r) => r.nodeId.toString());
        expect(ids.includes("ns=0;i=2253"), `Server not found in [${ids.join(", ")}]`);
        const d = refs.find((r) => r.nodeId.toString() === DEMO.toString());
        expect(d, `${DEMO.toString()} not found in [${ids.join(", ")}]`);
        expect(d.browseName.name === "Demo", `Demo browse name is ${d.browseName.toString()}`);
    });

    await check("Browse Demo lists all demo variables and methods", async () => {
        const br = await session.browse({
            nodeId: DEMO,
            browseDirection: BrowseDirection.Forward,
            referenceTypeId: "HierarchicalReferences",
            includeSubtypes: true,
            nodeClassMask: 0,
            resultMask: 0x3f,
        });
        expectGood(br.statusCode, "browse Demo");
        const ids = new Set((br.references || []).map((r) => r.nodeId.toString()));
        const want = ["Demo.Echo", "Demo.Add"];
        for (const t of demo.TYPES) want.push(`Scalar.${t.name}`, `Array.${t.name}`);
        const missing = want.filter((s) => !ids.has(demoId(s).toString()));
        expect(missing.length === 0, `missing: ${missing.join(", ")}`);
    });

    await check("ServerStatus (i=2256) is ExtensionObject, State Running, CurrentTime ~ now", async () => {
        const dv = await session.read({ nodeId: "i=2256", attributeId: AttributeIds.Value });
        expectGood(dv.statusCode, "read ServerStatus");
        expect(dv.value.dataType === DataType.ExtensionObject, `dataType ${DataType[dv.value.dataType]}`);
        const st = dv.value.value;
        expect(st instanceof ServerStatusDataType, `value not decoded as ServerStatusDataType (${st && st.constructor && st.constructor.name})`);
        expect(st.state === ServerState.Running, `state ${ServerState[st.state]} (${st.state})`);
        const skew = Math.abs(st.currentTime.getTime() - Date.now());
        expect(skew < 30000, `CurrentTime ${st.currentTime.toISOString()} is ${skew} ms from now`);
        expect(st.startTime.getTime() <= st.currentTime.getTime(), "StartTime after CurrentTime");
    });

    // ---- demo variables -----------------------------------------------------------------
    const rwMask = makeAccessLevelFlag("CurrentRead | CurrentWrite");
    for (const t of demo.TYPES) {
        for (const kind of ["Scalar", "Array"]) {
            const isArray = kind === "Array";
            const name = `${kind}.${t.name}`;
            const nodeId = demoId(name);

            await check(`${name} attributes (DataType i=${t.typeNodeId}, ValueRank ${isArray ? 1 : -1}, AccessLevel RW)`, async () => {
                const dvs = await session.read([
                    { nodeId, attributeId: AttributeIds.DataType },
                    { nodeId, attributeId: AttributeIds.ValueRank },
                    { nodeId, attributeId: AttributeIds.AccessLevel },
                ]);
                expectGood(dvs[0].statusCode, "DataType");
                expectGood(dvs[1].statusCode, "ValueRank");
                expectGood(dvs[2].statusCode, "AccessLevel");
                const dt = dvs[0].value.value;
                expect(dt && dt.namespace === 0 && dt.value === t.typeNodeId, `DataType is ${dt && dt.toString()}`);
                const vr = dvs[1].value.value;
                expect(vr === (isArray ? 1 : -1), `ValueRank is ${vr}`);
                const al = dvs[2].value.value;
                expect((al & rwMask) === rwMask, `AccessLevel is 0x${Number(al).toString(16)}`);
            });

            await check(`${name} write a changed value and read it back`, async () => {
                const before = await session.read({ nodeId, attributeId: AttributeIds.Value });
                expectGood(before.statusCode, "initial read");
                let value = isArray ? demo.arrayVariant(t) : demo.scalarVariant(t);
                if (sameVariant(before.value, value)) {
                    // e.g. a second run against the same server: write the other
                    // value so that the write always changes what is stored.
                    value = isArray ? demo.arrayDefaultVariant(t) : demo.scalarDefaultVariant(t);
                }
                const ws = await session.write({ nodeId, attributeId: AttributeIds.Value, value: { value } });
                expectGood(ws, "write");
                const after = await session.read({ nodeId, attributeId: AttributeIds.Value });
                expectGood(after.statusCode, "read back");
                expect(
                    sameVariant(after.value, value),
                    `read back ${describeVariant(after.value)} != written ${describeVariant(value)}`,
                );
            });
        }
    }

    // ---- methods ------------------------------------------------------------------------
    // Echo: a few bytes, one chunk of 20 kB (pnp writes it by scatter-gather) and 300 kB in
    // several chunks.
    const large = (size) => {
        const data = Buffer.alloc(size);
        for (let i = 0; i < size; ++i) data[i] = (i * 31) >> 3;
        return data;
    };
    const echoes = [
        ["Call Demo.Echo(ByteString) returns the same bytes",
            Buffer.from([0x00, 0x50, 0x4e, 0x50, 0xff, 0x7f, 0x80])],
        ["Call Demo.Echo(ByteString of 20000 bytes) returns the same bytes", large(20000)],
        ["Call Demo.Echo(ByteString of 300000 bytes) returns the same bytes", large(300000)],
    ];
    for (const [name, data] of echoes) {
        await check(name, async () => {
            const res = await session.call({
                objectId: DEMO,
                methodId: demoId("Demo.Echo"),
                inputArguments: [new Variant({ dataType: DataType.ByteString, value: data })],
            });
            expectGood(res.statusCode, "call");
            const out = res.outputArguments || [];
            expect(out.length === 1, `expected 1 output argument, got ${out.length}`);
            expect(out[0].dataType === DataType.ByteString, `output dataType ${DataType[out[0].dataType]}`);
            expect(Buffer.isBuffer(out[0].value) && out[0].value.equals(data),
                data.length > 64 ? `got ${out[0].value ? out[0].value.length : "no"} bytes back`
                    : `got ${describeVariant(out[0])}`);
        });
    }

    await check("Call Demo.Add(2, 3) returns Int32 5", async () => {
        const res = await session.call({
            objectId: DEMO,
            methodId: demoId("Demo.Add"),
            inputArguments: [
                new Variant({ dataType: DataType.Int32, value: 2 }),
                new Variant({ dataType: DataType.Int32, value: 3 }),
            ],
        });
        expectGood(res.statusCode, "call");
        const out = res.outputArguments || [];
        expect(out.length === 1, `expected 1 output argument, got ${out.length}`);
        expect(out[0].dataType === DataType.Int32 && out[0].value === 5, `got ${describeVariant(out[0])}`);
    });

    await check("Call Demo.Add with a String argument -> BadTypeMismatch or BadInvalidArgument", async () => {
        const res = await session.call({
            objectId: DEMO,
            methodId: demoId("Demo.Add"),
            inputArguments: [
                new Variant({ dataType: DataType.String, value: "two" }),
                new Variant({ dataType: DataType.Int32, value: 3 }),
            ],
        });
        const okCodes = [StatusCodes.BadTypeMismatch.value, StatusCodes.BadInvalidArgument.value];
        expect(okCodes.includes(res.statusCode.value), `status ${sc(res.statusCode)}`);
    });

    await check("Read of an unknown node -> BadNodeIdUnknown", async () => {
        const dv = await session.read({ nodeId: demoId("Does.Not.Exist"), attributeId: AttributeIds.Value });
        expect(dv.statusCode.value === StatusCodes.BadNodeIdUnknown.value, `status ${sc(dv.statusCode)}`);
    });

    // ---- Robotics (OPC 40010-1) loaded from NodeSet2 XML ---------------------------------
    // run_node_client_vs_pnp.sh starts the server with pnp.RobotCell.NodeSet2.xml (which
    // requires Robotics, IA and DI) and two instances made by AddressSpace::instantiate:
    // RobotSystem (Robotics MotionDeviceSystemType) and Arm1 (PnpArmType, a subtype of
    // MotionDeviceType with a ToolLoad structure defined in pnp.RobotCell). Skipped when the
    // server does not hold them (the node-opcua self test).
    const ROBOTICS_URI = "http://opcfoundation.org/UA/Robotics/";
    const CELL_URI = "urn:pnp:robotcell";
    let roboticsNs = -1;
    let cellNs = -1;
    await check("Robotics and pnp.RobotCell namespaces loaded from NodeSet2 XML", async () => {
        const dv = await session.read({ nodeId: "i=2255", attributeId: AttributeIds.Value });
        const arr = dv.value.value || [];
        roboticsNs = arr.indexOf(ROBOTICS_URI);
        cellNs = arr.indexOf(CELL_URI);
        if (roboticsNs < 0 || cellNs < 0) throw new Skip("server has no Robotics model loaded");
        expect(arr.includes("http://opcfoundation.org/UA/DI/"), "DI (required by Robotics) missing");
    });
    // Forward hierarchical children of a node by BrowseName.
    async function childrenOf(nodeId) {
        const r = await session.browse({
            nodeId,
            browseDirection: BrowseDirection.Forward,
            referenceTypeId: "i=33",
            includeSubtypes: true,
            resultMask: 63,
        });
        expectGood(r.statusCode, `browse ${nodeId}`);
        const byName = new Map();
        for (const ref of r.references) byName.set(ref.browseName.toString(), ref);
        return byName;
    }
    if (roboticsNs >= 0 && cellNs >= 0) {
        await check("browse RobotSystem: a MotionDeviceSystemType instance with its Mandatory folders", async () => {
            const objects = await childrenOf("i=85");
            const sys = objects.get("1:RobotSystem");
            expect(sys, `RobotSystem not below Objects (${[...objects.keys()].join(", ")})`);
            expect(sys.typeDefinition.toString() === `ns=${roboticsNs};i=1002`,
                `TypeDefinition ${sys.typeDefinition.toString()}`);
            const kids = await childrenOf(sys.nodeId);
            for (const name of ["MotionDevices", "Controllers", "SafetyStates"])
                expect(kids.has(`${roboticsNs}:${name}`), `no ${name} (${[...kids.keys()].join(", ")})`);
        });
        await check("browse Arm1: Mandatory children of PnpArmType, MotionDeviceType and DI", async () => {
            const kids = await childrenOf(`ns=1;s=Arm1`);
            const diNs = (await session.read({ nodeId: "i=2255", attributeId: AttributeIds.Value }))
                .value.value.indexOf("http://opcfoundation.org/UA/DI/");
            const want = [`${roboticsNs}:Axes`, `${roboticsNs}:PowerTrains`,
                `${roboticsNs}:MotionDeviceCategory`, `${diNs}:Manufacturer`, `${diNs}:SerialNumber`,
                `${cellNs}:ToolLoad`];
            for (const name of want) expect(kids.has(name), `no ${name} (${[...kids.keys()].join(", ")})`);
            expect(!kids.has(`${roboticsNs}:FlangeLoad`), "Optional FlangeLoad was instantiated");
        });
        await check("read Arm1.MotionDeviceCategory: DataType is the Robotics enumeration", async () => {
            const [dt, v] = await session.read([
                { nodeId: "ns=1;s=Arm1.MotionDeviceCategory", attributeId: AttributeIds.DataType },
                { nodeId: "ns=1;s=Arm1.MotionDeviceCategory", attributeId: AttributeIds.Value },
            ]);
            expectGood(dt.statusCode, "read DataType");
            expect(dt.value.value.toString() === `ns=${roboticsNs};i=18193`, `DataType ${dt.value.value}`);
            expectGood(v.statusCode, "read Value");
        });
        await check("read Arm1.ToolLoad: a structure of pnp.RobotCell decoded from its DataTypeDefinition", async () => {
            const dt = await session.read({ nodeId: "ns=1;s=Arm1.ToolLoad", attributeId: AttributeIds.DataType });
            expect(dt.value.value.toString() === `ns=${cellNs};i=3001`, `DataType ${dt.value.value}`);
            const dv = await session.read({ nodeId: "ns=1;s=Arm1.ToolLoad", attributeId: AttributeIds.Value });
            expectGood(dv.statusCode, "read Value");
            expect(dv.value.dataType === DataType.ExtensionObject, `got ${describeVariant(dv.value)}`);
            // node-opcua decodes the body with the StructureDefinition it reads from the server.
            const { promoteOpaqueStructure } = require("node-opcua-client-dynamic-extension-object");
            await promoteOpaqueStructure(session, [dv]);
            const load = dv.value.value;
            expect(load && load.name === "vacuum-gripper", `name: ${oneLine(JSON.stringify(load))}`);
            expect(load.mass === 2.5, `mass ${load.mass}`);
            const com = load.centerOfMass;
            expect(com && com.x === 0 && com.y === 0.01 && com.z === 0.12,
                `centerOfMass ${oneLine(JSON.stringify(com))}`);
        });
    }

    await check("CloseSession (anonymous)", async () => {
        await session.close();
        session = null;
    });

    // ---- username sessions ----------------------------------------------------------------
    await check("CreateSession with username operator/secret, read ServerStatus, close", async () => {
        const s = await client.createSession({
            type: UserTokenType.UserName,
            userName: "operator",
            password: "secret",
        });
        try {
            const dv = await s.read({ nodeId: "i=2259", attributeId: AttributeIds.Value });
            expectGood(dv.statusCode, "read ServerStatus.State");
            expect(dv.value.value === ServerState.Running, `State = ${dv.value.value}`);
        } finally {
            await s.close();
        }
    });

    await check("CreateSession with a wrong password -> BadUserAccessDenied/BadIdentityToken*", async () => {
        let s = null;
        try {
            s = await client.createSession({
                type: UserTokenType.UserName,
                userName: "operator",
                password: "wrong-password",
            });
        } catch (err) {
            const msg = String(err && err.message);
            expect(/Bad(UserAccessDenied|IdentityTokenRejected|IdentityTokenInvalid)/.test(msg), `unexpected error: ${msg}`);
            return;
        }
        await s.close().catch(() => {});
        throw new Error("session with a wrong password was activated");
    });

    await check("Disconnect (CloseSecureChannel)", async () => {
        await client.disconnect();
    });

    finish();
}

main().catch(unexpected);
