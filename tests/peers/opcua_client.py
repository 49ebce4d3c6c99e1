"""An OPC UA client that is not ours, for gateway/tests/opcua.rs: Python asyncua
2.1.0 (pinned in scripts/test). It connects to the gateway, then takes commands on
stdin and answers with one JSON object per line on stdout:

    browse                 every object, variable and method under Millgate
    read PATH              one variable (PATH below Millgate, e.g. Drivelines/F1/taf)
    subscribe PATH...      data changes of variables (100 ms publishing)
    events                 AlarmConditionType events from the Server object (where
                           clause OfType AlarmConditionType)
    defaultevents          AlarmConditionType, RefreshStartEventType and
                           RefreshEndEventType events from the Server object with
                           asyncua's own filter (subscribe_events: their fields, where
                           clause EventType InList [the types and their subtypes])
    baseevents             events from the Server object with asyncua's defaults
                           (subscribe_events() without arguments: BaseEventType's
                           fields, where clause EventType InList [every event type])
    refresh [ID]           ConditionRefresh of the subscription (or of ID)
    refresh2 [ID]          ConditionRefresh2 of the subscription's event item (or ID)
    ackcondition NODE HEX [COMMENT]
                           call the condition NODE's Acknowledge (i=9111) with EventId HEX
    translate NAME...      TranslateBrowsePathsToNodeIds from Objects (names ns:Name)
    children PATH          the browse names of PATH's children, in the server's order
    buildinfo              Server/ServerStatus/BuildInfo
    nsindex URI            the index of namespace URI
    readpath NAME...       read the variable at the browse path NAME... from Objects
    ack                    call Gateway/AcknowledgeAlarms
    quit

Notifications come as {"type": "data", ...} and {"type": "event", ...} lines at any
time. A connection the server refuses prints {"type": "refused", ...} and exits 0.

    python3 opcua_client.py URL [--user NAME --password PW]
        [--cert-dir DIR --mode sign|sign_and_encrypt]

With --cert-dir the client makes (once) a self-signed certificate in DIR
(client.der, client.pem) for application URI urn:millgate-test:client and connects
with Basic256Sha256 in the given mode.
"""

import argparse
import asyncio
import datetime
import json
import socket
import sys
from pathlib import Path

from asyncua import Client, ua
from asyncua.common.events import get_filter_from_event_type
from asyncua.crypto import cert_gen, security_policies
from cryptography.x509.oid import ExtendedKeyUsageOID

NAMESPACE = "urn:millgate:results"
APP_URI = "urn:millgate-test:client"


def emit(message):
    print(json.dumps(message, default=str), flush=True)


def plain(value):
    """A variant's value as JSON."""
    if isinstance(value, datetime.datetime):
        return {"time": value.isoformat(), "unix": value.timestamp()}
    if isinstance(value, ua.EUInformation):
        return {
            "namespace": value.NamespaceUri,
            "unit_id": value.UnitId,
            "display": value.DisplayName.Text,
            "description": value.Description.Text,
        }
    if isinstance(value, ua.Range):
        return [value.Low, value.High]
    if isinstance(value, ua.LocalizedText):
        return value.Text
    if isinstance(value, ua.NodeId):
        return value.to_string()
    if isinstance(value, ua.StatusCode):
        return value.name
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, ua.QualifiedName):
        return value.Name
    return value


def data_value(dv):
    return {
        "value": plain(dv.Value.Value) if dv.Value is not None else None,
        "variant": dv.Value.VariantType.name if dv.Value is not None else None,
        "status": dv.StatusCode.name,
        "source": plain(dv.SourceTimestamp) if dv.SourceTimestamp else None,
        "server": plain(dv.ServerTimestamp) if dv.ServerTimestamp else None,
    }


class Handler:
    def __init__(self, paths):
        self.paths = paths

    def datachange_notification(self, node, _value, data):
        dv = data.monitored_item.Value
        emit({"type": "data", "path": self.paths.get(node.nodeid.to_string()), **data_value(dv)})

    def event_notification(self, event):
        fields = {name: plain(variant.Value) for name, variant in event.get_event_props_as_fields_dict().items()}
        emit({"type": "event", "fields": fields})

    def status_change_notification(self, status):
        emit({"type": "status", "status": str(status)})


