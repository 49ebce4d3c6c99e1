"""What a careless or hostile OPC UA client does to a server, for gateway/tests/opcua.rs
and the measurements in docs/opcua.md: Python asyncua 2.1.0, one JSON line on stdout
per step.

    python3 opcua_abuse.py orphans URL SESSIONS SUBSCRIPTIONS ITEMS
        SESSIONS sessions one after the other, each with SUBSCRIPTIONS subscriptions
        (publishing interval 1 h, lifetime count 90 000, keep-alive count 30 000) of
        ITEMS monitored items each (the variables of Millgate, repeated), closed with
        DeleteSubscriptions = false. Prints the revised values of the first
        subscription and what was created and refused (by status name).
    python3 opcua_abuse.py hold-sessions URL COUNT [FROM]
        COUNT sessions, each on its own connection (from the local address FROM, a
        loopback address, when given), then {"type": "held"} with the sessions held
        and the refused by status name; waits to be killed (sockets dropped without
        CloseSession).
    python3 opcua_abuse.py browse-points URL COUNT
        COUNT browses of one reference at a time without BrowseNext: how many left a
        continuation point, how many were refused (by status name).
    python3 opcua_abuse.py unread URL SECONDS [BLOCKED_S]
        Raw OPC UA TCP: Hello, a channel of SecurityPolicy None, then GetEndpoints
        requests written for SECONDS without reading an answer (until the socket
        stays blocked BLOCKED_S, default 2 s): how many were written.
    python3 opcua_abuse.py rejected URL COUNT DIR
        COUNT connections with Basic256Sha256 sign and encrypt, each with its own
        self-signed certificate (one key, made in DIR): the refusals by status name.
"""

import asyncio
import datetime
import json
import socket
import struct
import sys
import time
from urllib.parse import urlparse
from collections import Counter
from pathlib import Path

from asyncua import Client, ua
from asyncua.crypto import security_policies
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import rsa
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

NAMESPACE = "urn:millgate:results"
# How long a write may stay blocked before `unread` stops.
BLOCKED_S = 2.0


def emit(message):
    print(json.dumps(message, default=str), flush=True)


def status_name(error):
    code = getattr(error, "code", None)
    return ua.StatusCode(code).name if code is not None else type(error).__name__


async def variables(client):
    ns = await client.get_namespace_index(NAMESPACE)
    found = []

    async def walk(node):
        for child in await node.get_children(refs=ua.ObjectIds.HierarchicalReferences):
            node_class = await child.read_node_class()
            if node_class == ua.NodeClass.Variable:
                found.append(child.nodeid)
            elif node_class == ua.NodeClass.Object:
                await walk(child)

    await walk(client.get_node(ua.NodeId("Millgate", ns)))
    return found


async def orphans(url, sessions, subscriptions, items):
    created, refused = Counter(), Counter()
    revised = None
    nodes = None
    for _ in range(sessions):
        client = Client(url, timeout=30)
        try:
            await client.connect()
        except Exception as error:
            refused["session " + status_name(error)] += 1
            continue
        if nodes is None:
            nodes = await variables(client)
        for _ in range(subscriptions):
            params = ua.CreateSubscriptionParameters(
                RequestedPublishingInterval=3_600_000.0, RequestedLifetimeCount=90_000,
                RequestedMaxKeepAliveCount=30_000, MaxNotificationsPerPublish=0,
                PublishingEnabled=True, Priority=0)
            try:
                result = await client.uaclient.create_subscription(params, lambda *_: None)
            except Exception as error:
                refused["subscription " + status_name(error)] += 1
                continue
            created["subscriptions"] += 1
            if revised is None:
                revised = {"interval_ms": result.RevisedPublishingInterval,
                           "lifetime": result.RevisedLifetimeCount,
                           "keep_alive": result.RevisedMaxKeepAliveCount}
            for start in range(0, items, 1000):
                batch = [ua.MonitoredItemCreateRequest(
                    ItemToMonitor=ua.ReadValueId(NodeId=nodes[i % len(nodes)],
                                                 AttributeId=ua.AttributeIds.Value),
                    MonitoringMode=ua.MonitoringMode.Reporting,
                    RequestedParameters=ua.MonitoringParameters(
                        ClientHandle=i, SamplingInterval=100.0, QueueSize=1,
                        DiscardOldest=True))
                    for i in range(start, min(items, start + 1000))]
                try:
                    results = await client.uaclient.create_monitored_items(
                        ua.CreateMonitoredItemsParameters(
                            SubscriptionId=result.SubscriptionId,
                            TimestampsToReturn=ua.TimestampsToReturn.Both,
                            ItemsToCreate=batch))
                except Exception as error:
                    refused["items " + status_name(error)] += len(batch)
                    continue
                for r in results:
                    if r.StatusCode.is_good():
                        created["items"] += 1
                    else:
                        refused["items " + r.StatusCode.name] += 1
        # Left behind: the session closes, its subscriptions stay.
        try:
            await client.uaclient.close_session(False)
            await client.close_secure_channel()
        except Exception as error:
            refused["close " + status_name(error)] += 1
        finally:
            client.disconnect_socket()
    emit({"type": "orphans", "created": created, "refused": refused, "revised": revised})


