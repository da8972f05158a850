"""Beacons, sirens and relays: the coils of a Modbus TCP IO module (Moxa ioLogik, Advantech
ADAM and alike) or of a networked signal tower, written by pymodbus.

    signal = Signal(spec, on_health=lambda name, up, why: ...)
    signal.want({"beacon", "siren"})    # these coils on, the others off (never blocks)
    signal.want(set())                  # every coil off: the hazard is over

A thread of its own per device writes what is wanted at once (woken by `want`) and every
`refresh_s` again, so that a module that restarted is set again within a second. A device
that does not answer within `timeout_s`, closes, or answers with an exception is down:
`on_health(name, False, why)` once, `on_health(name, True, "")` when it answers again, and it
is tried again every `retry_s`. A closing Signal turns its coils off (best effort).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Collection
from typing import TYPE_CHECKING

from stereopose.onsite.settings import SignalSpec

if TYPE_CHECKING:
    from pymodbus.client import ModbusTcpClient

__all__ = ["Signal"]

logger = logging.getLogger(__name__)

REFRESH_S = 1.0
RETRY_S = 2.0
TIMEOUT_S = 1.0


class Signal:
    """One Modbus TCP device's coils (see the module). on_health(name, up, why): its health
    changed (the device's thread calls it)."""

    def __init__(
        self,
        spec: SignalSpec,
        on_health: Callable[[str, bool, str], None] | None = None,
        refresh_s: float = REFRESH_S,
        retry_s: float = RETRY_S,
        timeout_s: float = TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.spec, self.on_health = spec, on_health
        self.refresh_s, self.retry_s, self.timeout_s = refresh_s, retry_s, timeout_s
        self.clock = clock
        self.coils = dict(spec.coils)
        self._cond = threading.Condition()
        self._wanted: frozenset[str] = frozenset()
        self._changed = True
        self._stopped = False
        self.up: bool | None = None  # None: not tried yet
        self.reason = ""
        self.written: dict[str, bool] = {}  # what the device took last
        self.taken: tuple[frozenset[str], float] | None = None  # the last new wish taken, when
        self.figures = {"writes": 0, "failures": 0, "down": 0}
        self._client = None
        self._thread = threading.Thread(target=self._run, name=f"signal {spec.name}", daemon=True)
        self._thread.start()

    def want(self, on: Collection[str]) -> None:
        """These coils (by name) on, every other off."""
        wish = frozenset(c for c in on if c in self.coils)
        with self._cond:
            if wish != self._wanted:
                self._wanted, self._changed = wish, True
                self._cond.notify()

    def close(self, timeout_s: float = 3.0) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(timeout_s)

    # -- the device's thread ----------------------------------------------------------------

    def _connect(self) -> ModbusTcpClient:
        from pymodbus.client import ModbusTcpClient

        if self._client is None:
            self._client = ModbusTcpClient(
                self.spec.host, port=self.spec.port, timeout=self.timeout_s, retries=0
            )
        if not self._client.connected and not self._client.connect():
            raise ConnectionError(f"no connection to {self.spec.host}:{self.spec.port}")
        return self._client

    def _write(self, wish: frozenset[str]) -> None:
        """Every coil set as `wish` says; an exception or a failed answer raises."""
        client = self._connect()
        for name, address in self.coils.items():
            value = name in wish
            answer = client.write_coil(address, value, device_id=self.spec.unit)
            if answer.isError():
                raise ConnectionError(f"coil {name} ({address}): {answer}")
            self.written[name] = value
        self.figures["writes"] += 1

    def _health(self, up: bool, why: str) -> None:
        if up == self.up:
            return
        was, self.up, self.reason = self.up, up, why
        if not up:
            self.figures["down"] += 1
            logger.warning("signal %s (%s): down: %s", self.spec.name, self.spec.host, why)
        elif was is False:
            logger.info("signal %s (%s): answering again", self.spec.name, self.spec.host)
        if self.on_health is not None and (was is not None or not up):
            try:
                self.on_health(self.spec.name, up, why)
            except Exception:  # the owner's failure must not stop the device's thread
                logger.exception("signal %s: its health could not be told", self.spec.name)

    def _run(self) -> None:
        last = -float("inf")
        while True:
            with self._cond:
                while not self._stopped:
                    wait = (self.refresh_s if self.up else self.retry_s) - (self.clock() - last)
                    if self._changed or wait <= 0:
                        break
                    self._cond.wait(wait)
                stopped = self._stopped
                wish = frozenset() if stopped else self._wanted
                self._changed = False
            last = self.clock()
            try:
                self._write(wish)
                if self.taken is None or self.taken[0] != wish:
                    self.taken = (wish, self.clock())
                self._health(True, "")
            except Exception as e:  # pymodbus raises its own and OSError alike
                self.figures["failures"] += 1
                self._drop()
                self._health(False, _why(e))
            if stopped:
                self._drop()
                return

    def _drop(self) -> None:
        if self._client is not None:
            try:
                self._client.close()
            except Exception:
                logger.debug("signal %s: close failed", self.spec.name, exc_info=True)
            self._client = None


def _why(e: BaseException) -> str:
    text = str(e).strip() or type(e).__name__
    return text[:200]
