"""systemd's notify protocol for `serve` (sd_notify(3), the documented datagram socket): the
service says READY=1 once its frame loop takes its first step (cameras open, models loaded),
feeds the watchdog (WATCHDOG=1) only while steps advance, and says STOPPING=1 when it closes.

A frame loop that hangs (a native call that never returns, a deadlock) then stops feeding, and
systemd, with `WatchdogSec=` in the unit (packaging/stereopose.service), kills the service and
starts it again instead of leaving the site blind and silent. Without $NOTIFY_SOCKET (not run by
systemd with Type=notify) everything here does nothing.

Native faults are logged with their stack by stereopose.faults (every command turns it on).
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from stereopose.io.sinks.base import ClosesOnce, FrameResult

logger = logging.getLogger(__name__)

FEED_SHARE = 0.5  # the watchdog fed at least this often, as a share of WatchdogSec
STATUS_EVERY_S = 10.0  # STATUS= (shown by systemctl status) at most this often


class Notifier:
    """The notify socket systemd gave this process ($NOTIFY_SOCKET: a path, or "@name" for an
    abstract socket), and its watchdog period ($WATCHDOG_USEC, for this process when
    $WATCHDOG_PID names it). `send` does nothing where there is none."""

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        where = env.get("NOTIFY_SOCKET", "")
        self.address: str | bytes | None = None
        if where.startswith("@"):
            self.address = b"\0" + where[1:].encode()
        elif where.startswith("/"):
            self.address = where
        elif where:
            logger.warning(
                "NOTIFY_SOCKET %r is neither a path nor an abstract name: ignored", where
            )
        self.watchdog_s: float | None = None
        usec, pid = env.get("WATCHDOG_USEC", ""), env.get("WATCHDOG_PID", "")
        if usec and (not pid or pid == str(os.getpid())):
            try:
                self.watchdog_s = int(usec) / 1e6 if int(usec) > 0 else None
            except ValueError:
                logger.warning("WATCHDOG_USEC %r is not a number of microseconds: ignored", usec)
        self.failed = 0  # messages systemd could not be sent

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def send(self, *lines: str) -> bool:
        """One datagram of KEY=value lines; False where it could not go (counted)."""
        if self.address is None:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
                s.connect(self.address)
                s.sendall("\n".join(lines).encode())
            return True
        except OSError as e:
            self.failed += 1
            if self.failed == 1:  # said once: systemd gone means the service goes too
                logger.warning("cannot tell systemd %s: %s", lines[0], e)
            return False


class Watchdog(ClosesOnce):
    """A step output (pipeline.outputs) that tells systemd the service is ready at the first
    step, feeds the watchdog while steps advance (every FEED_SHARE of its period, at most) and
    says it is stopping when the outputs close. `status()` a line for systemctl status."""

    stage = "write"

    def __init__(
        self,
        notifier: Notifier,
        status: Callable[[], str] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.notifier = notifier
        self.status = status
        self.clock = clock
        self.ready = False
        self.fed = 0  # WATCHDOG=1 sent
        self._last_feed = -float("inf")
        self._last_status = -float("inf")

    def write(self, frame: FrameResult) -> None:
        if not self.notifier.enabled:
            return
        now = self.clock()
        lines = []
        if not self.ready:
            lines.append("READY=1")
            self.ready = True
        period = self.notifier.watchdog_s
        if period is not None and now - self._last_feed >= FEED_SHARE * period:
            lines.append("WATCHDOG=1")
            self._last_feed = now
            self.fed += 1
        if now - self._last_status >= STATUS_EVERY_S:
            said = f"step {frame.frame}, {frame.t:.0f} s"
            lines.append(f"STATUS={said}; {self.status()}" if self.status else f"STATUS={said}")
            self._last_status = now
        if lines:
            self.notifier.send(*lines)

    def _close(self) -> list[Path]:
        self.notifier.send("STOPPING=1")
        return []