async def hold_sessions(url, count, source=None):
    if source is not None:
        # asyncua has no option for the local address: its connections are made by
        # the loop's create_connection.
        loop = asyncio.get_running_loop()
        connect = loop.create_connection
        loop.create_connection = lambda *args, **kwargs: connect(
            *args, local_addr=(source, 0), **kwargs)
    clients = []
    refused = Counter()
    for _ in range(count):
        client = Client(url, timeout=30)
        try:
            await client.connect()
            clients.append(client)
        except Exception as error:
            refused[status_name(error)] += 1
            client.disconnect_socket()
    emit({"type": "held", "sessions": len(clients), "refused": refused})
    await asyncio.sleep(3600)


async def browse_points(url, count):
    client = Client(url, timeout=30)
    await client.connect()
    results = Counter()
    try:
        for _ in range(count):
            description = ua.BrowseDescription(
                NodeId=ua.NodeId(ua.ObjectIds.Server), BrowseDirection=ua.BrowseDirection.Forward,
                ReferenceTypeId=ua.NodeId(ua.ObjectIds.HierarchicalReferences),
                IncludeSubtypes=True, NodeClassMask=0, ResultMask=63)
            params = ua.BrowseParameters()
            params.View.Timestamp = ua.get_win_epoch()
            params.RequestedMaxReferencesPerNode = 1
            params.NodesToBrowse.append(description)
            [result] = await client.uaclient.browse(params)
            if result.StatusCode.is_good() and result.ContinuationPoint:
                results["continuation_points"] += 1
            else:
                results[result.StatusCode.name] += 1
    finally:
        await client.disconnect()
    emit({"type": "browse_points", "results": results})


def ua_bytes(value):
    return struct.pack("<i", -1) if value is None else struct.pack("<i", len(value)) + value


def request_header(handle):
    return (b"\x00\x00" + struct.pack("<qII", 0, handle, 0) + ua_bytes(None)
            + struct.pack("<I", 10_000) + b"\x00\x00\x00")


def framed(kind, body):
    return kind + struct.pack("<I", 8 + len(body)) + body


def read_message(sock):
    def exactly(n):
        data = b""
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("closed")
            data += chunk
        return data
    header = exactly(8)
    return header + exactly(struct.unpack("<I", header[4:8])[0] - 8)


