"""Ctrl-C (SIGINT) for a frame loop: stop after the current step, or at once while waiting.

The first Ctrl-C sets the loop's `stop` event, so the step in progress finishes and the loop
ends; when the loop is waiting for its source (a live camera that does not deliver, a stream
being opened) there is no step to finish, and it raises KeyboardInterrupt at once. A second
Ctrl-C always raises KeyboardInterrupt. Either way the loop closes its outputs.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Iterator

logger = logging.getLogger(__name__)


class Interrupt:
    """Installs the SIGINT handler for the time of `installed()` (main thread only: elsewhere
    signal handlers cannot be set, and the caller's own stop event is the way to stop)."""

    def __init__(self, stop: threading.Event) -> None:
        self.stop = stop
        self.waiting = False  # true while the loop waits for its source

    def _handle(self, signum: int, frame: object) -> None:
        if self.stop.is_set() or self.waiting:
            raise KeyboardInterrupt
        logger.warning("interrupted: finishing the current step and closing the outputs")
        self.stop.set()

    @contextlib.contextmanager
    def installed(self) -> Iterator[Interrupt]:
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = signal.signal(signal.SIGINT, self._handle)
        try:
            yield self
        finally:
            signal.signal(signal.SIGINT, previous)

    @contextlib.contextmanager
    def wait(self) -> Iterator[None]:
        """Around a wait for the source: a Ctrl-C during it ends the loop at once."""
        self.waiting = True
        try:
            yield
        finally:
            self.waiting = False
