// The second subscribed client of gateway/benches/opcua.rs, not ours and not Python:
// node-opcua (node-opcua-client 2.180.0 from tests/peers: `npm ci --prefix tests/peers`)
// subscribes to every variable the bench's server publishes (node ids
// Millgate/Drivelines/D<k>/v<j>, publishing interval 100 ms, queue size QUEUE) and
// counts the data changes it receives, as opcua_subscriber.py does. node-opcua keeps
// several Publish requests in flight (asyncua one), so the two clients side by side
// tell whether the server or the client bounds the delivery.
//
//     node opcua_subscriber.mjs URL OBJECTS VARIABLES SECONDS QUEUE
//
// Prints {"ready": true} once subscribed, then, after SECONDS, one JSON line: the
// changes received, the seconds they came in, the changes whose value was older than
// the latest one of their variable's (values only grow), the changes that carried the
// Overflow bit (the server dropped a value of that variable from its queue before
// this one), and the client's CPU seconds over the run.

import { format } from "node:util";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

// node-opcua logs with console.log: to stderr, stdout is the JSON lines'.
for (const name of ["log", "info", "warn", "debug"]) {
    console[name] = (...args) => process.stderr.write(`${format(...args)}\n`);
}
// The peers' node_modules are in tests/peers, beside this bench's crate.
const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, "../../tests/peers/package.json"));
const {
    OPCUAClient,
    AttributeIds,
    ClientSubscription,
    ClientMonitoredItemGroup,
    MessageSecurityMode,
    SecurityPolicy,
    TimestampsToReturn,
    coerceNodeId,
} = require("node-opcua-client");

const NAMESPACE = "urn:millgate:results";
const [url, objects, variables, seconds, queueSize] = [
    process.argv[2],
    Number(process.argv[3]),
    Number(process.argv[4]),
    Number(process.argv[5]),
    Number(process.argv[6] ?? 1),
];

const emit = (message) => process.stdout.write(`${JSON.stringify(message)}\n`);
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

const client = OPCUAClient.create({
    endpointMustExist: false,
    securityMode: MessageSecurityMode.None,
    securityPolicy: SecurityPolicy.None,
    connectionStrategy: { maxRetry: 0 },
});
await client.connect(url);
const session = await client.createSession();
const namespaces = await session.readNamespaceArray();
const ns = namespaces.indexOf(NAMESPACE);
const subscription = ClientSubscription.create(session, {
    requestedPublishingInterval: 100,
    requestedLifetimeCount: 600,
    requestedMaxKeepAliveCount: 20,
    maxNotificationsPerPublish: 0,
    publishingEnabled: true,
    priority: 1,
});
await new Promise((resolve) => subscription.once("started", resolve));

const counter = { changes: 0, first: null, last: null, outOfOrder: 0, overflow: 0 };
const latest = new Map();
const nodes = [];
for (let k = 0; k < objects; k++) {
    for (let j = 0; j < variables; j++) {
        nodes.push(`Millgate/Drivelines/D${k}/v${j}`);
    }
}
// At most 1000 items per CreateMonitoredItems, the server's limit per call.
for (let start = 0; start < nodes.length; start += 1000) {
    const batch = nodes.slice(start, start + 1000);
    const group = ClientMonitoredItemGroup.create(
        subscription,
        batch.map((id) => ({ nodeId: coerceNodeId(`ns=${ns};s=${id}`), attributeId: AttributeIds.Value })),
        { samplingInterval: 100, discardOldest: true, queueSize },
        TimestampsToReturn.Both,
    );
    await new Promise((resolve) => group.once("initialized", resolve));
    group.on("changed", (_item, dataValue, index) => {
        const now = performance.now();
        counter.first ??= now;
        counter.last = now;
        counter.changes += 1;
        const key = start + index;
        const value = dataValue.value?.value;
        if (typeof value === "number") {
            if (value < (latest.get(key) ?? -Infinity)) {
                counter.outOfOrder += 1;
            }
            latest.set(key, value);
        }
        if (dataValue.statusCode.hasOverflowBit) {
            counter.overflow += 1;
        }
    });
}
// The initial values are not part of the run.
await sleep(1000);
Object.assign(counter, { changes: 0, first: null, last: null, outOfOrder: 0, overflow: 0 });
const cpu = process.cpuUsage();
emit({ ready: true });
await sleep(seconds * 1000);
const used = process.cpuUsage(cpu);
emit({
    changes: counter.changes,
    seconds: counter.first === null ? 0 : (counter.last - counter.first) / 1000,
    out_of_order: counter.outOfOrder,
    overflow: counter.overflow,
    client_cpu: (used.user + used.system) / 1e6,
});
await subscription.terminate();
await session.close();
await client.disconnect();
