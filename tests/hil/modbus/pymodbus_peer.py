#!/usr/bin/python3
"""Independent Modbus peer for the HIL tests: pymodbus' own server (TCP or RTU).

Usage: pymodbus_peer.py tcp [PORT] [INIT] [DUMP]   prints "PORT <n>" once listening on 127.0.0.1
       pymodbus_peer.py rtu DEVICE [INIT] [DUMP]   prints "READY" once the serial device is open
INIT: table=address:value,... with table one of co, di, hr, ir, e.g. "ir=0:7,1:65535;hr=10:3".
DUMP: a file; on SIGUSR1 the peer writes its holding registers there ("hr v0,v1,...", atomically
by rename), so a test can see what an RTU client wrote without a second master on the line.
The tests write holding registers over Modbus (with their own client) to drive events.
Runs until killed.
"""
import asyncio
import os
import signal
import sys

from pymodbus.datastore import (ModbusSequentialDataBlock, ModbusServerContext,
                                ModbusSlaveContext)
from pymodbus.server.async_io import StartAsyncSerialServer, StartAsyncTcpServer
from pymodbus.transaction import ModbusRtuFramer

SIZE = 1024


def make_context(init):
    blocks = {name: [0] * SIZE for name in ("co", "di", "hr", "ir")}
    for part in filter(None, init.split(";")):
        table, items = part.split("=", 1)
        for item in filter(None, items.split(",")):
            address, value = item.split(":")
            blocks[table][int(address)] = int(value)
    slave = ModbusSlaveContext(
        co=ModbusSequentialDataBlock(0, blocks["co"]),
        di=ModbusSequentialDataBlock(0, blocks["di"]),
        hr=ModbusSequentialDataBlock(0, blocks["hr"]),
        ir=ModbusSequentialDataBlock(0, blocks["ir"]),
        zero_mode=True)
    return ModbusServerContext(slaves=slave, single=True)


def install_dump(context, path):
    def dump():
        values = context[0].getValues(3, 0, count=SIZE)
        tmp = path + ".tmp"
        with open(tmp, "w", encoding="ascii") as f:
            f.write("hr " + ",".join(str(v) for v in values) + "\n")
        os.replace(tmp, path)
    asyncio.get_running_loop().add_signal_handler(signal.SIGUSR1, dump)


async def main():
    mode = sys.argv[1]
    context = make_context(sys.argv[3] if len(sys.argv) > 3 else "")
    if len(sys.argv) > 4:
        install_dump(context, sys.argv[4])
    if mode == "tcp":
        port = int(sys.argv[2]) if len(sys.argv) > 2 else 0
        server = await StartAsyncTcpServer(context=context, address=("127.0.0.1", port),
                                           defer_start=True, allow_reuse_address=True)
        task = asyncio.create_task(server.serve_forever())
        await server.serving
        print("PORT", server.server.sockets[0].getsockname()[1], flush=True)
        await task
    else:
        server = await StartAsyncSerialServer(context=context, framer=ModbusRtuFramer,
                                              port=sys.argv[2], baudrate=115200, bytesize=8,
                                              parity="N", stopbits=1, defer_start=True)
        await server.start()
        print("READY", flush=True)
        await server.serve_forever()


if __name__ == "__main__":
    asyncio.run(main())
