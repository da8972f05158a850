"""The service's running parts as one ordered, immutable list: each part named, with its own
start and close. `Parts.start()` starts them in their order (the order read in one place, the
builder's list); `Parts.close()` closes those started in the mirror order, the last started
first. A part that fails to start raises, and the caller's `close()` closes those before it; a
part that fails to close is logged and the others still close.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

__all__ = ["Part", "Parts", "nothing", "running"]

logger = logging.getLogger(__name__)


def nothing() -> None:
    """A part's start or close with nothing to do (a part running from when it is made, one
    that leaves nothing open)."""


@dataclass(frozen=True)
class Part:
    """One running part: its name in the logs, its start, its close."""

    name: str
    start: Callable[[], object]
    close: Callable[[], object]


def running(name: str, close: Callable[[], object]) -> Part:
    """A part already running when made: nothing to start, only its close."""
    return Part(name, nothing, close)


class Parts:
    """See the module. `order` is the builder's list; `started` the names started so far."""

    def __init__(self, parts: Sequence[Part]) -> None:
        self.order: tuple[Part, ...] = tuple(parts)
        names = [p.name for p in self.order]
        if len(set(names)) != len(names):
            raise ValueError(f"parts named twice: {names}")
        self._started = 0  # how many of `order` have started
        self._lock = threading.Lock()

    @property
    def started(self) -> list[str]:
        """The names of the parts started and not yet closed, in their order."""
        return [p.name for p in self.order[: self._started]]

    def start(self) -> None:
        """Each part started in its order (once)."""
        with self._lock:
            if self._started:
                raise RuntimeError("the parts were started already")
        for part in self.order:
            part.start()
            with self._lock:
                self._started += 1

    def close(self) -> None:
        """The parts started closed, the last started first (any thread; once)."""
        while True:
            with self._lock:
                if not self._started:
                    return
                self._started -= 1
                part = self.order[self._started]
            try:
                part.close()
            except Exception as e:  # one part never keeps the others open
                logger.warning("closing %s: %s", part.name, e)