def unread(url, seconds):
    where = urlparse(url)
    sock = socket.create_connection((where.hostname, where.port))
    hello = struct.pack("<IIIII", 0, 65535, 65535, 0, 0) + ua_bytes(url.encode())
    sock.sendall(framed(b"HELF", hello))
    assert read_message(sock).startswith(b"ACKF")
    policy = b"http://opcfoundation.org/UA/SecurityPolicy#None"
    body = (struct.pack("<I", 0) + ua_bytes(policy) + ua_bytes(None) + ua_bytes(None)
            + struct.pack("<II", 1, 1) + b"\x01\x00" + struct.pack("<H", 446) + request_header(1)
            + struct.pack("<III", 0, 0, 1) + ua_bytes(b"") + struct.pack("<I", 600_000))
    sock.sendall(framed(b"OPNF", body))
    answer = read_message(sock)
    channel = struct.unpack("<I", answer[8:12])[0]
    at = 12
    for _ in range(3):
        length = struct.unpack("<i", answer[at:at + 4])[0]
        at += 4 + max(length, 0)
    at += 12 + 28
    token = struct.unpack("<I", answer[at + 8:at + 12])[0]
    sock.setblocking(False)
    sequence, sent, pending = 1, 0, b""
    started = time.monotonic()
    blocked_since = None
    while time.monotonic() - started < seconds:
        if not pending:
            batch = []
            for _ in range(100):
                sequence += 1
                body = (struct.pack("<IIII", channel, token, sequence, sequence) + b"\x01\x00"
                        + struct.pack("<H", 428) + request_header(sequence) + ua_bytes(url.encode())
                        + struct.pack("<ii", -1, -1))
                batch.append(framed(b"MSGF", body))
            pending = b"".join(batch)
            sent += 100
        try:
            written = sock.send(pending)
            pending = pending[written:]
            blocked_since = None
        except BlockingIOError:
            blocked_since = blocked_since or time.monotonic()
            if time.monotonic() - blocked_since > BLOCKED_S:
                break
            time.sleep(0.01)
    emit({"type": "unread", "sent": sent, "seconds": time.monotonic() - started,
          "blocked": blocked_since is not None})
    sock.close()


def certificate(key, serial):
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"stranger {serial}")])
    now = datetime.datetime.now(datetime.timezone.utc)
    uri = "urn:millgate-test:stranger"
    return (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(serial)
            .not_valid_before(now - datetime.timedelta(days=1))
            .not_valid_after(now + datetime.timedelta(days=30))
            .add_extension(x509.SubjectAlternativeName([x509.UniformResourceIdentifier(uri)]),
                           critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True,
                                         key_encipherment=True, data_encipherment=True,
                                         key_agreement=False, key_cert_sign=False, crl_sign=False,
                                         encipher_only=False, decipher_only=False), critical=False)
            .sign(key, hashes.SHA256()))


async def rejected(url, count, folder):
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    key_path = folder / "stranger.pem"
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                           serialization.PrivateFormat.TraditionalOpenSSL,
                                           serialization.NoEncryption()))
    results = Counter()
    for serial in range(1, count + 1):
        cert_path = folder / "stranger.der"
        cert_path.write_bytes(certificate(key, serial).public_bytes(serialization.Encoding.DER))
        client = Client(url, timeout=30)
        client.application_uri = "urn:millgate-test:stranger"
        await client.set_security(security_policies.SecurityPolicyBasic256Sha256,
                                  str(cert_path), str(key_path),
                                  mode=ua.MessageSecurityMode.SignAndEncrypt)
        try:
            await client.connect()
            results["connected"] += 1
            await client.disconnect()
        except Exception as error:
            results[status_name(error)] += 1
            client.disconnect_socket()
    emit({"type": "rejected", "results": results})


def main():
    command, url, *rest = sys.argv[1:]
    if command == "orphans":
        asyncio.run(orphans(url, *map(int, rest)))
    elif command == "hold-sessions":
        asyncio.run(hold_sessions(url, int(rest[0]), *rest[1:2]))
    elif command == "browse-points":
        asyncio.run(browse_points(url, int(rest[0])))
    elif command == "unread":
        global BLOCKED_S
        BLOCKED_S = float(rest[1]) if len(rest) > 1 else BLOCKED_S
        unread(url, float(rest[0]))
    elif command == "rejected":
        asyncio.run(rejected(url, int(rest[0]), rest[1]))
    else:
        sys.exit(f"unknown command {command}")


if __name__ == "__main__":
    main()
