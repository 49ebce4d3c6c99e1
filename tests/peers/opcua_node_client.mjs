// A second OPC UA client that is not ours, for gateway/tests/opcua.rs: node-opcua
// (node-opcua-client 2.180.0, pinned in tests/peers/package.json; scripts/test installs
// it with `npm ci --prefix tests/peers`). It connects to the gateway (security none,
// anonymous), then takes commands on stdin and answers with one JSON object per line
// on stdout, as opcua_client.py does:
//
//     alarms                 node-opcua's own alarm monitoring (installAlarmMonitoring:
//                            its default A&C filter, OfType AcknowledgeableConditionType,
//                            on the Server object, then ConditionRefresh); each alarm
//                            it holds comes as {"type": "alarm", ...} when it is new
//                            or changes
//     ack CONDITION COMMENT  acknowledge the alarm of ConditionId CONDITION (its last
//                            EventId) as node-opcua does (ClientAlarm.acknowledge)
//     ackwith CONDITION HEX  acknowledge with EventId HEX (a stale or foreign one)
//     refresh SUBSCRIPTION   ConditionRefresh of subscription id SUBSCRIPTION
//     quit
//
//     node opcua_node_client.mjs URL

import readline from "node:readline";
import { format } from "node:util";

// node-opcua logs its warnings with console.log: to stderr, stdout is the JSON lines'.
for (const name of ["log", "info", "warn", "debug"]) {
    console[name] = (...args) => process.stderr.write(`${format(...args)}\n`);
}
const {
    OPCUAClient,
    MessageSecurityMode,
    SecurityPolicy,
    installAlarmMonitoring,
    callConditionRefresh,
    acknowledgeCondition,
    coerceNodeId,
} = await import("node-opcua-client");

function emit(message) {
    process.stdout.write(`${JSON.stringify(message)}\n`);
}

/** A field of an alarm's event as JSON. */
function value(variant) {
    if (!variant) {
        return null;
    }
    const v = variant.value;
    if (v === null || v === undefined) {
        return null;
    }
    if (Buffer.isBuffer(v)) {
        return v.toString("hex");
    }
    if (v.text !== undefined) {
        return v.text;
    }
    if (typeof v === "object" && typeof v.toString === "function" && v.identifierType !== undefined) {
        return v.toString();
    }
    if (v instanceof Date) {
        return v.toISOString();
    }
    return v;
}

function alarmJson(alarm) {
    const f = alarm.fields;
    return {
        type: "alarm",
        conditionId: alarm.conditionId.toString(),
        eventId: alarm.eventId.toString("hex"),
        eventType: alarm.eventType.toString(),
        conditionName: value(f.conditionName),
        sourceName: value(f.sourceName),
        message: value(f.message),
        severity: value(f.severity),
        retain: value(f.retain),
        enabled: value(f.enabledState?.id),
        active: value(f.activeState?.id),
        activeText: value(f.activeState),
        acked: value(f.ackedState?.id),
        ackedText: value(f.ackedState),
        comment: value(f.comment),
    };
}

async function main() {
    const url = process.argv[2];
    const client = OPCUAClient.create({
        applicationName: "millgate node-opcua test client",
        securityMode: MessageSecurityMode.None,
        securityPolicy: SecurityPolicy.None,
        endpointMustExist: false,
        connectionStrategy: { maxRetry: 2, initialDelay: 200, maxDelay: 1000 },
    });
    let session;
    try {
        await client.connect(url);
        session = await client.createSession();
    } catch (error) {
        emit({ type: "refused", error: String(error) });
        await client.disconnect();
        return;
    }
    emit({ type: "ready" });
    let alarms = null;
    const lines = readline.createInterface({ input: process.stdin });
    for await (const line of lines) {
        const [command, ...rest] = line.trim().split(/\s+/);
        if (!command || command === "quit") {
            break;
        }
        try {
            if (command === "alarms") {
                alarms = await installAlarmMonitoring(session);
                const seen = (alarm) => emit(alarmJson(alarm));
                alarms.on("newAlarm", seen);
                alarms.on("alarmChanged", seen);
                const subscription = session.$subscriptionForAlarmList;
                emit({ type: "subscribed", subscriptionId: subscription.subscriptionId });
            } else if (command === "ack") {
                const [condition, ...comment] = rest;
                const alarm = alarms?.alarms().find((a) => a.conditionId.toString() === condition);
                if (!alarm) {
                    emit({ type: "error", error: `no alarm ${condition}` });
                    continue;
                }
                const status = await alarm.acknowledge(session, comment.join(" "));
                emit({ type: "ack", status: status.name });
            } else if (command === "ackwith") {
                const [condition, hex] = rest;
                const status = await acknowledgeCondition(
                    session,
                    coerceNodeId(condition),
                    Buffer.from(hex, "hex"),
                    "a stale event"
                );
                emit({ type: "ack", status: status.name });
            } else if (command === "refresh") {
                const status = await callConditionRefresh(session, Number(rest[0]));
                emit({ type: "refresh", status: status.name });
            } else {
                emit({ type: "error", error: `unknown command ${command}` });
            }
        } catch (error) {
            emit({ type: "error", error: `${command}: ${error}` });
        }
    }
    await session.close();
    await client.disconnect();
}

main().catch((error) => {
    emit({ type: "error", error: String(error) });
    process.exit(1);
});
