"""Reading ahead: an iterator's next items made on a thread of their own while the consumer
works on the current one (a recorded camera set's next steps decoded while the detector runs
on this one: FFmpeg's decoding and the detector's inference both leave Python's lock).

    ahead = ReadAhead(cams, depth=2, name="camera-read-ahead")
    for step in ahead:
        ...
    ahead.close()          # the thread stopped and joined: nothing of it outlives the set

The items come in their order, each once, as the iterator gives them; an error of the
iterator is raised in the consumer at the point it came, after the items before it. At most
`depth` items wait (bounded memory). `close()` ends the thread and joins it; the consumer's
wait for an item is a short poll, so Ctrl-C reaches it.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import Generic, TypeVar, cast

T = TypeVar("T")

_POLL_S = 0.05
_ITEM, _END, _ERROR = range(3)


class ReadAhead(Generic[T]):
    """`items` read on a thread, at most `depth` ahead of the consumer (see the module)."""

    def __init__(self, items: Iterable[T], depth: int = 2, name: str = "read-ahead") -> None:
        if depth < 1:
            raise ValueError(f"read-ahead depth must be at least 1, got {depth!r}")
        self._queue: queue.Queue[tuple[int, object]] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._done = False
        self._thread = threading.Thread(
            target=self._read, args=(iter(items),), name=name, daemon=True
        )
        self._thread.start()

    def _read(self, items: Iterator[T]) -> None:
        try:
            for item in items:
                if not self._put((_ITEM, item)):
                    return
            self._put((_END, None))
        except BaseException as e:  # the consumer raises it, in its place
            self._put((_ERROR, e))

    def _put(self, entry: tuple[int, object]) -> bool:
        """Queue `entry` unless closed first; whether it was queued."""
        while not self._stop.is_set():
            try:
                self._queue.put(entry, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def __iter__(self) -> ReadAhead[T]:
        return self

    def __next__(self) -> T:
        while not self._done:
            try:
                kind, value = self._queue.get(timeout=_POLL_S)
            except queue.Empty:
                if not self._thread.is_alive() and self._queue.empty():
                    self._done = True  # closed while the consumer waited
                continue
            if kind == _ITEM:
                return cast(T, value)  # an item of the iterator read
            self._done = True
            if kind == _ERROR and isinstance(value, BaseException):
                raise value
        raise StopIteration

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop reading and join the thread (an item being read is finished first)."""
        self._stop.set()
        self._done = True
        self._thread.join(timeout_s)

    @property
    def alive(self) -> bool:
        """Whether the reading thread still runs."""
        return self._thread.is_alive()
