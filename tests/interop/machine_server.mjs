// A "machine" served by node-opcua (tests/test_interop_node.py): publishes a recorded trace (a CSV of
// `gantry-twin export`) as gantry-twin serve's sample blocks, with its run state and sample period, and as scalar
// positions and commands (a decimated HMI view, one value per block), so that `monitor --opcua` follows an OPC UA
// server that is not asyncua. Prints "listening URL" once it listens; starts when a client subscribes; exits a
// few seconds after the run state `finished`. Usage: node machine_server.mjs TRACE.csv SAMPLES_PER_BLOCK
import fs from "node:fs";
import { DataType, OPCUAServer, StatusCodes, Variant, VariantArrayType } from "node-opcua";

const [csvPath, perBlockText] = process.argv.slice(2);
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
