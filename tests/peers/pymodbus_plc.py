#!/usr/bin/env python3
"""A PLC played by pymodbus: a Modbus TCP server with writable holding registers.

usage: pymodbus_plc.py PORT REGISTERS

Listens on 127.0.0.1:PORT, prints "ready" once listening, serves until its standard
input closes, then prints the holding registers 0..REGISTERS-1 as a JSON list.
"""
import asyncio
import json
import sys

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
from pymodbus.server import ServerAsyncStop, StartAsyncTcpServer


async def main(port: int, registers: int) -> None:
    device = ModbusDeviceContext(hr=ModbusSequentialDataBlock(1, [0] * (registers + 1)))
    context = ModbusServerContext(devices=device, single=True)
    server = asyncio.create_task(StartAsyncTcpServer(context, address=("127.0.0.1", port)))
    await asyncio.sleep(0.3)
    print("ready", flush=True)
    loop = asyncio.get_running_loop()
    await loop.run_in_executor(None, sys.stdin.read)
    # Read back over Modbus, as the PLC program would see its registers (this keeps
    # clear of pymodbus' datastore internals, which change between releases).
    client = AsyncModbusTcpClient("127.0.0.1", port=port)
    await client.connect()
    values = []
    for start in range(0, registers, 125):
        count = min(125, registers - start)
        reply = await client.read_holding_registers(start, count=count, device_id=1)
        values.extend(reply.registers)
    client.close()
    print(json.dumps(values), flush=True)
    await ServerAsyncStop()
    server.cancel()


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1]), int(sys.argv[2])))
