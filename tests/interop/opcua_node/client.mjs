// node-opcua's client (a second OPC UA stack no one here wrote) driven by
// tests/interop/test_opcua_node.py: one JSON argument says where to connect,
// as whom and what to do; every outcome is printed as one JSON line on
// stdout, so that the test can read results as they come (and kill the
// process mid-move, as a client that vanishes).
//
// The argument:
//   { "url": "opc.tcp://127.0.0.1:PORT", "pki": "client PKI folder",
//     "user": ["name", "password"] | null,          (null: anonymous)
//     "mode": "SignAndEncrypt" | "Sign" | "None",   (Basic256Sha256 unless None)
//     "steps": [ STEP, ... ] }
// A STEP's "path" is a list of browse names from the Objects folder:
//   {"do": "browse", "path": [...]}                 the children's names
//   {"do": "read", "path": [...]}                   the value
//   {"do": "write", "path": [...], "type": "UInt16", "value": 1}
//   {"do": "call", "path": [...object], "method": "Move",
//    "args": [["String", "velocity"], ["Double", 100], ...]}
//   {"do": "subscribe", "path": [...], "interval_ms": 50, "for_ms": 3000}
//                                                   the values it received
//   {"do": "hold", "path": [...]}                   prints {"holding": true},
//       then stays subscribed to the path (so the session keeps talking)
//       until the process is killed
// Lines printed (each after "@candeck "): {"connected": bool, "error"?}, {"session": bool,
// "status"?}, then per step {"step": i, "ok": bool, "value"?, "status"?}.

import {
  AttributeIds,
  BrowseDirection,
  ClientMonitoredItem,
  DataType,
  MessageSecurityMode,
  OPCUAClient,
  SecurityPolicy,
  TimestampsToReturn,
  UserTokenType,
  Variant,
} from "node-opcua-client";
import { OPCUACertificateManager } from "node-opcua-certificate-manager";

// node-opcua logs on stdout: its lines go to stderr, and each of ours is
// marked, so that the test reads only these.
const MARK = "@candeck ";
const say = (line) => process.stdout.write(MARK + JSON.stringify(line) + "\n");
console.log = console.error;
console.info = console.error;
console.warn = console.error;
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

function plain(value) {
  if (value === null || value === undefined) return null;
  if (typeof value === "bigint") return Number(value);
  if (Array.isArray(value)) return value.map(plain);
  if (typeof value !== "object") return value;
  if ("text" in value && "locale" in value) return value.text ?? null;
  if ("displayName" in value && "unitId" in value) {
    return { displayName: plain(value.displayName), unitId: value.unitId };
  }
  if (value instanceof Date) return value.toISOString();
  if (value.toString && value.toString !== Object.prototype.toString) return value.toString();
  return String(value);
}

async function resolve(session, path) {
  let nodeId = "i=85"; // the Objects folder
  for (const name of path) {
    const result = await session.browse({
      nodeId,
      referenceTypeId: "HierarchicalReferences",
      includeSubtypes: true,
      browseDirection: BrowseDirection.Forward,
      resultMask: 63,
    });
    const child = (result.references ?? []).find((r) => r.browseName.name === name);
    if (!child) {
      throw Object.assign(new Error(`no ${name} under ${nodeId}`), { status: "BadNoMatch" });
    }
    nodeId = child.nodeId.toString();
  }
  return nodeId;
}

