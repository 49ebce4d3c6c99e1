#!/usr/bin/env python3
"""A Modbus RTU device played by pymodbus: a drive with a small DAQ on a serial line.

usage: pymodbus_rtu_device.py DEVICE BAUD STOPBITS UNIT EPOCH [firehose]

Serves Modbus RTU on the serial device DEVICE (BAUD, 8 data bits, no parity: a
pseudo-terminal refuses parity settings, STOPBITS 1 or 2) as unit UNIT:

- registers 200-201: the speed, 12.5 as f32 (ABCD word order);
- register 202: 4242 (u16);
- registers 0..121: a sample block in the millgate acquisition layout. Block k,
  k = floor((now - EPOCH) / 0.1 s), has sequence k mod 65536 and 20 samples; sample i
  of block k is ((20 k + i) mod 2000) - 1000 (i16). The blocks follow the wall clock
  from EPOCH (seconds since 1970), so a device restarted with the same EPOCH goes on
  as if it had kept sampling (a cable pulled and plugged back), and a reader can tell
  from the values alone which samples it missed.

With "firehose" the block is instead a new one at every read of register 0 (block k
for the k-th read; EPOCH unused): the RTU benchmark's device, whose every poll brings
a block.

Holding and input registers are one register space (pymodbus' shared registers).
Prints "ready" once the port is open; serves until killed.
"""
import asyncio
import struct
import sys
import time

from pymodbus.server import ModbusSerialServer
from pymodbus.simulator import DataType, SimData, SimDevice

BLOCK_PERIOD_S = 0.1
BLOCK_SAMPLES = 20
BLOCK_REGISTERS = 122
SPEED_REGISTER = 200


def block(k: int) -> list[int]:
    """The registers of block k: sequence, count, samples (as u16 words)."""
    samples = [((BLOCK_SAMPLES * k + i) % 2000) - 1000 for i in range(BLOCK_SAMPLES)]
    words = [k % 65536, BLOCK_SAMPLES] + [s & 0xFFFF for s in samples]
    return words + [0] * (BLOCK_REGISTERS - len(words))


async def main(device: str, baud: int, stop_bits: int, unit: int, epoch: float, firehose: bool) -> None:
    speed = list(struct.unpack(">HH", struct.pack(">f", 12.5)))
    reads = 0

    async def current_block(_function, start, address, _count, registers, _set_values):
        """Before each access: the block of this moment into registers 0..121."""
        nonlocal reads
        if firehose:
            reads += address == 0
            k = reads
        else:
            k = int((time.time() - epoch) / BLOCK_PERIOD_S)
        registers[0 - start : BLOCK_REGISTERS - start] = block(k)

    registers = [0] * SPEED_REGISTER + speed + [4242]
    device_model = SimDevice(
        unit,
        simdata=[SimData(0, values=registers, datatype=DataType.REGISTERS)],
        action=current_block,
    )
    opened = asyncio.Event()
    server = ModbusSerialServer(
        device_model,
        port=device,
        baudrate=baud,
        bytesize=8,
        parity="N",
        stopbits=stop_bits,
        trace_connect=lambda connected: opened.set() if connected else None,
    )
    serving = asyncio.create_task(server.serve_forever())
    await asyncio.wait_for(opened.wait(), 10)
    print("ready", flush=True)
    await serving


if __name__ == "__main__":
    device, baud, stop_bits, unit, epoch = sys.argv[1:6]
    firehose = sys.argv[6:7] == ["firehose"]
    asyncio.run(main(device, int(baud), int(stop_bits), int(unit), float(epoch), firehose))
