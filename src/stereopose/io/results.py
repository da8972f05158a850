"""3D poses as JSON lines (the contract of ARCHITECTURE.md), written frame by frame.

One line per frame, frames with nobody included; the record is built and parsed in
`io.records` (see its docstring for the fields and their precision).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from stereopose.errors import StereoposeError
from stereopose.io.records import frame_record, parse_frame_record, people3d_from_record
from stereopose.io.writing import open_output
from stereopose.skeleton import floor_position
from stereopose.types import People3D

__all__ = ["PosesWriter", "floor_position", "frame_record", "load_people3d", "read_poses"]


class PosesWriter:
    """Appends one JSON line per frame and flushes it, so a crash keeps every frame written."""

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self._f: IO[str] = open_output(self.path, "3D poses")
        self.frames = 0

    def write(self, people: People3D) -> None:
        self._f.write(json.dumps(frame_record(people, self.fps), separators=(",", ":")) + "\n")
        self._f.flush()
        self.frames += 1

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> PosesWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_poses(path: str | Path) -> Iterator[tuple[int, float | None, list[dict]]]:
    """Yield (frame, t, people) from a 3D poses JSONL file; people keep their JSON fields and
    gain `joints_array` (17, 3) with NaN for null."""
    path = Path(path)
    try:
        f = path.open(encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot read 3D poses: {e.strerror}") from None
    with f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                parsed = parse_frame_record(json.loads(line))
            except (ValueError, KeyError, TypeError) as e:
                raise StereoposeError(f"{path}:{lineno}: malformed 3D poses line: {e}") from None
            yield parsed


def load_people3d(path: str | Path, num_cameras: int = 0) -> list[People3D]:
    """Read a 3D poses file back as People3D per frame (the per-joint reprojection errors and
    the detections used are not stored)."""
    return [people3d_from_record(f, people, num_cameras) for f, _t, people in read_poses(path)]
