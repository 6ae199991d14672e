// A "machine" served by node-opcua (tests/test_interop_node.py): publishes a recorded trace (a CSV of
// `gantry-twin export`) as gantry-twin serve's sample blocks, with its run state and sample period, and as scalar
// positions and commands (a decimated HMI view, one value per block), so that `monitor --opcua` follows an OPC UA
// server that is not asyncua. Prints "listening URL" once it listens; starts when a client subscribes; exits a
// few seconds after the run state `finished`. Usage: node machine_server.mjs TRACE.csv SAMPLES_PER_BLOCK [scalars N FROM]
// With `scalars N FROM`: no blocks; samples FROM to FROM + N as scalar values, every one, each with its sample's
// source time (t = 0 at 2026-12-04T00:00:00Z, the 0.2 ms steps below a millisecond in the DataValue's picoseconds).
// node-opcua's trigger StatusValueTimestamp compares source timestamps to the millisecond: a value that repeats
// within a millisecond (a machine at rest) is not reported, so FROM is where the machine moves.
import fs from "node:fs";
import { DataType, DataValue, OPCUAServer, StatusCodes, Variant, VariantArrayType } from "node-opcua";

const [csvPath, perBlockText, mode, countText, fromText] = process.argv.slice(2);
const perBlock = Number(perBlockText);
const SIGNALS = [
  "t_s", "x_meas_m", "y_meas_m", "x_m", "y_m", "x_d_m", "y_d_m", "u_x_v", "u_y_v", "eps_c_m",
  "theta_hat_M1", "theta_hat_M2", "theta_hat_B1", "theta_hat_B2",
  "theta_hat_Af1", "theta_hat_Af2", "theta_hat_dN1", "theta_hat_dN2",
];
const lines = fs.readFileSync(csvPath, "utf8").trim().split("\n");
const header = lines[0].split(",").map((name) => name.replaceAll('"', ""));
const columns = SIGNALS.map((name) => header.indexOf(name));
const rows = lines.slice(1).map((line) => line.split(",").map(Number));

// MinSupportedSampleRate 0: a monitored item that asks for 0 gets every change, not a coalesced one (OPC 10000-4 5.12.1.2).
const server = new OPCUAServer({
  port: 0,
  hostname: "127.0.0.1",
  maxAllowedSessionNumber: 10,
  serverCapabilities: { minSupportedSampleRate: 0 },
});
await server.initialize();
const addressSpace = server.engine.addressSpace;
const ns = addressSpace.registerNamespace("urn:gantry-twin:opcua");
const twin = ns.addObject({ organizedBy: addressSpace.rootFolder.objects, browseName: "GantryTwin", nodeId: "s=GantryTwin" });
const variable = (name, dataType, value, array = false) =>
  ns.addVariable({
    componentOf: twin,
    browseName: name,
    nodeId: `s=GantryTwin.${name}`,
    dataType,
    valueRank: array ? 1 : -1,
    minimumSamplingInterval: 0,
    value: new Variant({ dataType: DataType[dataType], arrayType: array ? VariantArrayType.Array : undefined, value }),
  });
const block = variable("SampleBlock", "Double", new Float64Array(0), true);
const state = variable("RunState", "String", "idle");
variable("SamplePeriod", "Double", 0.0002);
const scalars = ["x_meas_m", "y_meas_m", "u_x_v", "u_y_v"].map((name) => [name, variable(name, "Double", 0)]);
await server.start();
console.log(`listening opc.tcp://127.0.0.1:${server.endpoints[0].port}`);

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
const deadline = Date.now() + 60000;
while (server.currentSubscriptionCount === 0 && Date.now() < deadline) await sleep(50);
await sleep(500); // the subscriber's monitored items are created after its subscription
state.setValueFromSource(new Variant({ dataType: DataType.String, value: "running" }));
if (mode === "scalars") {
  await sleep(1000); // each of the four monitored items is created (and sent its first value) before sample 0
  const t0 = Date.UTC(2026, 11, 4);
  const indices = scalars.map(([name]) => header.indexOf(name));
  for (let k = Number(fromText); k < Number(fromText) + Number(countText); k++) {
    const tenthsOfMs = Math.round(rows[k][columns[0]] * 1e4); // t in units of 0.1 ms, exact for 0.2 ms samples
    const sourceTimestamp = new Date(t0 + Math.floor(tenthsOfMs / 10));
    const sourcePicoseconds = (tenthsOfMs % 10) * 1e8; // node-opcua: picoseconds within the millisecond
    scalars.forEach(([, node], j) => {
      const value = new Variant({ dataType: DataType.Double, value: rows[k][indices[j]] });
      node._internal_set_dataValue(new DataValue({ value, sourceTimestamp, sourcePicoseconds }));
    });
    if (k % 20 === 19) await sleep(30); // well within what the queues hold between two publishes, on a loaded machine too
  }
  rows.length = 0; // no blocks
}
for (let first = 0; first < rows.length; first += perBlock) {
  const part = rows.slice(first, first + perBlock);
  const values = new Float64Array(4 + part.length * SIGNALS.length);
  values.set([first, part[0][columns[0]], part.length, SIGNALS.length]);
  columns.forEach((c, j) => part.forEach((row, i) => (values[4 + j * part.length + i] = c < 0 ? NaN : row[c])));
  block.setValueFromSource(
    new Variant({ dataType: DataType.Double, arrayType: VariantArrayType.Array, value: values }),
    StatusCodes.Good,
  );
  const last = part[part.length - 1];
  for (const [name, node] of scalars) {
    node.setValueFromSource(new Variant({ dataType: DataType.Double, value: last[header.indexOf(name)] }));
  }
  await sleep(20);
}
state.setValueFromSource(new Variant({ dataType: DataType.String, value: "finished" }));
await sleep(3000);
await server.shutdown(500);
process.exit(0);
