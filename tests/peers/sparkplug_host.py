"""A Sparkplug B host for gateway/tests/sparkplug.rs that is not millgate's code:
paho-mqtt 1.6.1 (the version pysparkplug 0.6.1 requires) subscribes, and the Eclipse Tahu protobuf schema as shipped by
pysparkplug 0.6.1 (sparkplug_b_pb2) decodes. Prints one JSON line per message on
spBv1.0/<group>/#; reads commands from stdin: "rebirth <node> [count]" publishes an
NCMD with Node Control/Rebirth = true (count times); "garbage <node> <bytes>
[retain]" an NCMD of that many 0xff bytes (not protobuf), retained if asked;
"clear <node>" clears a retained NCMD; "state <host_id> online|offline" publishes the
primary host's retained STATE (Sparkplug 3.0 JSON). Each of the last three prints
{"sent": ...} once the broker has it. A message that is not a
Sparkplug payload is printed with "undecodable": true and its size.

    python3 sparkplug_host.py HOST PORT GROUP [--ca FILE [--cert FILE --key FILE]]
        [--username U --password P]

With --ca the host connects over TLS (the broker checked against FILE; --cert and
--key for a broker that requires a client certificate). With --dots-as-slashes (for
RabbitMQ 3.10, which delivers a topic's "." as "/") a topic starting "spBv1/0/" is read
as "spBv1.0/" and its record says "rewritten": true.
"""

import argparse
import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
from pysparkplug._protobuf import sparkplug_b_pb2

Payload = sparkplug_b_pb2.Payload
BOOLEAN = 11

arguments = argparse.ArgumentParser()
arguments.add_argument("host")
arguments.add_argument("port", type=int)
arguments.add_argument("group")
arguments.add_argument("--ca")
arguments.add_argument("--cert")
arguments.add_argument("--key")
arguments.add_argument("--username")
arguments.add_argument("--password")
arguments.add_argument("--dots-as-slashes", action="store_true")
options = arguments.parse_args()
host, port, group = options.host, options.port, options.group
lock = threading.Lock()


def emit(record):
    with lock:
        print(json.dumps(record), flush=True)


def metric_json(metric):
    kind = metric.WhichOneof("value")
    properties = {}
    if metric.HasField("properties"):
        for key, value in zip(metric.properties.keys, metric.properties.values):
            properties[key] = getattr(value, value.WhichOneof("value"))
    return {
        "name": metric.name if metric.HasField("name") else None,
        "alias": metric.alias if metric.HasField("alias") else None,
        "timestamp": metric.timestamp if metric.HasField("timestamp") else None,
        "datatype": metric.datatype,
        "is_null": metric.is_null,
        "is_historical": metric.is_historical,
        "value": getattr(metric, kind) if kind else None,
        "properties": properties,
    }


def on_connect(client, userdata, flags, rc):
    client.subscribe(f"spBv1.0/{group}/#", qos=1)


def on_subscribe(client, userdata, mid, granted_qos):
    emit({"ready": True})


def on_message(client, userdata, message):
    topic = message.topic
    rewritten = options.dots_as_slashes and topic.startswith("spBv1/0/")
    if rewritten:
        topic = "spBv1.0/" + topic[len("spBv1/0/"):]
    parts = topic.split("/")
    payload = Payload()
    try:
        payload.ParseFromString(message.payload)
    except Exception:  # noqa: BLE001 (any protobuf error: not a Sparkplug payload)
        emit({"topic": topic, "type": parts[2], "undecodable": True,
              "bytes": len(message.payload), "retain": bool(message.retain)})
        return
    emit(
        {
            "topic": topic,
            "rewritten": rewritten,
            "type": parts[2],
            "node": parts[3],
            "device": parts[4] if len(parts) > 4 else None,
            "seq": payload.seq if payload.HasField("seq") else None,
            "timestamp": payload.timestamp if payload.HasField("timestamp") else None,
            "metrics": [metric_json(m) for m in payload.metrics],
        }
    )


client = mqtt.Client(client_id="test-host")
client.on_connect = on_connect
client.on_subscribe = on_subscribe
client.on_message = on_message
if options.ca:
    client.tls_set(ca_certs=options.ca, certfile=options.cert, keyfile=options.key)
if options.username:
    client.username_pw_set(options.username, options.password)
client.connect(host, port, keepalive=30)
client.loop_start()

for line in sys.stdin:
    words = line.split()
    if words[:1] == ["rebirth"]:
        command = Payload()
        metric = command.metrics.add()
        metric.name = "Node Control/Rebirth"
        metric.datatype = BOOLEAN
        metric.boolean_value = True
        for _ in range(int(words[2]) if len(words) > 2 else 1):
            client.publish(f"spBv1.0/{group}/NCMD/{words[1]}", command.SerializeToString(), qos=1)
    elif words[:1] == ["garbage"]:
        retain = words[3:4] == ["retain"]
        info = client.publish(f"spBv1.0/{group}/NCMD/{words[1]}", b"\xff" * int(words[2]), qos=1, retain=retain)
        info.wait_for_publish()
        emit({"sent": "garbage"})
    elif words[:1] == ["clear"]:
        info = client.publish(f"spBv1.0/{group}/NCMD/{words[1]}", b"", qos=1, retain=True)
        info.wait_for_publish()
        emit({"sent": "clear"})
    elif words[:1] == ["state"]:
        state = {"online": words[2] == "online", "timestamp": int(time.time() * 1000)}
        info = client.publish(f"spBv1.0/STATE/{words[1]}", json.dumps(state), qos=1, retain=True)
        info.wait_for_publish()
        emit({"sent": "state"})
client.loop_stop()