async def browse(client, ns):
    root = client.get_node(ua.NodeId(f"Millgate", ns))
    objects, variables, methods = [], [], []

    async def walk(node, path):
        for child in await node.get_children(refs=ua.ObjectIds.HierarchicalReferences):
            name = (await child.read_browse_name()).Name
            child_path = f"{path}/{name}" if path else name
            node_class = await child.read_node_class()
            if node_class == ua.NodeClass.Object:
                notifier = await child.read_event_notifier()
                objects.append({"path": child_path, "node": child.nodeid.to_string(),
                                "events": ua.EventNotifier.SubscribeToEvents in notifier})
                await walk(child, child_path)
            elif node_class == ua.NodeClass.Method:
                methods.append({"path": child_path, "node": child.nodeid.to_string()})
            elif node_class == ua.NodeClass.Variable:
                if name in ("EngineeringUnits", "EURange"):
                    continue
                entry = {"path": child_path, "node": child.nodeid.to_string()}
                data_type = await client.get_node(await child.read_data_type()).read_browse_name()
                entry["datatype"] = data_type.Name
                entry["type_definition"] = (await child.read_type_definition()).to_string()
                entry["description"] = (await child.read_description()).Text
                entry.update(data_value(await child.read_data_value(raise_on_bad_status=False)))
                for prop in await child.get_properties():
                    prop_name = (await prop.read_browse_name()).Name
                    entry[prop_name] = plain(await prop.read_value())
                variables.append(entry)

    await walk(root, "")
    emit({"type": "browse", "objects": objects, "variables": variables, "methods": methods})


