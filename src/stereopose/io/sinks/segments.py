"""3D poses in time segments for a service that runs for weeks: `poses/<start>.jsonl.gz`.

Each segment holds the lines of poses3d.jsonl (io.records.frame_record, the same contract, plus
each frame's Unix time `wall_t` after its `t`) for `segment_s` seconds, gzip-compressed, and is
named from the UTC wall time of its first frame (`20240501-130000.jsonl.gz`; `_001`, `_002`, ...
after it when that name is taken: a file is never overwritten). A frame's wall time is
`wall_start + frame.t`: `wall_start` is the Unix time at which the source's clock read 0 (for
live cameras, io.video's `clock.start_epoch`). Segments begin at whole multiples of `segment_s`
of wall time (on the hour by default), so the maintainer (site.storage) can drop them by age.

Lines are kept in memory for at most `segment_flush_s` of frame time (and 1 MiB), then
appended as one complete gzip member: a writer killed at any moment leaves a file that
io.results.read_poses reads to its last flushed frame (or, cut inside a member, to its last
complete line). A flush that fails (disk full, folder gone) is logged once per spell, its
frames counted in `frames_lost`, and the file cut back to its last whole member; later frames
are tried again, so the output comes back when space does.
"""

from __future__ import annotations

import gzip
import json
import logging
import math
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from stereopose.checks import DAY_S
from stereopose.errors import StereoposeError
from stereopose.io.datafolder import POSES_DIR
from stereopose.io.records import frame_record
from stereopose.io.results import SEGMENT_SUFFIX
from stereopose.io.settings import check_settings, ranged
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.writing import make_folder, probe_folder, reason

__all__ = ["SEGMENT_SUFFIX", "SegmentSettings", "SegmentSink", "segment_stem"]

logger = logging.getLogger(__name__)

_STAMP = "%Y%m%d-%H%M%S"
_MAX_BUFFER_BYTES = 2**20
_MAX_TWINS = 999  # names tried after a taken one


@dataclass(frozen=True, kw_only=True)
class SegmentSettings:
    """segment_s: seconds of frames per segment; segment_flush_s: the longest a frame waits in
    memory before it is on disk (what a crash can lose). Keys of the `[storage]` section."""

    segment_s: float = ranged(3600.0, ge=1.0, le=DAY_S)
    segment_flush_s: float = ranged(1.0, gt=0.0, le=60.0)

    def __post_init__(self) -> None:
        check_settings(self, "storage")


def segment_stem(wall_t: float) -> str:
    """A segment's name without suffix, from the Unix time of its first frame (UTC)."""
    return datetime.fromtimestamp(wall_t, UTC).strftime(_STAMP)


