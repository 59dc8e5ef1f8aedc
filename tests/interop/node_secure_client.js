#!/usr/bin/env node
"use strict";
// node-opcua as a secured client (issue 24): connects with a given security policy and mode,
// its own PKI folder (server certificates are trusted only when they are in its
// trusted/certs: nothing is accepted automatically) and a user identity, reads
// Server_ServerStatus_State (i=2259) and the demo variable Scalar.Int32 when the server has the
// demo namespace, and calls Demo.Echo when asked.
//
// usage:
//   node node_secure_client.js --init --pki DIR [--export-cert FILE.der] [--application-uri URI]
//       creates the PKI folder and the client's certificate (own/certs/client_certificate.pem),
//       writes it as DER to FILE.der and prints
//       {"certificate":PEM,"certificateDer":FILE.der,"thumbprint":HEX,"applicationUri":URI}
//   node node_secure_client.js URL --pki DIR [--policy NAME|all] [--mode Sign|SignAndEncrypt|all]
//       [--identity anonymous | user:NAME:PASSWORD | x509:CERT.der:KEY.pem]... [--call-echo]
//       [--application-uri URI] [--timeout-ms N]
//       one connection (channel + session) per policy x mode x identity (one node start for a
//       whole matrix); one JSON line per connection on stdout:
//       {"policy","mode","identity","index","ok":true,"state":N,"demoInt32":N|null,
//        "call":"Good"|"BadXxx" (--call-echo),"echo":HEX|null}
//       or {"policy","mode","identity","index","ok":false,"status":"BadXxx"|null,"error":TEXT}
//       (index: the position of the --identity option, from 0).
//       Exit 0 when every connection succeeded; 1 otherwise (the failures' status text on
//       stderr too); 2 on a usage error.
// Policies: Basic256Sha256, Aes128_Sha256_RsaOaep, Aes256_Sha256_RsaPss (names or URIs).

const { out, oneLine, withTimeout } = require("./common");
const fs = require("fs");
const path = require("path");
const os = require("os");
const {
    OPCUACertificateManager,
    OPCUAClient,
    MessageSecurityMode,
    SecurityPolicy,
    AttributeIds,
    DataType,
    UserTokenType,
    coerceNodeId,
} = require("node-opcua");
const { convertPEMtoDER, makeSHA1Thumbprint } = require("node-opcua-crypto");

const SCRIPT = "node_secure_client.js";
const DEMO_NS_URI = "urn:pnp:demo";
const POLICIES = {
    Basic256Sha256: SecurityPolicy.Basic256Sha256,
    Aes128_Sha256_RsaOaep: SecurityPolicy.Aes128_Sha256_RsaOaep,
    Aes256_Sha256_RsaPss: SecurityPolicy.Aes256_Sha256_RsaPss,
};
const MODES = {
    Sign: MessageSecurityMode.Sign,
    SignAndEncrypt: MessageSecurityMode.SignAndEncrypt,
};

function usage(message) {
    console.error(`${SCRIPT}: ${message}`);
    console.error(
        `usage: ${SCRIPT} --init --pki DIR [--export-cert FILE.der] [--application-uri URI]\n` +
            `       ${SCRIPT} URL --pki DIR [--policy NAME|all] [--mode Sign|SignAndEncrypt|all]\n` +
            "           [--identity anonymous|user:NAME:PASSWORD|x509:CERT.der:KEY.pem]... " +
            "[--call-echo] [--application-uri URI] [--timeout-ms N]",
    );
    process.exit(2);
}

function parseArgs(argv) {
    const o = {
        init: false,
        url: null,
        pki: null,
        exportCert: null,
        applicationUri: "urn:pnp:interop:node-secure-client",
        policies: [],
        modes: [],
        identities: [],
        callEcho: false,
        timeoutMs: 15000,
    };
    const value = (i) => {
        if (i + 1 >= argv.length) usage(`${argv[i]} needs a value`);
        return argv[i + 1];
    };
    for (let i = 0; i < argv.length; i++) {
        const a = argv[i];
        if (a === "--init") o.init = true;
        else if (a === "--call-echo") o.callEcho = true;
        else if (a === "--pki") o.pki = value(i++);
        else if (a === "--export-cert") o.exportCert = value(i++);
        else if (a === "--application-uri") o.applicationUri = value(i++);
        else if (a === "--policy") o.policies.push(value(i++));
        else if (a === "--mode") o.modes.push(value(i++));
        else if (a === "--identity") o.identities.push(value(i++));
        else if (a === "--timeout-ms") o.timeoutMs = parseInt(value(i++), 10);
        else if (a.startsWith("opc.tcp://") && !o.url) o.url = a;
        else usage(`unexpected argument "${a}"`);
    }
    if (!o.pki) usage("--pki DIR is required");
    if (!o.init && !o.url) usage("an opc.tcp:// URL is required (or --init)");
    if (!Number.isInteger(o.timeoutMs) || o.timeoutMs <= 0 || o.timeoutMs > 120000)
        usage("--timeout-ms: 1..120000");
    return o;
}

