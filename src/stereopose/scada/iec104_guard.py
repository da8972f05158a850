"""The outstation's front door: every IEC 104 connection passes through it to c104's server,
which listens on loopback only.

lib60870 (under c104) keeps a connection as long as its socket stays open and answers the
link's tests, and refuses newcomers once `max_connections` are open: two idle sockets could
hold both places of a master and its twin. The guard sees each connection's frames (it only
reads the APCI headers of what the client sends; every byte is passed on as it came) and:

- refuses an address outside `allowed_clients` at once (counted, logged once per address;
  the socket closed half a second later: lib60870's client can crash on a connection closed
  the moment it was accepted);
- closes a connection that has not started data transfer (STARTDT) within `start_within_s`
  of opening (a master starts at once; a socket that does not speak IEC 104, or speaks it and
  never starts, would hold a place);
- gives a newcomer, when every place is taken, the place of the oldest connection that has
  not started data transfer (no STARTDT, or a STOPDT since: idle, or a redundant master
  waiting); when every connection has started, the newcomer is refused (counted).

It runs its own asyncio loop on a thread; `Guard(...).start()` raises OSError when its port
cannot be taken.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ["Guard"]

logger = logging.getLogger(__name__)

START = 0x68  # an APCI's first byte
STARTDT_ACT, STOPDT_ACT = 0x07, 0x13  # U-frames' control fields
CHUNK = 65536
REFUSE_LINGER_S = 0.5  # a refused connection is closed this long after it was accepted
MAX_LINGERING = 64  # refused connections lingering together at most


@dataclass(eq=False)
class _Link:
    """One client's connection: its writer, since when, what it said."""

    writer: asyncio.StreamWriter
    since: float
    started: bool = False  # STARTDT, and no STOPDT since
    buffer: bytearray = field(default_factory=bytearray)
    parsing: bool = True  # False once it sent what is not IEC 104 (passed on, not read)

    def read(self, data: bytes) -> None:
        """Follow the client's frames (APCI: 0x68, length, 4 control bytes, the ASDU)."""
        if not self.parsing:
            return
        self.buffer += data
        while len(self.buffer) >= 2:
            if self.buffer[0] != START:
                self.parsing = False  # lib60870 closes it: nothing more to follow
                self.buffer.clear()
                return
            n = self.buffer[1]
            if len(self.buffer) < n + 2:
                return
            frame, self.buffer = bytes(self.buffer[: n + 2]), self.buffer[n + 2 :]
            if n < 4:
                continue
            control = frame[2]
            if control & 0x01 == 0 or control == STARTDT_ACT:  # an I-frame, or STARTDT
                self.started = True
            elif control == STOPDT_ACT:
                self.started = False


class Guard:
    """See the module. allows(ip): whether an address may connect; refused(ip): told of each
    refused address (the outstation counts and logs)."""

    def __init__(
        self,
        host: str,
        port: int,
        upstream_port: int,
        *,
        max_connections: int,
        start_within_s: float,
        allows: Callable[[str], bool],
        refused: Callable[[str], None],
    ) -> None:
        self.host, self.port, self.upstream_port = host, int(port), int(upstream_port)
        self.max_connections, self.start_within_s = int(max_connections), float(start_within_s)
        self.allows, self.refused = allows, refused
        self.links: set[_Link] = set()
        self.counts = {"evicted": 0, "unstarted_closed": 0, "full": 0}
        self._lingering = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.base_events.Server | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Listening once it returns; OSError when the port cannot be taken."""
        ready = threading.Event()
        error: list[BaseException] = []

        def run() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            try:
                self._server = loop.run_until_complete(
                    asyncio.start_server(self._handle, self.host, self.port, reuse_address=True)
                )
            except BaseException as e:  # reported by start()
                error.append(e)
                ready.set()
                loop.close()
                return
            ready.set()
            try:
                loop.run_forever()
            finally:
                loop.close()

        self._thread = threading.Thread(target=run, name="iec104-guard", daemon=True)
        self._thread.start()
        ready.wait()
        if error:
            raise error[0]

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def connections(self) -> int:
        return len(self.links)

    def started(self) -> int:
        """Connections that have started data transfer (STARTDT, no STOPDT since): these are
        never evicted for a newcomer."""
        return sum(1 for link in list(self.links) if link.started)

    def close(self) -> None:
        loop = self._loop
        if loop is None or not self.running:
            return

        async def stop() -> None:
            if self._server is not None:
                self._server.close()
            for link in list(self.links):
                link.writer.close()
            await asyncio.sleep(0)

        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(stop(), loop).result(5.0)
        loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(5.0)

    # --- the loop's side ------------------------------------------------------------------

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        ip = str(peer[0]) if isinstance(peer, tuple) and peer else "?"
        if not self.allows(ip):
            self.refused(ip)
            await self._refuse(writer)
            return
        if len(self.links) >= self.max_connections and not self._make_room():
            self.counts["full"] += 1
            await self._refuse(writer)
            return
        link = _Link(writer, time.monotonic())
        self.links.add(link)
        try:
            try:
                upstream = await asyncio.open_connection("127.0.0.1", self.upstream_port)
            except OSError as e:
                logger.error("IEC 60870-5-104: the outstation cannot be reached: %s", e)
                return
            up_reader, up_writer = upstream
            pumps = [
                asyncio.create_task(self._pump(reader, up_writer, link)),
                asyncio.create_task(self._pump(up_reader, writer, None)),
                asyncio.create_task(self._watch(link)),
            ]
            try:
                await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for p in pumps:
                    p.cancel()
                up_writer.close()
        finally:
            self.links.discard(link)
            writer.close()

    async def _refuse(self, writer: asyncio.StreamWriter) -> None:
        """Closed after REFUSE_LINGER_S (some masters, lib60870's client among them, can crash
        on a connection closed the moment it was accepted); at once beyond MAX_LINGERING."""
        if self._lingering < MAX_LINGERING:
            self._lingering += 1
            try:
                await asyncio.sleep(REFUSE_LINGER_S)
            finally:
                self._lingering -= 1
        writer.close()

    def _make_room(self) -> bool:
        """The oldest connection that has not started data transfer closed; False when every
        one has."""
        idle = [link for link in self.links if not link.started]
        if not idle:
            return False
        oldest = min(idle, key=lambda link: link.since)
        self.links.discard(oldest)
        oldest.writer.close()
        self.counts["evicted"] += 1
        logger.info(
            "IEC 60870-5-104: a connection that had not started data transfer closed "
            "for a new one (max_connections = %d)",
            self.max_connections,
        )
        return True

    async def _watch(self, link: _Link) -> None:
        """Ends the connection when it has not started data transfer within start_within_s."""
        await asyncio.sleep(self.start_within_s)
        if not link.started:
            self.counts["unstarted_closed"] += 1
            logger.info(
                "IEC 60870-5-104: a connection closed: no STARTDT within %.0f s",
                self.start_within_s,
            )
            return
        await asyncio.Event().wait()  # started: the pumps end it

    @staticmethod
    async def _pump(
        reader: asyncio.StreamReader, writer: asyncio.StreamWriter, link: _Link | None
    ) -> None:
        with contextlib.suppress(OSError, asyncio.IncompleteReadError):
            while True:
                data = await reader.read(CHUNK)
                if not data:
                    return
                if link is not None:
                    link.read(data)
                writer.write(data)
                await writer.drain()
