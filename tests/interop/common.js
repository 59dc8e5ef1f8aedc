"use strict";
// What the node-opcua interop scripts share: stdout kept for the script's own lines, the
// command line, PKI folders out of $HOME, a server's shutdown on SIGTERM / SIGINT, and the
// TAP-like checks of the client scripts.

// node-opcua logs warnings with console.log: send all library output to stderr and keep
// stdout for this script's own lines, written with the returned out(line).
const stdoutWrite = process.stdout.write.bind(process.stdout);
const out = (line) => stdoutWrite(line + "\n");
process.stdout.write = process.stderr.write.bind(process.stderr);

const path = require("path");
const os = require("os");
const { OPCUACertificateManager, OPCUAClient, MessageSecurityMode, SecurityPolicy } = require("node-opcua");

function usage(script, what) {
    console.error(`usage: ${script} ${what}`);
    process.exit(2);
}

// argv[2] as a TCP port (exits with a usage line otherwise).
function portArg(script) {
    const port = parseInt(process.argv[2] || "", 10);
    if (!Number.isInteger(port) || port <= 0 || port > 65535) usage(script, "PORT");
    return port;
}

// argv[2] as an opc.tcp URL (exits with a usage line otherwise).
function urlArg(script) {
    const url = process.argv[2];
    if (!url || !url.startsWith("opc.tcp://")) usage(script, "opc.tcp://HOST:PORT");
    return url;
}

// A certificate manager accepting every certificate, in $PNP_NODE_PKI_DIR (default: a
// folder under the temporary directory) / kind: the PKI is created even for
// SecurityPolicy None, and runs stay self-contained and repeatable.
function certificateManager(kind) {
    const pkiRoot = process.env.PNP_NODE_PKI_DIR || path.join(os.tmpdir(), "pnp-node-opcua-pki");
    return new OPCUACertificateManager({
        automaticallyAcceptUnknownCertificate: true,
        rootFolder: path.join(pkiRoot, kind),
    });
}

// An OPCUAClient of the client scripts: SecurityPolicy None, a few quick reconnect attempts,
// the PKI of certificateManager("client"); `extra` adds or overrides options.
function noneClient(applicationName, extra = {}) {
    return OPCUAClient.create({
        applicationName,
        clientCertificateManager: certificateManager("client"),
        endpointMustExist: false,
        securityMode: MessageSecurityMode.None,
        securityPolicy: SecurityPolicy.None,
        connectionStrategy: { maxRetry: 2, initialDelay: 250, maxDelay: 1000 },
        ...extra,
    });
}

// Shuts the server down on SIGTERM / SIGINT (beforeShutdown() first; the process exits
// within 3 s whatever happens).
function shutDownOnSignals(server, log, beforeShutdown = () => {}) {
    let stopping = false;
    const stop = async (sig) => {
        if (stopping) return;
        stopping = true;
        log(`received ${sig}, shutting down`);
        beforeShutdown();
        const hard = setTimeout(() => process.exit(0), 3000);
        hard.unref();
        try {
            await server.shutdown(0);
        } catch (err) {
            log("shutdown error:", err && err.message);
        }
        process.exit(0);
    };
    process.on("SIGTERM", () => stop("SIGTERM"));
    process.on("SIGINT", () => stop("SIGINT"));
}

function oneLine(s) {
    s = String(s).replace(/\s+/g, " ").trim();
    return s.length > 300 ? s.slice(0, 297) + "..." : s;
}

function withTimeout(promise, ms, what) {
    let timer;
    const t = new Promise((_, reject) => {
        timer = setTimeout(() => reject(new Error(`timeout after ${ms} ms (${what})`)), ms);
    });
    return Promise.race([promise, t]).finally(() => clearTimeout(timer));
}

function expect(cond, msg) {
    if (!cond) throw new Error(msg);
}

// Thrown by a check to report a skip.
class Skip extends Error {}

// The checks of a client script: one line per check (`ok - NAME`, `not ok - NAME: reason`,
// `skip - NAME: reason`), then the summary `node_client: N passed, N failed, N skipped`
// (scripts/test.sh reads it). The whole run is bounded by deadlineMs; `tag` prefixes
// unhandled rejections on stderr.
function checks({ tag, deadlineMs, stepTimeoutMs }) {
    const counts = { passed: 0, failed: 0, skipped: 0 };
    const summaryAndExit = (code) => {
        out(`node_client: ${counts.passed} passed, ${counts.failed} failed, ${counts.skipped} skipped`);
        process.exit(code);
    };
    // A late failure of an operation that already timed out must not crash the run.
    process.on("unhandledRejection", (err) => {
        console.error(`[${tag}] unhandled rejection:`, err && err.message ? err.message : err);
    });
    setTimeout(() => {
        counts.failed++;
        out(`not ok - overall deadline: run exceeded ${deadlineMs} ms`);
        summaryAndExit(1);
    }, deadlineMs).unref();

    // Runs one check. fn returns/throws; throw Skip to report a skip. Returns true on pass.
    async function check(name, fn, timeoutMs = stepTimeoutMs) {
        try {
            await withTimeout(Promise.resolve().then(fn), timeoutMs, name);
            counts.passed++;
            out(`ok - ${name}`);
            return true;
        } catch (err) {
            if (err instanceof Skip) {
                counts.skipped++;
                out(`skip - ${name}: ${oneLine(err.message)}`);
                return true;
            }
            counts.failed++;
            out(`not ok - ${name}: ${oneLine(err && err.message ? err.message : err)}`);
            return false;
        }
    }
    // The end of the run: exit 0 only if nothing failed.
    const finish = () => summaryAndExit(counts.failed === 0 ? 0 : 1);
    // main()'s rejection handler.
    const unexpected = (err) => {
        counts.failed++;
        out(`not ok - unexpected error: ${oneLine(err && err.stack ? err.stack : err)}`);
        summaryAndExit(1);
    };
    return { check, finish, unexpected, abort: () => summaryAndExit(1) };
}

module.exports = {
    out,
    portArg,
    urlArg,
    certificateManager,
    noneClient,
    shutDownOnSignals,
    oneLine,
    withTimeout,
    expect,
    Skip,
    checks,
};
