#!/usr/bin/env python3
"""An HMI played by pymodbus: reads the gateway's register map (FC 03 and FC 04),
acknowledges alarms (FC 06 and FC 16), probes a bad address and a write to a result
register, and asks every other function code pymodbus offers (01, 02, 05, 15, 22, 23).

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
    head_input = client.read_input_registers(0, count=8, device_id=1)
    past = client.read_holding_registers(map_len, count=1, device_id=1)
    write_result = client.write_register(result, 1, device_id=1)
    write_ack = client.write_register(ack, 1, device_id=1)
    write_ack_multiple = client.write_registers(ack, [1], device_id=1)
    bad_ack = client.write_register(ack, 9, device_id=1)
    # Every other function code a client library offers: exception 01 each.
    others = {
        "01": client.read_coils(0, count=1, device_id=1),
        "02": client.read_discrete_inputs(0, count=1, device_id=1),
        "05": client.write_coil(0, True, device_id=1),
        "15": client.write_coils(0, [True], device_id=1),
        "22": client.mask_write_register(address=ack, and_mask=0xFFFF, or_mask=0, device_id=1),
        "23": client.readwrite_registers(
            read_address=0, read_count=1, write_address=ack, values=[1], device_id=1
        ),
    }
    client.close()
    print(json.dumps({
        "head": None if head.isError() else list(head.registers),
        "head_fc04": None if head_input.isError() else list(head_input.registers),
        "read_past_map": exception_code(past),
        "write_result_register": exception_code(write_result),
        "write_ack": exception_code(write_ack),
        "write_ack_fc16": exception_code(write_ack_multiple),
        "write_bad_ack_value": exception_code(bad_ack),
        "other_functions": {fc: exception_code(answer) for fc, answer in others.items()},
    }))


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:5]))
