"""A zone's breakers and earthing switches read from the utility over OPC UA: an asyncua client
per endpoint, on a thread with its own event loop, subscribing to its nodes' data changes and
reading them every `interrogation_s`, onto a PowerBoard (zones.power_state). A failure or a bad
status makes the points unknown and the client connects again after 1, 2, 4 ... 30 s. A password
comes from `password_file` (its first line), never from the site file, and is never logged.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import MutableMapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereopose.errors import ConfigError
from stereopose.secrets import redact
from stereopose.zones.power import OpcuaPoint, reading
from stereopose.zones.power_state import PowerBoard

if TYPE_CHECKING:
    from asyncua import ua
    from asyncua.common.node import Node
    from asyncua.common.subscription import DataChangeNotif

__all__ = ["OpcuaWatcher"]

logger = logging.getLogger(__name__)

BACKOFF_S = (1.0, 2.0, 4.0, 8.0, 15.0, 30.0)


def _password(p: OpcuaPoint, base: Path | None) -> str | None:
    name = p.password_file
    if name is None:
        return None
    path = Path(name) if base is None or Path(name).is_absolute() else base / name
    try:
        return path.read_text(encoding="utf-8").splitlines()[0].strip()
    except (OSError, UnicodeDecodeError, IndexError) as e:
        raise ConfigError(f"{path}: cannot read the OPC UA password: {type(e).__name__}") from None


class OpcuaWatcher:
    """An asyncua client of one endpoint, on a thread with its own event loop."""

    def __init__(
        self,
        endpoint: str,
        points: list[OpcuaPoint],
        board: PowerBoard,
        figures: MutableMapping[str, int],
        base: Path | None,
    ) -> None:
        self.endpoint, self.points, self.board, self.figures = endpoint, points, board, figures
        self.keys = [p.label for p in points]
        self.user = next((p.username for p in points if p.username), None)
        self.password = next((_password(p, base) for p in points if p.password_file), None)
        self.interrogation_s = min(p.interrogation_s for p in points)
        self._loop = asyncio.new_event_loop()
        self._stopping: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._run, name="zone-state-opcua", daemon=True)

    def __repr__(self) -> str:
        return f"OPC UA client of {redact(self.endpoint)}"

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        if self._stopping is not None:
            self._loop.call_soon_threadsafe(self._stopping.set)
        self._thread.join(timeout=10.0)

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        self._loop.run_until_complete(self._main())

    async def _main(self) -> None:
        self._stopping = asyncio.Event()
        attempt = 0
        while not self._stopping.is_set():
            try:
                await self._session()
                attempt = 0
            except Exception as e:  # any failure: unknown, then connect again
                self.figures["opcua_link_lost"] += 1
                where = redact(self.endpoint)
                self.board.lost(self.keys, f"OPC UA {where}: {type(e).__name__}")
                logger.info("zone state: OPC UA %s: %s; connecting again", where, e)
            wait = BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)]
            attempt += 1
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), wait)

    async def _session(self) -> None:
        from asyncua.client.client import Client

        stopping = self._stopping
        assert stopping is not None  # made by the running loop
        client = Client(self.endpoint, timeout=5)
        if self.user:
            client.set_user(self.user)
        if self.password:
            client.set_password(self.password)
        async with client:
            nodes = {p.label: client.get_node(p.node_id) for p in self.points}
            handler = _Changes(self)
            sub = await client.create_subscription(200, handler)
            handler.labels = {n.nodeid: label for label, n in nodes.items()}
            await sub.subscribe_data_change(list(nodes.values()))
            while not stopping.is_set():
                for label, node in nodes.items():
                    dv = await node.read_data_value()
                    self._take(label, dv.Value.Value if dv.Value else None, dv.StatusCode)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stopping.wait(), self.interrogation_s)

    def _take(self, label: str, value: object, status: Any) -> None:
        good = status is None or bool(getattr(status, "is_good", lambda: True)())
        if value is None:
            self.board.set(label, None, False, "no value")
        else:
            self.board.set(label, reading(value), good, "" if good else f"status {status}")
        self.figures["opcua_received"] += 1


class _Changes:
    def __init__(self, watcher: OpcuaWatcher) -> None:
        self.watcher = watcher
        self.labels: dict[Any, str] = {}

    def datachange_notification(self, node: Node, val: object, data: DataChangeNotif) -> None:
        label = self.labels.get(node.nodeid)
        if label is None:
            self.watcher.figures["opcua_refused"] += 1
            return
        status = getattr(getattr(data, "monitored_item", None), "Value", None)
        self.watcher._take(label, val, getattr(status, "StatusCode", None))

    def status_change_notification(self, status: ua.StatusChangeNotification) -> None:
        where = redact(self.watcher.endpoint)
        self.watcher.board.lost(self.watcher.keys, f"OPC UA {where}: {status}")
