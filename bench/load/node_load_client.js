#!/usr/bin/env node
// node-opcua as one load client of bench/load/load_bench.py (--client node): the same
// options, mixes, checks and JSON line as pnp_bench_load_client (load_client.cpp).
//
//   node node_load_client.js URL [--mix call|read|write|mixed|publish] [--seconds S]
//                            [--payload BYTES] [--id N] [--namespace URI] [--start-at NS]
'use strict';

const {
  OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, DataType, Variant,
  TimestampsToReturn,
} = require('node-opcua');

function monotonicNs() { return process.hrtime.bigint(); }

function bucketOf(ns) {
  const us = Number(ns / 1000n);
  if (us < 1000) return us;
  if (us < 10000) return Math.floor(us / 10) * 10;
  return Math.floor(Math.min(us, 100000000) / 100) * 100;
}

async function main() {
  const argv = process.argv.slice(2);
  if (argv.length < 1) {
    console.error('usage: node_load_client.js URL [--mix M] [--seconds S] ...');
    process.exit(2);
  }
  const url = argv[0];
  const o = { mix: 'call', seconds: 5, payload: 2, id: 0, namespace: 'urn:pnp:demo', startAt: 0n };
  for (let i = 1; i + 1 < argv.length; i += 2) {
    const [a, v] = [argv[i], argv[i + 1]];
    if (a === '--mix') o.mix = v;
    else if (a === '--seconds') o.seconds = Math.min(Math.max(Number(v), 0.1), 86400);
    else if (a === '--payload') o.payload = Math.min(Math.max(Number(v), 1), 1 << 20);
    else if (a === '--id') o.id = Number(v);
    else if (a === '--namespace') o.namespace = v;
    else if (a === '--start-at') o.startAt = BigInt(v);
    else { console.error(`unknown option ${a}`); process.exit(2); }
  }
  if (!['call', 'read', 'write', 'mixed', 'publish'].includes(o.mix)) {
    console.error(`unknown mix ${o.mix}`);
    process.exit(2);
  }
  const hist = new Map();
  let calls = 0, errors = 0, mismatches = 0, notifications = 0, outOfOrder = 0;
  const client = OPCUAClient.create({
    endpointMustExist: false, securityMode: MessageSecurityMode.None,
    securityPolicy: SecurityPolicy.None, connectionStrategy: { maxRetry: 0 },
    requestedSessionTimeout: 60000, keepSessionAlive: false,
  });
  let session, subscription;
  try {
    await client.connect(url);
    session = await client.createSession();
    const nsArray = await session.readNamespaceArray();
    const ns = nsArray.indexOf(o.namespace);
    if (ns < 0) throw new Error(`no namespace ${o.namespace}`);
    const objectId = `ns=${ns};s=Demo`, echoId = `ns=${ns};s=Demo.Echo`;
    const int32Id = `ns=${ns};s=Scalar.Int32`, bytesId = `ns=${ns};s=Scalar.ByteString`;
    if (o.mix === 'publish') {
      subscription = await session.createSubscription2({
        requestedPublishingInterval: 10, requestedLifetimeCount: 6000,
        requestedMaxKeepAliveCount: 100, publishingEnabled: true,
      });
      let last = -1n;
      const item = await subscription.monitor(
        { nodeId: `ns=${ns};s=Bench.Ticker`, attributeId: AttributeIds.Value },
        { samplingInterval: 0, queueSize: 100, discardOldest: true }, TimestampsToReturn.Neither);
      item.on('changed', (dv) => {
        const v = dv.value.value;  // Int64: [high, low] 32-bit words in node-opcua
        const x = Array.isArray(v) ? (BigInt(v[0] >>> 0) << 32n) | BigInt(v[1] >>> 0) : BigInt(v);
        if (x <= last) ++outOfOrder;
        last = x;
        ++notifications;
      });
    }
    const mine = Buffer.alloc(o.payload);
    while (o.startAt > 0n && monotonicNs() < o.startAt) await new Promise((r) => setTimeout(r, 1));
    const t0 = monotonicNs();
    const end = t0 + BigInt(Math.round(o.seconds * 1e9));
    for (let n = 0; ; ++n) {
      const before = monotonicNs();
      if (before >= end) break;
      // This call's number, then this client's id: a response of another request fails.
      for (let k = 0; k < Math.min(4, o.payload); ++k) mine[k] = (n >>> (8 * k)) & 0xff;
      if (o.payload >= 12) mine.writeInt32LE(o.id, 8);
      const kind = o.mix === 'mixed' ? ['call', 'read', 'write'][n % 3]
        : o.mix === 'publish' ? 'read' : o.mix;
      try {
        if (kind === 'call') {
          const r = await session.call({
            objectId, methodId: echoId,
            inputArguments: [new Variant({ dataType: DataType.ByteString, value: mine })],
          });
          if (r.statusCode.value !== 0) ++errors;
          else if (!r.outputArguments[0] || !Buffer.from(r.outputArguments[0].value).equals(mine))
            ++mismatches;
        } else if (kind === 'read') {
          const dv = await session.read({ nodeId: int32Id, attributeId: AttributeIds.Value });
          if (dv.value.dataType !== DataType.Int32) ++mismatches;
        } else {
          const s = await session.write({
            nodeId: bytesId, attributeId: AttributeIds.Value,
            value: { value: new Variant({ dataType: DataType.ByteString, value: mine }) },
          });
          if (s.value !== 0) ++errors;
        }
      } catch (e) {
        ++errors;
      }
      const b = bucketOf(monotonicNs() - before);
      hist.set(b, (hist.get(b) || 0) + 1);
      ++calls;
    }
    const elapsed = Number(monotonicNs() - t0) / 1e9;
    if (subscription) await subscription.terminate();
    await session.close();
    await client.disconnect();
    const h = [...hist.entries()].sort((a, b) => a[0] - b[0]);
    console.log(JSON.stringify({
      id: o.id, mix: o.mix, calls, errors, mismatches, notifications, outOfOrder,
      seconds: elapsed, hist: h,
    }));
  } catch (e) {
    console.error(`node load client ${o.id}: ${e.message}`);
    console.log(JSON.stringify({ id: o.id, error: 'connect' }));
    process.exit(1);
  }
}

main();