async def session(args):
    client = Client(args.url, timeout=10)
    client.application_uri = APP_URI
    client.name = "millgate test client"
    if args.user:
        client.set_user(args.user)
        client.set_password(args.password)
    if args.cert_dir:
        folder = Path(args.cert_dir)
        folder.mkdir(parents=True, exist_ok=True)
        key, cert = folder / "client.pem", folder / "client.der"
        if not cert.exists():
            await cert_gen.setup_self_signed_certificate(
                key, cert, APP_URI, socket.gethostname(),
                [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "millgate test client"})
        mode = {"sign": ua.MessageSecurityMode.Sign,
                "sign_and_encrypt": ua.MessageSecurityMode.SignAndEncrypt}[args.mode]
        await client.set_security(security_policies.SecurityPolicyBasic256Sha256,
                                  str(cert), str(key), mode=mode)
    try:
        await client.connect()
    except Exception as error:  # the server refused: say why, as the test expects
        status = getattr(error, "code", None)
        emit({"type": "refused", "error": f"{type(error).__name__}: {error}",
              "status": ua.StatusCode(status).name if status is not None else None})
        return
    try:
        ns = await client.get_namespace_index(NAMESPACE)
        emit({"type": "ready", "namespace": ns})
        node = lambda path: client.get_node(ua.NodeId(f"Millgate/{path}", ns))
        subscription = None
        event_item = None
        paths = {}
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
        while True:
            line = (await reader.readline()).decode().strip()
            if not line or line == "quit":
                break
            command, *rest = line.split()
            try:
                if command == "browse":
                    await browse(client, ns)
                elif command == "read":
                    dv = await node(rest[0]).read_data_value(raise_on_bad_status=False)
                    emit({"type": "read", "path": rest[0], **data_value(dv)})
                elif command == "defaultevents":
                    if subscription is None:
                        subscription = await client.create_subscription(100, Handler(paths))
                    types = [client.get_node(t) for t in (ua.ObjectIds.AlarmConditionType,
                             ua.ObjectIds.RefreshStartEventType, ua.ObjectIds.RefreshEndEventType)]
                    event_item = await subscription.subscribe_events(client.nodes.server, types)
                    emit({"type": "subscribed", "what": line, "subscription": subscription.subscription_id})
                elif command == "baseevents":
                    if subscription is None:
                        subscription = await client.create_subscription(100, Handler(paths))
                    await subscription.subscribe_events()
                    emit({"type": "subscribed", "what": line, "subscription": subscription.subscription_id})
                elif command in ("refresh", "refresh2"):
                    condition_type = client.get_node(ua.ObjectIds.ConditionType)
                    sub_id = int(rest[0]) if rest else subscription.subscription_id
                    args = [ua.Variant(sub_id, ua.VariantType.UInt32)]
                    method = ua.ObjectIds.ConditionType_ConditionRefresh
                    if command == "refresh2":
                        method = ua.ObjectIds.ConditionType_ConditionRefresh2
                        item = int(rest[1]) if len(rest) > 1 else event_item
                        args.append(ua.Variant(item, ua.VariantType.UInt32))
                    try:
                        await condition_type.call_method(ua.NodeId(method), *args)
                        emit({"type": "refresh", "status": "Good"})
                    except ua.UaStatusCodeError as error:
                        emit({"type": "refresh", "status": ua.StatusCode(error.code).name})
                elif command == "ackcondition":
                    condition = client.get_node(ua.NodeId.from_string(rest[0]))
                    comment = ua.LocalizedText(" ".join(rest[2:]), "en")
                    try:
                        await condition.call_method(
                            ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                            ua.Variant(bytes.fromhex(rest[1]), ua.VariantType.ByteString),
                            ua.Variant(comment, ua.VariantType.LocalizedText))
                        emit({"type": "ack", "status": "Good"})
                    except ua.UaStatusCodeError as error:
                        emit({"type": "ack", "status": ua.StatusCode(error.code).name})
                elif command == "translate":
                    try:
                        found = await client.nodes.objects.get_child(rest)
                        emit({"type": "translate", "node": found.nodeid.to_string()})
                    except ua.UaStatusCodeError as error:
                        emit({"type": "translate", "status": ua.StatusCode(error.code).name})
                elif command == "children":
                    children = await node(rest[0]).get_children()
                    names = [(await c.read_browse_name()).to_string() for c in children]
                    emit({"type": "children", "names": names})
                elif command == "nsindex":
                    emit({"type": "nsindex", "index": await client.get_namespace_index(rest[0])})
                elif command == "readpath":
                    found = await client.nodes.objects.get_child(rest)
                    dv = await found.read_data_value(raise_on_bad_status=False)
                    emit({"type": "readpath", "node": found.nodeid.to_string(), **data_value(dv)})
                elif command == "buildinfo":
                    info = await client.get_node(ua.ObjectIds.Server_ServerStatus_BuildInfo).read_value()
                    emit({"type": "buildinfo", "product": info.ProductName, "uri": info.ProductUri,
                          "manufacturer": info.ManufacturerName, "version": info.SoftwareVersion,
                          "date": plain(info.BuildDate)})
                elif command in ("subscribe", "events"):
                    if subscription is None:
                        subscription = await client.create_subscription(100, Handler(paths))
                    if command == "subscribe":
                        nodes = [node(path) for path in rest]
                        for path, n in zip(rest, nodes):
                            paths[n.nodeid.to_string()] = path
                        await subscription.subscribe_data_change(nodes)
                    else:
                        # The fields of AlarmConditionType; the where clause OfType:
                        # async-opcua 0.19 cannot compare NodeIds, so asyncua's own
                        # where clause (EventType InList [...]) would match nothing.
                        alarm_type = client.get_node(ua.ObjectIds.AlarmConditionType)
                        evfilter = await get_filter_from_event_type([alarm_type], False)
                        evfilter.WhereClause = ua.ContentFilter(Elements=[ua.ContentFilterElement(
                            FilterOperator=ua.FilterOperator.OfType,
                            FilterOperands=[ua.LiteralOperand(Value=ua.Variant(alarm_type.nodeid))])])
                        await subscription.subscribe_events(
                            client.nodes.server, alarm_type, evfilter=evfilter)
                    emit({"type": "subscribed", "what": line})
                elif command == "ack":
                    try:
                        await node("Gateway").call_method(ua.NodeId("Millgate/Gateway/AcknowledgeAlarms", ns))
                        emit({"type": "ack", "status": "Good"})
                    except ua.UaStatusCodeError as error:
                        emit({"type": "ack", "status": ua.StatusCode(error.code).name})
                else:
                    emit({"type": "error", "error": f"unknown command {command}"})
            except Exception as error:
                emit({"type": "error", "error": f"{command}: {type(error).__name__}: {error}"})
    finally:
        await client.disconnect()


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("url")
    parser.add_argument("--user")
    parser.add_argument("--password")
    parser.add_argument("--cert-dir")
    parser.add_argument("--mode", default="sign_and_encrypt", choices=["sign", "sign_and_encrypt"])
    asyncio.run(session(parser.parse_args()))


if __name__ == "__main__":
    main()
