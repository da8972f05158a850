"""3D poses as JSON lines (the contract in docs/formats.md), written frame by frame.

One line per frame, frames with nobody included; the record is built and parsed in
`io.records` (see its docstring for the fields and their precision).
"""

from __future__ import annotations

import json
import logging
import math
import os
import stat
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, Any

from stereopose.errors import StereoposeError
from stereopose.io.gzlines import DamagedGzipError, GzipLines
from stereopose.io.records import frame_record, parse_frame_record, people3d_from_record
from stereopose.io.writing import open_output
from stereopose.skeleton import NUM_JOINTS, floor_position
from stereopose.types import People3D

logger = logging.getLogger(__name__)

__all__ = ["PosesWriter", "floor_position", "frame_record", "load_people3d", "read_poses"]


class PosesWriter:
    """Appends one JSON line per frame and flushes it, so a crash keeps every frame written."""

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self._f: IO[str] = open_output(self.path, "3D poses")
        self.frames = 0

    def write(self, people: People3D, postures: Mapping[int, Any] | None = None) -> None:
        """One frame; postures: person id -> posture (see io.records.frame_record)."""
        record = frame_record(people, self.fps, postures)
        self._f.write(json.dumps(record, separators=(",", ":")) + "\n")
        self._f.flush()
        self.frames += 1

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> PosesWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


SEGMENT_SUFFIX = ".jsonl.gz"  # a 3D poses segment (io.sinks.segments)
# A line holds one frame: 100 people take about 0.2 MB; a line far longer is not poses.
MAX_LINE_BYTES = 64 * 2**20
_MAX_INT64 = 2**63 - 1
# optional per-person fields the readers turn into arrays: (key, length, null allowed inside)
_OPTIONAL = (
    ("position", 2, False),
    ("velocity", 2, True),
    ("conf", NUM_JOINTS, False),
    ("views", NUM_JOINTS, False),
)
_MAX_VALUE = 1e15  # beyond any coordinate, speed or count; within 64-bit integers


def read_poses(
    path: str | Path, *, skipped: list[tuple[int, str]] | None = None
) -> Iterator[tuple[int, float | None, list[dict]]]:
    """Yield (frame, t, people) from a 3D poses JSONL file; people keep their JSON fields and
    gain `joints_array` (17, 3) with NaN for null.

    A `.gz` file (a segment, io.sinks.segments) is read through its gzip members, to its last
    complete line when its writer was cut off; a folder is read as its segments in name (time)
    order. A malformed line raises StereoposeError naming the file and the line; given
    `skipped` (a list), such a line is skipped instead, with a warning, and its (line number,
    problem) appended. Whatever the file holds, nothing else is raised."""
    path = Path(path)
    if path.is_dir():
        for part in _segments(path):
            yield from read_poses(part, skipped=skipped)
        return
    with _open_regular(path) as f:
        lineno = 0
        while True:
            try:
                raw = f.readline(MAX_LINE_BYTES + 1)
            except DamagedGzipError as e:  # nothing after it can be read
                if skipped is None:
                    raise StereoposeError(f"{path}:{lineno + 1}: {e}") from None
                logger.warning("%s:%d: %s; the rest skipped", path, lineno + 1, e)
                skipped.append((lineno + 1, str(e)))
                return
            if not raw:
                return
            lineno += 1
            try:
                parsed = _parse_line(raw, f)
            except ValueError as e:
                if skipped is None:
                    raise StereoposeError(
                        f"{path}:{lineno}: malformed 3D poses line: {e}"
                    ) from None
                logger.warning("%s:%d: malformed 3D poses line skipped: %s", path, lineno, e)
                skipped.append((lineno, str(e)))
                continue
            if parsed is not None:
                yield parsed


def _segments(folder: Path) -> list[Path]:
    """A folder's 3D poses segments in name order (their start times), or StereoposeError."""
    try:
        parts = sorted(p for p in folder.iterdir() if p.name.endswith(SEGMENT_SUFFIX))
    except OSError as e:
        raise StereoposeError(f"{folder}: cannot read 3D poses: {e.strerror}") from None
    if not parts:
        raise StereoposeError(f"{folder}: no 3D poses segments (*{SEGMENT_SUFFIX}) in the folder")
    return parts


def _open_regular(path: Path) -> IO[bytes] | GzipLines:
    """A regular file opened for reading (a named pipe would block), or StereoposeError; a
    `.gz` file as its decompressed lines."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise StereoposeError(f"{path}: cannot read 3D poses: not a regular file")
        f = path.open("rb")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot read 3D poses: {e.strerror}") from None
    return GzipLines(f, str(path)) if path.name.endswith(".gz") else f


def _parse_line(
    raw: bytes, f: IO[bytes] | GzipLines
) -> tuple[int, float | None, list[dict]] | None:
    """One line's frame (None for a blank line); ValueError naming the problem otherwise."""
    if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
        while (rest := f.readline(MAX_LINE_BYTES)) and not rest.endswith(b"\n"):
            pass  # the rest of the overlong line
        raise ValueError(f"longer than {MAX_LINE_BYTES // 2**20} MiB")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"not UTF-8 text: {e.reason} at byte {e.start}") from None
    if not text.strip():
        return None
    try:
        frame, t, people = parse_frame_record(json.loads(text))
    except RecursionError:
        raise ValueError("nested too deeply") from None
    except (KeyError, TypeError, IndexError, OverflowError) as e:
        raise ValueError(f"{type(e).__name__}: {e}") from None
    _check_record(frame, t, people)
    return frame, t, people


def _check_record(frame: int, t: float | None, people: object) -> None:
    """The fields readers use beyond what parse_frame_record checks: ranges and shapes."""
    if not 0 <= frame <= _MAX_INT64:
        raise ValueError(f"frame {frame} is not a frame number")
    if t is not None and not math.isfinite(t):
        raise ValueError(f"t = {t} is not a time")
    if not isinstance(people, list):
        raise ValueError(f"'people' must be a list, got {type(people).__name__}")
    for i, p in enumerate(people):
        if not -_MAX_INT64 <= int(p["id"]) <= _MAX_INT64:
            raise ValueError(f"person {i}: id {p['id']} beyond 64 bits")
        for key, n, none_inside in _OPTIONAL:
            if not _numbers(p.get(key), n, none_inside):
                raise ValueError(f"person {i}: {key} must be null or {n} numbers")


def _numbers(value: object, n: int, none_inside: bool) -> bool:
    """Whether value is None or a list of n numbers within +-_MAX_VALUE (or nulls, with
    none_inside)."""
    if value is None:
        return True
    if not isinstance(value, list) or len(value) != n:
        return False
    for v in value:
        if v is None and none_inside:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return False
        if not -_MAX_VALUE <= v <= _MAX_VALUE:  # NaN compares false
            return False
    return True


def load_people3d(path: str | Path, num_cameras: int = 0) -> list[People3D]:
    """Read a 3D poses file back as People3D per frame (the per-joint reprojection errors and
    the detections used are not stored); a malformed line is a StereoposeError."""
    return [people3d_from_record(f, people, num_cameras) for f, _t, people in read_poses(path)]
