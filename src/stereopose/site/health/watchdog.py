"""The service's long-lived receivers kept running: a thread that every `interval_s` asks each
registered part to start again whatever thread of its own died (`ensure_running()`: the event
outbox's sender and its MQTT client, the nodes' MQTT client).

    dog = Watchdog()
    dog.add("outbox", outbox.ensure_running)
    dog.start()
    ...
    dog.stop()

A callback's error is caught where the message is read; a thread that dies anyway (a bug, a
library's own error) is started again here, and each part's health says so meanwhile. A part
whose ensure_running raises is logged (at most once a minute) and asked again next time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping

__all__ = ["Watchdog"]

logger = logging.getLogger(__name__)

INTERVAL_S = 0.5
WARN_EVERY_S = 60.0


class Watchdog:
    """See the module."""

    def __init__(
        self,
        interval_s: float = INTERVAL_S,
        parts: Mapping[str, Callable[[], object]] | None = None,
    ) -> None:
        """parts: each receiver's name and its ensure_running (more by `add`)."""
        self.interval_s = float(interval_s)
        self._parts: dict[str, Callable[[], object]] = dict(parts or {})
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._warned: dict[str, float] = {}

    def add(self, name: str, ensure_running: Callable[[], object]) -> None:
        self._parts[name] = ensure_running

    def start(self) -> None:
        if self._parts and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="watchdog", daemon=True)
            self._thread.start()

    def check(self) -> None:
        """Each part asked once (the thread's round; callable directly)."""
        for name, ensure in list(self._parts.items()):
            try:
                ensure()
            except Exception:  # one part failing never stops the others' watch
                now = time.monotonic()
                if now - self._warned.get(name, -WARN_EVERY_S) >= WARN_EVERY_S:
                    self._warned[name] = now
                    logger.exception("watchdog: %s cannot be started again", name)

    def _run(self) -> None:
        while not self._stop.wait(self.interval_s):
            self.check()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