class SegmentSink(ClosesOnce):
    """The 3D poses as gzip JSON-lines segments in `<out_dir>/poses/` (see the module).

    fps: the poses' frame rate (frame_record's t where frames carry no time); wall_start: the
    Unix time of t = 0. `frames` counts the frames on disk, `frames_lost` those a failed flush
    lost (`last_error`: why); `incomplete` says so at close.
    """

    stage = "write"

    def __init__(
        self,
        out_dir: str | Path,
        fps: float,
        *,
        wall_start: float,
        settings: SegmentSettings | None = None,
    ) -> None:
        if isinstance(wall_start, bool) or not isinstance(wall_start, (int, float)):
            raise StereoposeError(f"segments: wall_start must be a Unix time, got {wall_start!r}")
        if not math.isfinite(wall_start) or not 0 <= wall_start < 2**33:
            raise StereoposeError(f"segments: wall_start must be a Unix time, got {wall_start!r}")
        self.settings = settings or SegmentSettings()
        self.folder = Path(out_dir) / POSES_DIR
        probe_folder(self.folder, "3D poses segments")
        self.fps, self.wall_start = float(fps), float(wall_start)
        self.frames = self.frames_lost = 0
        self.incomplete: str | None = None
        self.path: Path | None = None  # the segment being written
        self.written: list[Path] = []
        self._f = None
        self._good = 0  # bytes of the open file that end with a whole member
        self._slot: int | None = None  # which segment_s-long slot of wall time is open
        self._buf = bytearray()
        self._buffered = 0
        self._buf_wall: float | None = None  # wall time of the first buffered frame
        self._flush_t = -math.inf
        self._t = 0.0  # the last frame's time
        self._flushed_at = time.monotonic()
        self._error: str | None = None  # why the current spell of failures began
        self.last_error: str | None = None

    def write(self, frame: FrameResult) -> None:
        t = float(frame.t) if math.isfinite(frame.t) else self._t  # a bad time: the last one
        wall = self.wall_start + t
        slot = math.floor(wall / self.settings.segment_s)
        if self._slot is not None and slot != self._slot:
            self._flush()
            self._end_segment()
        self._slot = slot
        if self._buf_wall is None:
            self._buf_wall = wall
            self._flush_t = t + self.settings.segment_flush_s
        rec = frame_record(frame.people3d, self.fps, frame.postures)
        # the frame's Unix time after its t, near the line's start: the replay (site.replay)
        # finds a time window without parsing the lines before it
        record = {"frame": rec["frame"], "t": rec["t"], "wall_t": round(wall, 3), **rec}
        self._buf += (json.dumps(record, separators=(",", ":")) + "\n").encode()
        self._buffered += 1
        self._t = t
        waited = time.monotonic() - self._flushed_at
        full = len(self._buf) >= _MAX_BUFFER_BYTES
        if full or t >= self._flush_t or waited >= self.settings.segment_flush_s:
            self._flush()

    def flush(self) -> None:
        """Put the frames held in memory on disk now (as one gzip member)."""
        self._flush()

    def _flush(self) -> None:
        self._flushed_at = time.monotonic()
        if not self._buffered:
            return
        data = gzip.compress(bytes(self._buf), compresslevel=6, mtime=0)
        n, wall = self._buffered, self._buf_wall
        self._buf.clear()
        self._buffered, self._buf_wall = 0, None
        try:
            if self._f is None:
                self._open(wall if wall is not None else self.wall_start)
            self._append(data)
        except OSError as e:
            self._lost(n, e)
            return
        self.frames += n
        if self._error is not None:
            logger.warning(
                "%s: 3D poses written again (%d frame(s) lost)", self.path, self.frames_lost
            )
            self._error = None

    def _open(self, wall: float) -> None:
        make_folder(self.folder)
        stem = segment_stem(wall)
        for n in range(_MAX_TWINS + 1):
            path = self.folder / (f"{stem}_{n:03d}" if n else stem)
            path = path.with_name(path.name + SEGMENT_SUFFIX)
            try:
                self._f = path.open("xb", buffering=0)
            except FileExistsError:
                continue
            self.path, self._good = path, 0
            self.written.append(path)
            return
        raise FileExistsError(f"{self.folder}: every name for {stem} is taken")

    def _append(self, data: bytes) -> None:
        """Append one member; on failure cut the file back to its last whole member."""
        f = self._f
        assert f is not None  # a member goes into the open file
        view = memoryview(data)
        try:
            while view:
                view = view[f.write(view) :]
        except OSError:
            try:
                f.truncate(self._good)
                f.seek(self._good)
            except OSError:  # cannot even cut it back: start another file next time
                self._drop_file()
            raise
        self._good += len(data)

    def _lost(self, n: int, e: OSError) -> None:
        self.frames_lost += n
        if self._error is None:
            logger.error(
                "%s: cannot write 3D poses (%s); %d frame(s) lost, later frames tried again",
                self.path or self.folder,
                reason(e),
                n,
            )
        self._error = self.last_error = reason(e)

    def _drop_file(self) -> None:
        f, self._f = self._f, None
        if f is not None:
            try:
                f.close()
            except OSError as e:
                logger.debug("%s: closing: %s", self.path, e)

    def _end_segment(self) -> None:
        self._drop_file()
        self._slot = None

    def _close(self) -> list[Path]:
        self._flush()
        self._end_segment()
        if self.frames_lost:
            self.incomplete = f"{self.frames_lost} frame(s) of 3D poses lost ({self.last_error})"
        return [p for p in self.written if p.exists()]
