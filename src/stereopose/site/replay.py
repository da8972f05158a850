"""The 3D poses of a past time window, for the console's replay (GET /api/poses): read from
the service's pose segments (io.sinks.segments), thinned to at most `max_frames` frames spread
evenly over the window, each person as its id, joints, floor position and posture.

Only the segments that can hold the window are opened (their names are their first frames'
UTC times), and a line's time is read from its first bytes (`"wall_t"`, which the segments
write after `t`), so the lines outside the window are never parsed; a line of an older segment
without `wall_t` is placed from its segment's name and its `t`. A segment damaged or cut off is
read to its last whole line, a malformed line skipped and counted: the answer says how many.
"""

from __future__ import annotations

import json
import logging
import math
import re
from calendar import timegm
from dataclasses import dataclass, field
from pathlib import Path
from time import strptime

from stereopose.errors import StereoposeError
from stereopose.io.gzlines import DamagedGzipError, GzipLines
from stereopose.io.results import MAX_LINE_BYTES, SEGMENT_SUFFIX

__all__ = ["MAX_FRAMES", "MAX_WINDOW_S", "Window", "read_window"]

logger = logging.getLogger(__name__)

MAX_WINDOW_S = 3 * 3600.0  # the longest window replayed
MAX_FRAMES = 3000  # the most frames one answer holds
_STEM = re.compile(r"(\d{8}-\d{6})(?:_\d{3})?$")
_HEAD = re.compile(rb'^\{"frame":(-?\d+),"t":([-0-9.eE+]+),"wall_t":([0-9.eE+]+)')
_T = re.compile(rb'"t":([-0-9.eE+]+)')


@dataclass
class Window:
    """The answer: frames [{"wall_t", "t", "people": [{"id", "joints", "position",
    "posture"}]}] in time order; skipped: malformed lines; thinned: whether frames were left
    out to keep to max_frames."""

    since: float
    until: float
    frames: list[dict] = field(default_factory=list)
    skipped: int = 0
    thinned: bool = False

    def as_dict(self) -> dict:
        return {
            "since": self.since,
            "until": self.until,
            "frames": self.frames,
            "skipped": self.skipped,
            "thinned": self.thinned,
        }


def _start(path: Path) -> float | None:
    """A segment's first frame's Unix time from its name, or None (not a segment's name)."""
    m = _STEM.fullmatch(path.name[: -len(SEGMENT_SUFFIX)])
    if m is None:
        return None
    try:
        return float(timegm(strptime(m.group(1), "%Y%m%d-%H%M%S")))
    except ValueError:
        return None


def _segments(folder: Path, since: float, until: float) -> list[Path]:
    """The segments that can hold frames of [since, until], in time order."""
    try:
        found = [
            (s, p)
            for p in folder.iterdir()
            if p.name.endswith(SEGMENT_SUFFIX)
            for s in [_start(p)]
            if s is not None
        ]
    except FileNotFoundError:
        return []
    except OSError as e:
        raise StereoposeError(f"cannot read the 3D poses: {e.strerror}") from None
    found.sort()
    out = []
    for i, (start, path) in enumerate(found):
        # a segment ends where the next begins (its name is whole seconds: one second's slack)
        end = found[i + 1][0] + 1.0 if i + 1 < len(found) else math.inf
        if start <= until and end >= since:
            out.append(path)
    return out


def _person(p: dict) -> dict:
    return {
        "id": p.get("id"),
        "joints": p.get("joints"),
        "position": p.get("position"),
        "posture": p.get("posture"),
    }


def read_window(folder: str | Path, since: float, until: float, max_frames: int = 600) -> Window:
    """The frames of [since, until] (Unix seconds) in the segments of `folder` (see the
    module); a window longer than MAX_WINDOW_S or reversed is a ValueError."""
    if not (math.isfinite(since) and math.isfinite(until)) or until < since:
        raise ValueError("the window's end must not be before its start")
    if until - since > MAX_WINDOW_S:
        raise ValueError(f"a window of at most {MAX_WINDOW_S / 3600:g} h is replayed")
    max_frames = max(1, min(int(max_frames), MAX_FRAMES))
    w = Window(since, until)
    step = (until - since) / max_frames
    next_kept = since
    for path in _segments(Path(folder), since, until):
        start = _start(path)
        first_t: float | None = None
        try:
            f = path.open("rb")
        except OSError as e:
            logger.warning("%s: cannot read 3D poses: %s", path, e.strerror)
            continue
        with f:
            lines = GzipLines(f, str(path))
            while True:
                try:
                    raw = lines.readline(MAX_LINE_BYTES + 1)
                except DamagedGzipError as e:
                    logger.warning("%s: %s; the rest skipped", path, e)
                    w.skipped += 1
                    break
                if not raw:
                    break
                wall = _wall(raw, start, first_t)
                if wall is None:
                    w.skipped += 1
                    continue
                if first_t is None:
                    first_t = wall[1]
                at = wall[0]
                if at > until:
                    break
                if at < since or at < next_kept:
                    if at >= since:
                        w.thinned = True
                    continue
                frame = _frame(raw, at)
                if frame is None:
                    w.skipped += 1
                    continue
                w.frames.append(frame)
                next_kept = at + step if len(w.frames) < max_frames else math.inf
    return w


def _wall(raw: bytes, start: float | None, first_t: float | None) -> tuple[float, float] | None:
    """(the line's Unix time, its t) from its first bytes, or None when it has neither."""
    head = raw[:200]
    m = _HEAD.match(head)
    try:
        if m is not None:
            wall, t = float(m.group(3)), float(m.group(2))
        else:  # an older segment's line: its time from the segment's name
            mt = _T.search(head)
            if mt is None or start is None:
                return None
            t = float(mt.group(1))
            wall = start + (t - (first_t if first_t is not None else t))
    except ValueError:
        return None
    return (wall, t) if math.isfinite(wall) and math.isfinite(t) else None


def _frame(raw: bytes, wall: float) -> dict | None:
    try:
        rec = json.loads(raw)
        people = rec["people"]
        if not isinstance(people, list):
            return None
        return {
            "wall_t": round(wall, 3),
            "t": rec.get("t"),
            "people": [_person(p) for p in people if isinstance(p, dict)],
        }
    except (ValueError, KeyError, TypeError, RecursionError):
        return None
