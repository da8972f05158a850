"""The alarm outputs as the health state sees them (io.sinks.health): one probe each, and
for how long each has had messages waiting.

An output is a problem while its probe says it is not ok (or fails), and while it has had
messages waiting at every read for BACKLOG_S: it takes them more slowly than they come, or
not at all without saying so. Waiting not known counts as waiting, never as a false ok.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

logger = logging.getLogger(__name__)

BACKLOG_S = 30.0  # an output with messages waiting at every read for this long: degraded
REASON_CHARS = 200  # a probe's reason is cut to this many characters

OutputProbe = Callable[[], "tuple[bool, int, str | None]"]


@dataclass(frozen=True)
class OutputSnapshot:
    """One alarm output: up while it delivers (False also when its probe failed), messages
    waiting (None: not known), why it is down (None while up), and for how long it has had
    messages waiting at every read (0.0: none waiting at the last read)."""

    name: str
    up: bool
    waiting: int | None
    reason: str | None
    backlog_s: float

    @property
    def state(self) -> Literal["up", "down"]:
        return "up" if self.up else "down"

    @property
    def problem(self) -> str | None:
        """Why this output makes the service degraded, or None."""
        waiting = "" if self.waiting is None else f" ({self.waiting} waiting)"
        if not self.up:
            return f"output {self.name} failing: {self.reason}{waiting}"
        if self.backlog_s >= BACKLOG_S:
            return (
                f"output {self.name} falling behind: {self.waiting} waiting for "
                f"{self.backlog_s:.0f} s"
            )
        return None


def _count(value: object) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1 << 63:
        return None
    return value


class OutputWatch:
    """One registered output: its probe, and since when every read saw messages waiting (the
    caller serialises `snapshot`; `probe` may run outside its lock)."""

    def __init__(self, health: OutputProbe) -> None:
        self.health = health
        self.waiting_since: float | None = None

    def probe(self, name: str) -> tuple[bool, int | None, str | None]:
        """(ok, waiting, reason) now; a probe that fails or answers nonsense is down."""
        try:
            ok, waiting, reason = self.health()
        except Exception:  # a probe's failure is reported, never the reader's
            logger.exception("output %s: its health probe failed", name)
            return False, None, "its health is unknown"
        reason = None if reason is None else str(reason)[:REASON_CHARS]
        return ok is True, _count(waiting), reason

    def snapshot(
        self, name: str, ok: bool, waiting: int | None, reason: str | None, now: float
    ) -> OutputSnapshot:
        """The output at `now` from one probe's answer."""
        if waiting is None or waiting > 0:
            if self.waiting_since is None:
                self.waiting_since = now
        else:
            self.waiting_since = None
        backlog = 0.0 if self.waiting_since is None else max(now - self.waiting_since, 0.0)
        return OutputSnapshot(
            name, ok, waiting, None if ok else reason or "not delivering", backlog
        )