// "all", a policy name or its URI -> [[name, SecurityPolicy]].
function policyList(texts) {
    if (texts.length === 0 || texts.includes("all")) return Object.entries(POLICIES);
    return texts.map((t) => {
        const name = t.includes("#") ? t.slice(t.lastIndexOf("#") + 1) : t;
        if (!POLICIES[name]) usage(`unknown policy "${t}" (${Object.keys(POLICIES).join(", ")})`);
        return [name, POLICIES[name]];
    });
}

function modeList(texts) {
    if (texts.length === 0 || texts.includes("all")) return Object.entries(MODES);
    return texts.map((t) => {
        const name = { sign: "Sign", encrypt: "SignAndEncrypt" }[t] || t;
        if (!MODES[name]) usage(`unknown mode "${t}" (Sign, SignAndEncrypt)`);
        return [name, MODES[name]];
    });
}

// --identity texts -> [{ label, index, info }] (info: node-opcua's UserIdentityInfo; index: the
// option's position).
function identityList(texts) {
    if (texts.length === 0) texts = ["anonymous"];
    return texts.map((t, index) => ({ ...identityOf(t), index }));
}

function identityOf(t) {
    if (t === "anonymous") return { label: t, info: { type: UserTokenType.Anonymous } };
    if (t.startsWith("user:")) {
        const rest = t.slice(5);
        const colon = rest.indexOf(":");
        if (colon <= 0) usage(`--identity user:NAME:PASSWORD, got "${t}"`);
        return {
            label: `user:${rest.slice(0, colon)}`,
            info: { type: UserTokenType.UserName, userName: rest.slice(0, colon), password: rest.slice(colon + 1) },
        };
    }
    if (t.startsWith("x509:")) {
        const [cert, key] = t.slice(5).split(":");
        if (!cert || !key) usage(`--identity x509:CERT.der:KEY.pem, got "${t}"`);
        let der = fs.readFileSync(cert);
        if (der.toString("latin1").includes("-----BEGIN")) der = convertPEMtoDER(der.toString("latin1"));
        return {
            label: `x509:${path.basename(cert)}`,
            info: { type: UserTokenType.Certificate, certificateData: der, privateKey: fs.readFileSync(key, "utf8") },
        };
    }
    usage(`unknown identity "${t}"`);
}

// The certificate manager of the PKI folder: unknown server certificates land in its
// rejected/ folder and are refused.
async function certificateManager(root) {
    const cm = new OPCUACertificateManager({
        rootFolder: root,
        automaticallyAcceptUnknownCertificate: false,
    });
    await cm.initialize();
    return cm;
}

const ownCertificateFile = (root) => path.join(root, "own", "certs", "client_certificate.pem");

async function init(o) {
    const cm = await certificateManager(o.pki);
    const file = ownCertificateFile(o.pki);
    if (!fs.existsSync(file)) {
        await cm.createSelfSignedCertificate({
            applicationUri: o.applicationUri,
            dns: [os.hostname(), "localhost"],
            outputFile: file,
            subject: `/CN=pnp interop node-opcua client/O=pnp`,
            startDate: new Date(Date.now() - 24 * 3600 * 1000),
            validity: 365,
        });
    }
    const der = convertPEMtoDER(fs.readFileSync(file, "ascii"));
    if (o.exportCert) fs.writeFileSync(o.exportCert, der);
    await cm.dispose();
    out(
        JSON.stringify({
            certificate: file,
            certificateDer: o.exportCert,
            thumbprint: makeSHA1Thumbprint(der).toString("hex"),
            applicationUri: o.applicationUri,
        }),
    );
}

// "BadXxx" from a node-opcua error (its message or its status code), or null.
function statusOf(err) {
    if (err && err.statusCode && typeof err.statusCode.name === "string") return err.statusCode.name;
    const m = /\b(Bad[A-Za-z]+)\b/.exec(String(err && err.message ? err.message : err));
    return m ? m[1] : null;
}

