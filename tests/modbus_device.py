"""An IO module for the tests: pymodbus's own Modbus TCP server on 127.0.0.1, its coils read
back as the device holds them; it can be stopped and started again on its port."""

from __future__ import annotations

import asyncio
import socket
import threading

from pymodbus.client import ModbusTcpClient
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.server import ModbusTcpServer


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class IoModule:
    """A Modbus TCP server with `count` coils for unit `unit` (start() / stop())."""

    def __init__(self, unit: int = 1, count: int = 16, port: int | None = None) -> None:
        self.unit, self.count = unit, count
        self.port = port or free_tcp_port()
        device = ModbusDeviceContext(co=ModbusSequentialDataBlock(1, [0] * (count + 1)))
        self.context = ModbusServerContext(devices={unit: device}, single=False)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> IoModule:
        ready = threading.Event()

        def run() -> None:
            loop = asyncio.new_event_loop()
            asyncio.set_event_loop(loop)
            self._loop = loop

            async def serve() -> None:  # the server is made in its running loop
                self._server = ModbusTcpServer(self.context, address=("127.0.0.1", self.port))
                await self._server.serve_forever(background=True)
                ready.set()
                await self._server.serving

            try:
                loop.run_until_complete(serve())
            finally:
                loop.close()

        self._thread = threading.Thread(target=run, name="io module", daemon=True)
        self._thread.start()
        assert ready.wait(10), "the Modbus server did not start"
        return self

    def stop(self) -> None:
        if self._loop is None or self._server is None:
            return
        done = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
        done.result(10)
        self._thread.join(10)
        self._loop = self._server = None

    def coils(self, address: int, count: int = 1) -> list[bool]:
        """The coils as the device holds them, read back by Modbus (a client of its own)."""
        client = ModbusTcpClient("127.0.0.1", port=self.port, timeout=5, retries=0)
        try:
            assert client.connect(), "the IO module does not answer"
            answer = client.read_coils(address, count=count, device_id=self.unit)
            assert not answer.isError(), answer
            return [bool(v) for v in answer.bits[:count]]
        finally:
            client.close()