async function step(session, s) {
  switch (s.do) {
    case "browse": {
      const nodeId = await resolve(session, s.path);
      const result = await session.browse({
        nodeId,
        referenceTypeId: "HierarchicalReferences",
        includeSubtypes: true,
        browseDirection: BrowseDirection.Forward,
        resultMask: 63,
      });
      return { ok: true, value: (result.references ?? []).map((r) => r.browseName.name) };
    }
    case "read": {
      const nodeId = await resolve(session, s.path);
      const value = await session.read({ nodeId, attributeId: AttributeIds.Value });
      if (!value.statusCode.isGood()) return { ok: false, status: value.statusCode.name };
      return { ok: true, value: plain(value.value.value) };
    }
    case "write": {
      const nodeId = await resolve(session, s.path);
      const status = await session.write({
        nodeId,
        attributeId: AttributeIds.Value,
        value: { value: new Variant({ dataType: DataType[s.type], value: s.value }) },
      });
      return status.isGood() ? { ok: true } : { ok: false, status: status.name };
    }
    case "call": {
      const objectId = await resolve(session, s.path);
      const methodId = await resolve(session, [...s.path, s.method]);
      const result = await session.call({
        objectId,
        methodId,
        inputArguments: (s.args ?? []).map(
          ([type, value]) => new Variant({ dataType: DataType[type], value }),
        ),
      });
      if (!result.statusCode.isGood()) return { ok: false, status: result.statusCode.name };
      return { ok: true, value: (result.outputArguments ?? []).map((v) => plain(v.value)) };
    }
    case "subscribe":
    case "hold": {
      const nodeId = await resolve(session, s.path);
      const values = [];
      const subscription = await session.createSubscription2({
        requestedPublishingInterval: s.interval_ms ?? 50,
        requestedLifetimeCount: 100,
        requestedMaxKeepAliveCount: 5,
        publishingEnabled: true,
      });
      const item = ClientMonitoredItem.create(
        subscription,
        { nodeId, attributeId: AttributeIds.Value },
        { samplingInterval: s.interval_ms ?? 50, discardOldest: true, queueSize: 10 },
        TimestampsToReturn.Both,
      );
      item.on("changed", (value) => values.push(plain(value.value.value)));
      if (s.do === "hold") {
        say({ holding: true });
        for (;;) await sleep(1000);
      }
      await sleep(s.for_ms ?? 3000);
      await subscription.terminate();
      return { ok: true, value: values };
    }
    default:
      throw new Error(`unknown step ${JSON.stringify(s)}`);
  }
}

async function main() {
  const spec = JSON.parse(process.argv[2]);
  const certificates = new OPCUACertificateManager({
    rootFolder: spec.pki,
    // The test's server makes its certificate on its first start: the
    // client trusts it as it is (the server's trust of the client is what
    // the tests check).
    automaticallyAcceptUnknownCertificate: true,
  });
  await certificates.initialize();
  const unsecured = spec.mode === "None";
  const client = OPCUAClient.create({
    applicationName: "candeck-interop-node",
    clientCertificateManager: certificates,
    securityMode: MessageSecurityMode[spec.mode ?? "SignAndEncrypt"],
    securityPolicy: unsecured ? SecurityPolicy.None : SecurityPolicy.Basic256Sha256,
    endpointMustExist: false,
    requestedSessionTimeout: 30000,
    connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
  });
  try {
    await client.connect(spec.url);
  } catch (err) {
    say({ connected: false, error: String(err.message ?? err) });
    await certificates.dispose();
    return 2;
  }
  say({ connected: true });
  let session;
  try {
    session = await client.createSession(
      spec.user
        ? { type: UserTokenType.UserName, userName: spec.user[0], password: spec.user[1] }
        : { type: UserTokenType.Anonymous },
    );
  } catch (err) {
    say({ session: false, status: err.response?.responseHeader?.serviceResult?.name ?? null, error: String(err.message ?? err) });
    await client.disconnect();
    await certificates.dispose();
    return 3;
  }
  say({ session: true });
  for (const [i, s] of (spec.steps ?? []).entries()) {
    try {
      say({ step: i, ...(await step(session, s)) });
    } catch (err) {
      say({ step: i, ok: false, status: err.status ?? err.statusCode?.name ?? null, error: String(err.message ?? err) });
    }
  }
  await session.close();
  await client.disconnect();
  await certificates.dispose();
  return 0;
}

main().then(
  (code) => process.exit(code),
  (err) => {
    say({ error: String(err.stack ?? err) });
    process.exit(1);
  },
);