async function demoNamespaceIndex(session) {
    const ns = await session.read({ nodeId: coerceNodeId("i=2255"), attributeId: AttributeIds.Value });
    const uris = (ns.value && ns.value.value) || [];
    const index = uris.indexOf(DEMO_NS_URI);
    return index > 0 ? index : null;
}

// One connection: channel, session, reads, optional call; always disconnects.
async function attempt(o, cm, [policyName, policy], [modeName, mode], identity) {
    const result = { policy: policyName, mode: modeName, identity: identity.label, index: identity.index };
    const client = OPCUAClient.create({
        applicationName: "pnp interop node-opcua client",
        applicationUri: o.applicationUri,
        clientCertificateManager: cm,
        certificateFile: ownCertificateFile(o.pki),
        securityMode: mode,
        securityPolicy: policy,
        endpointMustExist: true,
        connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
        requestedSessionTimeout: 20000,
        defaultTransactionTimeout: o.timeoutMs,
    });
    let session = null;
    try {
        await withTimeout(
            (async () => {
                await client.connect(o.url);
                session = await client.createSession(identity.info);
                const state = await session.read({ nodeId: coerceNodeId("i=2259"), attributeId: AttributeIds.Value });
                if (!state.statusCode.isGood()) throw new Error(`read i=2259: ${state.statusCode.toString()}`);
                result.state = state.value.value;
                result.demoInt32 = null;
                result.echo = null;
                const ns = await demoNamespaceIndex(session);
                if (ns !== null) {
                    const v = await session.read({
                        nodeId: coerceNodeId(`ns=${ns};s=Scalar.Int32`),
                        attributeId: AttributeIds.Value,
                    });
                    if (!v.statusCode.isGood()) throw new Error(`read Scalar.Int32: ${v.statusCode.toString()}`);
                    result.demoInt32 = v.value.value;
                }
                if (o.callEcho) {
                    // Reported, not a failure of the connection: whether this identity may
                    // call is the server's role policy.
                    if (ns === null) throw new Error(`no ${DEMO_NS_URI} namespace for Demo.Echo`);
                    const data = Buffer.from(`pnp ${policyName} ${modeName}`);
                    const r = await session.call({
                        objectId: coerceNodeId(`ns=${ns};s=Demo`),
                        methodId: coerceNodeId(`ns=${ns};s=Demo.Echo`),
                        inputArguments: [{ dataType: DataType.ByteString, value: data }],
                    });
                    result.call = r.statusCode.name;
                    if (r.statusCode.isGood()) {
                        const back = r.outputArguments[0] && r.outputArguments[0].value;
                        if (!Buffer.isBuffer(back) || !back.equals(data))
                            throw new Error(`Demo.Echo returned ${back && back.toString("hex")}`);
                        result.echo = back.toString("hex");
                    }
                }
            })(),
            o.timeoutMs,
            `${policyName} ${modeName} ${identity.label}`,
        );
        result.ok = true;
    } catch (err) {
        result.ok = false;
        result.status = statusOf(err);
        result.error = oneLine(err && err.message ? err.message : err);
        console.error(`${SCRIPT}: ${policyName} ${modeName} ${identity.label}: ${result.status || ""} ${result.error}`);
    } finally {
        // A failed or half-open connection must not keep the process alive.
        if (session) await withTimeout(session.close(), 3000, "CloseSession").catch(() => {});
        await withTimeout(client.disconnect(), 3000, "disconnect").catch(() => {});
    }
    out(JSON.stringify(result));
    return result.ok;
}

async function main() {
    const o = parseArgs(process.argv.slice(2));
    if (o.init) return init(o);
    const policies = policyList(o.policies);
    const modes = modeList(o.modes);
    const identities = identityList(o.identities);
    const cm = await certificateManager(o.pki);
    let failed = 0;
    for (const p of policies)
        for (const m of modes)
            for (const id of identities)
                if (!(await attempt(o, cm, p, m, id))) failed++;
    await cm.dispose().catch(() => {});
    process.exit(failed === 0 ? 0 : 1);
}

process.on("unhandledRejection", (err) => {
    console.error(`${SCRIPT}: unhandled rejection:`, err && err.message ? err.message : err);
});
// The whole run is bounded whatever node-opcua does.
setTimeout(() => {
    console.error(`${SCRIPT}: overall deadline (120 s) exceeded`);
    process.exit(1);
}, 120000).unref();

main().catch((err) => {
    console.error(`${SCRIPT}: ${err && err.stack ? err.stack : err}`);
    process.exit(1);
});
