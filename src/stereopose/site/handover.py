"""How a standing part of the service reaches one that the frame loop makes later.

The HTTP API, the OPC UA server and the IEC 104 outstation are made and listening before the
cameras open; the incident step, the calibration keeper and the warnings on site are made once
they are (they need the cameras' clock, rate and steps). Each standing part is given a
`Handover` when it is made, never the later part. The keeper and the warnings on site are
attached as they start and detached as they close (site.run_parts); the incident step is
attached once the loop's incident book runs and stays until the service closes. Until a part
is attached the handover says there is none (`current` is None), so the API answers 503
rather than failing.
"""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

__all__ = ["Handover"]

T = TypeVar("T")


class Handover(Generic[T]):
    """See the module: one later part at a time (attaching another replaces it)."""

    def __init__(self) -> None:
        self._part: T | None = None
        self._lock = threading.Lock()

    def attach(self, part: T) -> None:
        with self._lock:
            self._part = part

    def detach(self) -> None:
        with self._lock:
            self._part = None

    @property
    def current(self) -> T | None:
        """The part attached now (None: not yet made, or closed)."""
        with self._lock:
            return self._part
