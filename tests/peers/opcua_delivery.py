"""A subscriber at scale for gateway/tests/opcua_delivery.rs: Python asyncua 2.1.0
subscribes to every variable of the test's server (node ids
Millgate/Drivelines/D<k>/v<j>, publishing interval 100 ms, queue size QUEUE, values that
only grow by 1 per update) and checks that every value either arrives or is marked as
dropped: a value more than 1 above the last one received of its variable must carry the
Overflow bit (OPC 10000-4 5.12.1.5: the server set it on the value after the ones it
discarded from the item's queue).

    python3 opcua_delivery.py URL OBJECTS VARIABLES QUEUE

Prints {"ready": true} once subscribed. On each line "report" on stdin, one JSON line:
the changes received, the gaps marked with the Overflow bit, the gaps without it, the
smallest of the variables' latest values, and the Publish responses that came back as a
fault (a Bad service result such as Bad_ResponseTooLarge: every value in it lost).
"""

import asyncio
import json
import logging
import sys

from asyncua import Client, ua

NAMESPACE = "urn:millgate:results"
# StatusCode InfoType DataValue (0x400) with its Overflow bit (0x80), OPC 10000-4 7.39.
INFO_TYPE_DATA_VALUE = 0x400
OVERFLOW = 0x80


class Faults(logging.Handler):
    """asyncua logs a faulted Publish response and goes on: count those that lost
    values. Bad_Timeout is not one: a Publish request the server held for its timeout
    (30 s) without a message to send; asyncua sends the next."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.count = 0

    def emit(self, record):
        message = record.getMessage()
        if "PublishRequest" in message and "BadTimeout" not in message:
            self.count += 1
            sys.stderr.write(f"opcua_delivery.py: {message}\n")


class Checker:
    def __init__(self):
        self.changes = 0
        self.marked_gaps = 0
        self.unmarked_gaps = 0
        self.latest = {}

    def datachange_notification(self, node, value, data):
        self.changes += 1
        key = node.nodeid.Identifier
        status = data.monitored_item.Value.StatusCode
        overflow = status is not None and status.value & INFO_TYPE_DATA_VALUE and status.value & OVERFLOW
        last = self.latest.get(key)
        if last is not None and value is not None and value > last + 1:
            if overflow:
                self.marked_gaps += 1
            else:
                self.unmarked_gaps += 1
        self.latest[key] = value


async def main(url, objects, variables, queue):
    faults = Faults()
    logging.getLogger("asyncua").addHandler(faults)
    async with Client(url, timeout=60) as client:
        ns = await client.get_namespace_index(NAMESPACE)
        nodes = [
            client.get_node(ua.NodeId(f"Millgate/Drivelines/D{k}/v{j}", ns))
            for k in range(objects)
            for j in range(variables)
        ]
        checker = Checker()
        subscription = await client.create_subscription(100, checker)
        for start in range(0, len(nodes), 1000):
            await subscription.subscribe_data_change(nodes[start:start + 1000], queuesize=queue)
        print(json.dumps({"ready": True}), flush=True)
        loop = asyncio.get_running_loop()
        while True:
            line = await loop.run_in_executor(None, sys.stdin.readline)
            if not line or line.strip() == "quit":
                break
            latest = [checker.latest.get(n.nodeid.Identifier) for n in nodes]
            print(json.dumps({
                "changes": checker.changes,
                "marked_gaps": checker.marked_gaps,
                "unmarked_gaps": checker.unmarked_gaps,
                "least_latest": None if None in latest else min(latest),
                "faults": faults.count,
            }), flush=True)


if __name__ == "__main__":
    url, objects, variables, queue = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    asyncio.run(main(url, objects, variables, queue))
