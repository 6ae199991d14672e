// A node-opcua client of `gantry-twin serve` (tests/test_interop_node.py): browses the CNC object, reads X's
// ActPos, subscribes to the sample blocks and the alarm events until the run finishes (at most SECONDS), and
// prints what it saw as one JSON line. Usage: node twin_client.mjs ENDPOINT SECONDS [USER PASSWORD]
import {
  AttributeIds,
  ClientMonitoredItem,
  ClientSubscription,
  OPCUAClient,
  TimestampsToReturn,
  constructEventFilter,
  makeBrowsePath,
} from "node-opcua";

const [endpoint, secondsText, user, password] = process.argv.slice(2);
const seconds = Number(secondsText);
const out = { browsed: [], actPos: null, blocks: [], events: [], finished: false, error: null };
const client = OPCUAClient.create({
  endpointMustExist: false,
  connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
});
const timer = setTimeout(() => {
  out.error = "timed out";
  console.log(JSON.stringify(out));
  process.exit(3);
}, (seconds + 30) * 1000);

try {
  await client.connect(endpoint);
  const session = await client.createSession(user ? { type: 1, userName: user, password } : undefined);
  const ns = (await session.readNamespaceArray()).indexOf("urn:gantry-twin:opcua");
  const objects = await session.browse("ns=0;i=85");
  out.browsed = objects.references.map((r) => r.browseName.name);
  const path = makeBrowsePath("i=85", `/${ns}:CncInterface/${ns}:CncAxisList/${ns}:X/${ns}:PosDirect/${ns}:ActPos`);
  const found = await session.translateBrowsePath(path);
  const actPos = await session.read({ nodeId: found.targets[0].targetId, attributeId: AttributeIds.Value });
  out.actPos = actPos.value.value;

  const subscription = ClientSubscription.create(session, {
    requestedPublishingInterval: 100,
    requestedLifetimeCount: 600,
    requestedMaxKeepAliveCount: 20,
    maxNotificationsPerPublish: 0,
    publishingEnabled: true,
    priority: 1,
  });
  const monitor = (nodeId, attributeId, parameters) =>
    ClientMonitoredItem.create(subscription, { nodeId, attributeId }, parameters, TimestampsToReturn.Both);
  const blocks = monitor(`ns=${ns};s=GantryTwin.SampleBlock`, AttributeIds.Value, {
    samplingInterval: 0,
    queueSize: 500,
    discardOldest: false,
  });
  blocks.on("changed", (dataValue) => {
    const v = dataValue.value.value;
    if (v && v.length >= 4) out.blocks.push([v[0], v[2]]); // first index, samples
  });
  const state = monitor(`ns=${ns};s=GantryTwin.RunState`, AttributeIds.Value, { samplingInterval: 0, queueSize: 10 });
  state.on("changed", (dataValue) => {
    if (dataValue.value.value === "finished") out.finished = true;
  });
  const events = monitor(`ns=${ns};s=GantryTwin`, AttributeIds.EventNotifier, {
    samplingInterval: 0,
    queueSize: 100,
    filter: constructEventFilter(["Message", "Severity"]),
  });
  events.on("changed", (fields) => {
    out.events.push({ message: fields[0].value.text, severity: fields[1].value });
  });
  const deadline = Date.now() + seconds * 1000;
  while (!out.finished && Date.now() < deadline) await new Promise((r) => setTimeout(r, 100));
  await new Promise((r) => setTimeout(r, 500)); // the state came after the last block
  await subscription.terminate();
  await session.close();
} catch (error) {
  out.error = String(error && error.message ? error.message : error).split("\n")[0];
}
await client.disconnect().catch(() => {});
clearTimeout(timer);
console.log(JSON.stringify(out));
process.exit(out.error ? 2 : 0);
