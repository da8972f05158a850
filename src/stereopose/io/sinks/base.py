"""The one interface of every output: ``write(frame)`` once per frame, ``close()`` once."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from stereopose.io.writing import OUTPUT_FAILURES, reason
from stereopose.types import Event, People2D, People3D

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class FrameResult:
    """One frame through the loop, as every sink gets it.

    t: seconds on the source's clock (frame / fps for recorded input; since the start for live
    cameras). people2d: camera name -> that camera's 2D people (the cameras with an image or a
    keypoint file at this frame). events: the zone events raised at this frame. images: camera
    name -> its frame (H, W, 3) BGR at the calibration's size, or None; None for keypoint input.
    postures: person id -> posture (behaviour.posture.Posture: `posture`, `flags`) when the
    site has behaviour rules, else None.
    """

    frame: int
    t: float
    people2d: Mapping[str, People2D]
    people3d: People3D
    events: Sequence[Event] = ()
    images: Mapping[str, np.ndarray | None] | None = None
    postures: Mapping[int, Any] | None = None


class Sink(Protocol):
    """An output of the frame loop.

    stage: the summary's stage its time counts in ("write", or "overlays" for the videos).
    write: called once per frame, in frame order, also for frames with nobody.
    close: flushes and closes, once (later calls do nothing and return []); returns the files
    written. The loop closes every sink also after an error or Ctrl-C, so what a sink has
    written must stay readable at any moment.

    A sink that finishes with part of its output not written (events not delivered or not
    stored) says so in an `incomplete` attribute (a message; None or absent: complete).
    """

    @property
    def stage(self) -> str: ...

    def write(self, frame: FrameResult) -> None: ...

    def close(self) -> list[Path]: ...


class ClosesOnce:
    """A sink's `close` as the interface wants it: the first call closes (`_close`, which
    returns the files written), later calls do nothing and return []."""

    _closed = False

    def close(self) -> list[Path]:
        if self._closed:
            return []
        self._closed = True
        return self._close()

    def _close(self) -> list[Path]:
        raise NotImplementedError


def unwrapped(sink: Sink) -> Sink:
    """The output itself, also behind its Guarded wrapper."""
    return sink.sink if isinstance(sink, Guarded) else sink


def close_all(sinks: Iterable[Sink]) -> tuple[list[Path], BaseException | None]:
    """Close every sink in order, even when one fails; (files written, the first error)."""
    paths: list[Path] = []
    first: BaseException | None = None
    for sink in sinks:
        try:
            paths.extend(sink.close())
        except BaseException as e:  # close the others all the same
            logger.exception("closing %s failed", type(sink).__name__)
            first = first or e
    return paths, first


class Guarded:
    """A sink whose failures stop that output alone: the run and the other outputs go on.

    The first OSError (disk full, folder gone or read-only), StereoposeError (a writer's own
    message naming its file) or sqlite3.Error of `write` or `close` is logged once, recorded in
    `failures` (label -> reason) and ends the output: its files are closed as they are, later
    frames are not given to it, and its close returns []. A sink that closes `incomplete` is
    recorded the same way. Other errors (a bug) go through. Every other attribute is the
    sink's own.
    """

    def __init__(self, sink: Sink, label: str, failures: MutableMapping[str, str]) -> None:
        self.sink, self.label, self.failures = sink, label, failures
        self.stage = sink.stage
        self.failed = False

    def __getattr__(self, name: str) -> object:
        return getattr(self.__dict__["sink"], name)

    def write(self, frame: FrameResult) -> None:
        if self.failed:
            return
        try:
            self.sink.write(frame)
        except OUTPUT_FAILURES as e:
            self._fail(reason(e))
            self._release()

    def close(self) -> list[Path]:
        try:
            paths = self.sink.close()
        except OUTPUT_FAILURES as e:
            self._fail(reason(e))
            return []
        incomplete = getattr(self.sink, "incomplete", None)  # a message: part not written
        if incomplete and not self.failed:
            self._fail(incomplete)
            return paths  # what it did write stays listed: its file holds the rest
        return [] if self.failed else paths

    def _fail(self, why: str) -> None:
        self.failed = True
        self.failures.setdefault(self.label, why)
        logger.error("%s: output stopped: %s (the other outputs go on)", self.label, why)

    def _release(self) -> None:
        """Close the failed output's files as they are (they may fail again: ignored)."""
        try:
            self.sink.close()
        except Exception as e:  # the failure is already reported
            logger.debug("%s: closing after its failure: %s", self.label, e)
