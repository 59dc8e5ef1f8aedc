#!/usr/bin/env node
"use strict";
// node-opcua as the tool of the Part 12 push model against a pnp server: as a SecurityAdmin
// user it calls GetRejectedList and reads the TrustList file (OpenWithMasks, Read, Close) over
// SignAndEncrypt, and tries GetRejectedList over Sign (refused: the role counts only with
// encryption).
//
// usage:
//   node node_push_client.js --init --pki DIR --export-cert FILE.der --application-uri URI
//       creates the PKI folder and the client's certificate, writes it as DER to FILE.der and
//       prints "CERT <thumbprint>"
//   node node_push_client.js URL --pki DIR --application-uri URI --user NAME:PASSWORD
//       --results FILE
//       writes "RESULT <mode> <what> <status> [<detail>]" lines to FILE, then prints "DONE";
//       the server's certificate must be in DIR/trusted/certs (nothing is accepted
//       automatically)
// Every step has a deadline; exit 0 after DONE, 1 on an unexpected error, 2 on a usage error.

const fs = require("fs");
const path = require("path");
const os = require("os");
const {
    OPCUACertificateManager,
    OPCUAClient,
    MessageSecurityMode,
    SecurityPolicy,
    DataType,
    UserTokenType,
} = require("node-opcua");
const { convertPEMtoDER, makeSHA1Thumbprint } = require("node-opcua-crypto");

// node-opcua logs with console.log: stdout stays ours.
const stdoutWrite = process.stdout.write.bind(process.stdout);
const out = (line) => stdoutWrite(line + "\n");
process.stdout.write = process.stderr.write.bind(process.stderr);

const SERVER_CONFIGURATION = "ns=0;i=12637";
const GET_REJECTED_LIST = "ns=0;i=12777";
const TRUST_LIST = "ns=0;i=12642";
const OPEN_WITH_MASKS = "ns=0;i=12663";
const READ = "ns=0;i=12652";
const CLOSE = "ns=0;i=12650";

function usage(message) {
    console.error(`node_push_client.js: ${message}`);
    process.exit(2);
}

function parse(argv) {
    const o = { init: false };
    for (let i = 0; i < argv.length; ++i) {
        const a = argv[i];
        const value = () => (i + 1 < argv.length ? argv[++i] : usage(`${a} needs a value`));
        if (a === "--init") o.init = true;
        else if (a === "--pki") o.pki = value();
        else if (a === "--export-cert") o.exportCert = value();
        else if (a === "--application-uri") o.applicationUri = value();
        else if (a === "--user") o.user = value();
        else if (a === "--results") o.results = value();
        else if (a.startsWith("opc.tcp://")) o.url = a;
        else usage(`unexpected argument "${a}"`);
    }
    if (!o.pki || !o.applicationUri) usage("--pki and --application-uri are required");
    if (o.init ? !o.exportCert : !o.url || !o.user || !o.results)
        usage("--init --export-cert, or URL --user --results");
    return o;
}

function withTimeout(promise, ms, what) {
    let timer;
    return Promise.race([
        promise,
        new Promise((_, reject) => {
            timer = setTimeout(() => reject(new Error(`${what}: no answer within ${ms} ms`)), ms);
        }),
    ]).finally(() => clearTimeout(timer));
}

async function certificateManager(root) {
    const cm = new OPCUACertificateManager({ rootFolder: root, automaticallyAcceptUnknownCertificate: false });
    await cm.initialize();
    return cm;
}

const ownCertificateFile = (root) => path.join(root, "own", "certs", "client_certificate.pem");

async function init(o) {
    const cm = await certificateManager(o.pki);
    await cm.createSelfSignedCertificate({
        applicationUri: o.applicationUri,
        dns: [os.hostname(), "localhost"],
        outputFile: ownCertificateFile(o.pki),
        subject: "/CN=pnp push test node-opcua client/O=pnp",
        startDate: new Date(Date.now() - 24 * 3600 * 1000),
        validity: 30,
    });
    const der = convertPEMtoDER(fs.readFileSync(ownCertificateFile(o.pki), "ascii"));
    fs.writeFileSync(o.exportCert, der);
    await cm.dispose();
    out(`CERT ${makeSHA1Thumbprint(der).toString("hex")}`);
}

async function session(o, mode, body) {
    const cm = await certificateManager(o.pki);
    const client = OPCUAClient.create({
        applicationName: "pnp push test node-opcua client",
        applicationUri: o.applicationUri,
        securityMode: mode,
        securityPolicy: SecurityPolicy.Basic256Sha256,
        certificateFile: ownCertificateFile(o.pki),
        clientCertificateManager: cm,
        endpointMustExist: false,
        connectionStrategy: { maxRetry: 0 },
    });
    const [name, password] = [o.user.slice(0, o.user.indexOf(":")), o.user.slice(o.user.indexOf(":") + 1)];
    try {
        await withTimeout(client.connect(o.url), 10000, "connect");
        const s = await withTimeout(
            client.createSession({ type: UserTokenType.UserName, userName: name, password }),
            10000,
            "createSession",
        );
        try {
            await body(s);
        } finally {
            await withTimeout(s.close(), 5000, "closeSession").catch(() => {});
        }
    } finally {
        await withTimeout(client.disconnect(), 5000, "disconnect").catch(() => {});
        await cm.dispose();
    }
}

async function call(s, objectId, methodId, inputArguments = []) {
    return withTimeout(s.call({ objectId, methodId, inputArguments }), 10000, methodId);
}

async function run(o) {
    const result = (line) => fs.appendFileSync(o.results, line + "\n");
    await session(o, MessageSecurityMode.SignAndEncrypt, async (s) => {
        const rejected = await call(s, SERVER_CONFIGURATION, GET_REJECTED_LIST);
        result(`RESULT SignAndEncrypt GetRejectedList ${rejected.statusCode.name}`);
        const opened = await call(s, TRUST_LIST, OPEN_WITH_MASKS, [{ dataType: DataType.UInt32, value: 15 }]);
        result(`RESULT SignAndEncrypt OpenWithMasks ${opened.statusCode.name}`);
        if (opened.statusCode.name !== "Good") return;
        const handle = opened.outputArguments[0].value;
        let bytes = 0;
        for (let i = 0; i < 1000; ++i) {
            const r = await call(s, TRUST_LIST, READ, [
                { dataType: DataType.UInt32, value: handle },
                { dataType: DataType.Int32, value: 65536 },
            ]);
            if (r.statusCode.name !== "Good") {
                result(`RESULT SignAndEncrypt Read ${r.statusCode.name}`);
                return;
            }
            const chunk = r.outputArguments[0].value;
            if (!chunk || chunk.length === 0) break;
            bytes += chunk.length;
        }
        result(`RESULT SignAndEncrypt Read Good ${bytes}`);
        const closed = await call(s, TRUST_LIST, CLOSE, [{ dataType: DataType.UInt32, value: handle }]);
        result(`RESULT SignAndEncrypt Close ${closed.statusCode.name}`);
    });
    await session(o, MessageSecurityMode.Sign, async (s) => {
        const rejected = await call(s, SERVER_CONFIGURATION, GET_REJECTED_LIST);
        result(`RESULT Sign GetRejectedList ${rejected.statusCode.name}`);
    });
    out("DONE");
}

const o = parse(process.argv.slice(2));
(o.init ? init(o) : run(o)).then(
    () => process.exit(0),
    (err) => {
        console.error(`node_push_client.js: ${err && err.stack ? err.stack : err}`);
        process.exit(1);
    },
);
