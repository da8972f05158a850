"""3D poses as JSON lines (the contract of ARCHITECTURE.md), written frame by frame.

One line per frame, frames with nobody included:
{"frame": 42, "t": 1.68, "people": [{"id": 3, "joints": [[x, y, z] or null, ...17],
 "conf": [...17], "position": [x, y], "velocity": [vx, vy], "speed": 0.8, "heading_deg": 91.5,
 "predicted": false, "views": [...17], "reprojection_px": 2.1}]}
Coordinates in metres, world frame; `position` is the mid-hip point on the floor; `velocity`
(m/s) and `speed` come from tracking (null without it); `heading_deg` is the direction the body
faces, counter-clockwise from world +x; `predicted` is true for a tracked person not seen in
this frame, whose pose is predicted from the frames before.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import numpy as np

from stereopose.errors import StereoposeError
from stereopose.skeleton import NUM_JOINTS
from stereopose.tracking.positioning import floor_position, heading_deg
from stereopose.types import People3D

__all__ = ["PosesWriter", "floor_position", "frame_record", "load_people3d", "read_poses"]


def _round(x: float, nd: int) -> float | None:
    return None if not math.isfinite(x) else round(float(x), nd)


def _pair(v: np.ndarray, nd: int) -> list[float] | None:
    return [round(float(v[0]), nd), round(float(v[1]), nd)] if np.isfinite(v).all() else None


def frame_record(people: People3D, fps: float) -> dict:
    """The JSON object of one frame."""
    pos = floor_position(people.joints)
    heading = heading_deg(people.joints)
    speed = np.hypot(people.velocity[:, 0], people.velocity[:, 1])
    out = []
    for p in range(len(people)):
        J = people.joints[p]
        ok = np.isfinite(J).all(-1)
        out.append(
            {
                "id": int(people.ids[p]),
                "joints": [
                    [round(float(v), 4) for v in J[j]] if ok[j] else None for j in range(NUM_JOINTS)
                ],
                "conf": [round(float(c), 3) for c in people.conf[p]],
                "position": _pair(pos[p], 4),
                "velocity": _pair(people.velocity[p], 3),
                "speed": _round(speed[p], 3),
                "heading_deg": _round(heading[p], 1),
                "predicted": bool(people.predicted[p]),
                "views": [int(v) for v in people.views[p]],
                "reprojection_px": _round(
                    float(np.nanmean(people.reprojection_px[p]))
                    if np.isfinite(people.reprojection_px[p]).any()
                    else math.nan,
                    2,
                ),
            }
        )
    return {"frame": people.frame, "t": round(people.frame / fps, 6), "people": out}


class PosesWriter:
    """Appends one JSON line per frame and flushes it, so a crash keeps every frame written."""

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f: IO[str] = self.path.open("w", encoding="utf-8")
        except OSError as e:
            raise StereoposeError(f"{self.path}: cannot write 3D poses: {e.strerror}") from None
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
                rec = json.loads(line)
                frame = int(rec["frame"])
                people = rec["people"]
                for p in people:
                    p["joints_array"] = np.array(
                        [j if j is not None else [np.nan] * 3 for j in p["joints"]], dtype=float
                    ).reshape(NUM_JOINTS, 3)
            except (ValueError, KeyError, TypeError) as e:
                raise StereoposeError(f"{path}:{lineno}: malformed 3D poses line: {e}") from None
            yield frame, rec.get("t"), people


def load_people3d(path: str | Path, num_cameras: int = 0) -> list[People3D]:
    """Read a 3D poses file back as People3D per frame (views and errors are not stored)."""
    frames = []
    for frame, _t, people in read_poses(path):
        P = len(people)
        joints = np.array([p["joints_array"] for p in people]).reshape(P, NUM_JOINTS, 3)
        conf = np.array(
            [p.get("conf") or np.isfinite(p["joints_array"]).all(-1) for p in people], float
        ).reshape(P, NUM_JOINTS)
        frames.append(
            People3D(
                frame=frame,
                joints=joints,
                conf=conf,
                ids=np.array([p["id"] for p in people], dtype=np.int64),
                reprojection_px=np.full((P, NUM_JOINTS), np.nan),
                views=np.zeros((P, NUM_JOINTS), dtype=np.int64),
                detections=np.full((P, num_cameras), -1, dtype=np.int64),
                predicted=np.array([bool(p.get("predicted", False)) for p in people]),
                velocity=np.array(
                    [p.get("velocity") or [np.nan, np.nan] for p in people], dtype=float
                ).reshape(P, 2),
            )
        )
    return frames
