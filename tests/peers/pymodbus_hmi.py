#!/usr/bin/env python3
"""An HMI played by pymodbus: reads the gateway's register map, acknowledges alarms,
and probes a bad address and a write to a result register.

usage: pymodbus_hmi.py PORT MAP_LEN ACK_ADDRESS RESULT_ADDRESS

Prints one JSON object: the first registers, and the exception codes seen.
"""
import json
import sys

from pymodbus.client import ModbusTcpClient


def exception_code(response):
    return getattr(response, "exception_code", None) if response.isError() else None


def main(port: int, map_len: int, ack: int, result: int) -> None:
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=2)
    if not client.connect():
        raise SystemExit(f"cannot connect to 127.0.0.1:{port}")
    head = client.read_holding_registers(0, count=8, device_id=1)
    past = client.read_holding_registers(map_len, count=1, device_id=1)
    write_result = client.write_register(result, 1, device_id=1)
    write_ack = client.write_register(ack, 1, device_id=1)
    bad_ack = client.write_register(ack, 9, device_id=1)
    client.close()
    print(json.dumps({
        "head": None if head.isError() else list(head.registers),
        "read_past_map": exception_code(past),
        "write_result_register": exception_code(write_result),
        "write_ack": exception_code(write_ack),
        "write_bad_ack_value": exception_code(bad_ack),
    }))


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:5]))
