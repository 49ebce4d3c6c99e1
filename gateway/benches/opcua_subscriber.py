"""The subscribed client of gateway/benches/opcua.rs: Python asyncua 2.1.0 subscribes
to every variable the bench's server publishes (node ids Millgate/Drivelines/D<k>/v<j>,
publishing interval 100 ms, queue size QUEUE) and counts the data changes it receives.

    python3 opcua_subscriber.py URL OBJECTS VARIABLES SECONDS QUEUE

Prints {"ready": true} once subscribed, then, after SECONDS, one JSON line: the
changes received, the seconds they came in, the changes whose value was not the
latest one of their variable's (values only grow, so an older value is a reordering),
the changes that carried the Overflow bit (the server dropped a value of that variable
from its queue before this one), and the client's own CPU seconds over the run (near
SECONDS: the client is the bound).
"""

import asyncio
import json
import resource
import sys
import time

from asyncua import Client, ua

NAMESPACE = "urn:millgate:results"
# StatusCode InfoType DataValue (0x400) with its Overflow bit (0x80), OPC 10000-4 7.39.
INFO_TYPE_DATA_VALUE = 0x400
OVERFLOW = 0x80


class Counter:
    def __init__(self):
        self.changes = 0
        self.first = None
        self.last = None
        self.latest = {}
        self.out_of_order = 0
        self.overflow = 0

    def datachange_notification(self, node, value, data):
        now = time.monotonic()
        if self.first is None:
            self.first = now
        self.last = now
        self.changes += 1
        key = node.nodeid.Identifier
        if value is not None and value < self.latest.get(key, float("-inf")):
            self.out_of_order += 1
        self.latest[key] = value
        status = data.monitored_item.Value.StatusCode.value
        if status & INFO_TYPE_DATA_VALUE and status & OVERFLOW:
            self.overflow += 1


async def main(url, objects, variables, seconds, queue):
    async with Client(url, timeout=30) as client:
        ns = await client.get_namespace_index(NAMESPACE)
        nodes = [
            client.get_node(ua.NodeId(f"Millgate/Drivelines/D{k}/v{j}", ns))
            for k in range(objects)
            for j in range(variables)
        ]
        counter = Counter()
        subscription = await client.create_subscription(100, counter)
        for start in range(0, len(nodes), 1000):
            await subscription.subscribe_data_change(nodes[start:start + 1000], queuesize=queue)
        # The initial values are not part of the run.
        await asyncio.sleep(1.0)
        counter.changes, counter.first, counter.out_of_order, counter.overflow = 0, None, 0, 0
        cpu = resource.getrusage(resource.RUSAGE_SELF)
        print(json.dumps({"ready": True}), flush=True)
        await asyncio.sleep(seconds)
        span = (counter.last - counter.first) if counter.first is not None else 0.0
        used = resource.getrusage(resource.RUSAGE_SELF)
        client_cpu = (used.ru_utime - cpu.ru_utime) + (used.ru_stime - cpu.ru_stime)
        print(json.dumps({"changes": counter.changes, "seconds": span,
                          "out_of_order": counter.out_of_order,
                          "overflow": counter.overflow,
                          "client_cpu": client_cpu}), flush=True)
        await subscription.delete()


if __name__ == "__main__":
    url, objects, variables, seconds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
    queue = int(sys.argv[5]) if len(sys.argv) > 5 else 1
    asyncio.run(main(url, objects, variables, seconds, queue))
