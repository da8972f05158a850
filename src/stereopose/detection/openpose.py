"""2D keypoints on disk in the OpenPose / Pose2Sim layout.

``<pose_dir>/<camera>_json/<anything>_<frame>_keypoints.json``, one file per camera and frame:
``{"people": [{"pose_keypoints_2d": [x0, y0, c0, ..., x16, y16, c16]}, ...]}`` in COCO-17 order,
pixels of the original image, c = 0 (or null) for a missing joint. Optional per person:
``box_xyxy`` (x1, y1, x2, y2 pixels) and ``score``.
"""

from __future__ import annotations

import json
import logging
import os
import re
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import orjson

from stereopose.errors import KeypointsError
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import People2D

logger = logging.getLogger(__name__)

_INT = re.compile(r"\d+")
_NUM_VALUES = NUM_JOINTS * 3


def frame_number(filename: str) -> int | None:
    """Last integer in the file name's stem (``cam_01_000000000042_keypoints.json`` -> 42)."""
    name = Path(filename).name
    stem = name[: -len(".json")] if name.lower().endswith(".json") else Path(name).stem
    found = _INT.findall(stem)
    return int(found[-1]) if found else None


def find_camera_dirs(pose_dir: str | Path, camera_names: Sequence[str]) -> dict[str, Path]:
    """Keypoint folder of each camera: ``<name>_json``, else ``<name>``; calibration order.

    Cameras without a folder are skipped with a warning; raises KeypointsError if none matches.
    """
    pose_dir = Path(pose_dir)
    if not pose_dir.is_dir():
        raise KeypointsError(f"{pose_dir}: keypoints folder not found")
    found = sorted(p.name for p in pose_dir.iterdir() if p.is_dir())
    dirs: dict[str, Path] = {}
    for name in camera_names:
        for candidate in (f"{name}_json", name):
            if candidate in found:
                dirs[name] = pose_dir / candidate
                break
        else:
            logger.warning(
                "%s: no folder %s_json for camera %r; camera skipped", pose_dir, name, name
            )
    used = {p.name for p in dirs.values()}
    extra = [f for f in found if f not in used]
    if extra:
        logger.info("%s: folders not matching any camera ignored: %s", pose_dir, ", ".join(extra))
    if not dirs:
        raise KeypointsError(
            f"{pose_dir}: no keypoint folder matches a camera; expected "
            f"{', '.join(f'{n}_json' for n in camera_names) or '(no cameras given)'}; "
            f"found {', '.join(found) or 'no folders'}"
        )
    return dirs


# What JSON parsing yields for a number or null (bool is rejected: it is not a number here).
_VALUE_TYPES = frozenset({int, float, type(None)})


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _values(value: object, n: int) -> bool:
    """Whether value is a list of n numbers or nulls (checked in one pass over their types)."""
    return isinstance(value, list) and len(value) == n and _VALUE_TYPES.issuperset(map(type, value))


def _array(rows: list[list], shape: tuple[int, ...]) -> np.ndarray | None:
    """Rows of numbers or nulls (null -> NaN) as one float array, None if a number overflows."""
    try:
        return np.array(rows, dtype=np.float64).reshape(shape)
    except OverflowError:
        return None


def _load(path: Path) -> object:
    """Parsed JSON of a file; errors name the file and the problem."""
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise KeypointsError(f"{path}: cannot read: {e}") from None
    try:
        return orjson.loads(raw)
    except orjson.JSONDecodeError:
        pass
    # The standard parser decides what orjson refused (NaN, Infinity, a byte order mark, bad
    # UTF-8), so such files are read, or rejected, with the same messages as ever.
    try:
        return json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise KeypointsError(f"{path}: cannot read: {e}") from None
    except json.JSONDecodeError as e:
        raise KeypointsError(f"{path}: not valid JSON: {e}") from None


def read_pose_file(path: str | Path, camera: str, frame: int) -> People2D:
    """Read one keypoints file; raises KeypointsError naming the file and the problem.

    A person whose ``pose_keypoints_2d`` has a length other than 51 is skipped with a warning;
    ``null`` values count as missing.
    """
    path = path if isinstance(path, Path) else Path(path)
    doc = _load(path)
    if not isinstance(doc, dict):
        raise KeypointsError(f"{path}: expected a JSON object, got {type(doc).__name__}")
    if "people" not in doc:
        raise KeypointsError(f"{path}: missing key 'people'")
    people = doc["people"]
    if not isinstance(people, list):
        raise KeypointsError(f"{path}: 'people' must be a list, got {type(people).__name__}")
    kps: list[list] = []
    boxes: list[list | None] = []
    scores: list[float | None] = []
    for i, person in enumerate(people):
        if not isinstance(person, dict):
            raise KeypointsError(
                f"{path}: person {i} must be an object, got {type(person).__name__}"
            )
        value = person.get("pose_keypoints_2d")
        if not isinstance(value, list):
            got = "no such key" if "pose_keypoints_2d" not in person else type(value).__name__
            raise KeypointsError(
                f"{path}: person {i}: pose_keypoints_2d must be a list of {_NUM_VALUES} numbers, "
                f"got {got}"
            )
        if len(value) != _NUM_VALUES:
            logger.warning(
                "%s: person %d: pose_keypoints_2d must be %d numbers (17 x, y, c), got %d; skipped",
                path,
                i,
                _NUM_VALUES,
                len(value),
            )
            continue
        if not _VALUE_TYPES.issuperset(map(type, value)):
            bad = next(v for v in value if v is not None and not _is_number(v))
            raise KeypointsError(
                f"{path}: person {i}: pose_keypoints_2d must hold numbers or null, found {bad!r}"
            )
        kps.append(value)
        box = person.get("box_xyxy")
        boxes.append(box if _values(box, 4) else None)
        score = person.get("score")
        scores.append(float(score) if _is_number(score) else None)
    if not kps:
        return People2D(camera, frame, np.zeros((0, NUM_JOINTS, 3)))
    # every person's values checked above: one conversion for the whole file
    keypoints = _array(kps, (-1, NUM_JOINTS, 3))
    if keypoints is None:
        raise KeypointsError(f"{path}: pose_keypoints_2d holds a number too large for a float")
    has_boxes = all(b is not None for b in boxes)
    has_scores = all(s is not None for s in scores)
    return People2D(
        camera,
        frame,
        keypoints,
        boxes=_array(boxes, (-1, 4)) if has_boxes else None,  # type: ignore[arg-type]
        scores=np.array(scores, dtype=np.float64) if has_scores else None,
    )


class PoseSequence:
    """Keypoint files of several cameras indexed by frame; files are parsed when a frame is read.

    cameras: matched camera names in calibration order. frames: sorted frame numbers seen in
    any camera. skipped: (file, reason) of files left out (while indexing or reading).
    """

    def __init__(self, pose_dir: Path, files: dict[str, dict[int, Path]]) -> None:
        self.pose_dir = pose_dir
        self._files = files
        self.cameras: tuple[str, ...] = tuple(files)
        self.frames: list[int] = sorted({f for per in files.values() for f in per})
        self.skipped: list[tuple[Path, str]] = []

    def files(self, camera: str) -> dict[int, Path]:
        """Frame number -> file of one camera."""
        return dict(self._files[camera])

    def _skip(self, path: Path, reason: str) -> None:
        logger.warning("%s: skipped: %s", path, reason)
        self.skipped.append((path, reason))

    def frame(self, n: int) -> dict[str, People2D]:
        """People of each camera that has a readable file for frame n (others are absent)."""
        out: dict[str, People2D] = {}
        for cam in self.cameras:
            path = self._files[cam].get(n)
            if path is None:
                continue
            try:
                out[cam] = read_pose_file(path, cam, n)
            except KeypointsError as e:
                # a broken file is dropped once, so later reads see no file there
                del self._files[cam][n]
                self._skip(path, str(e).removeprefix(f"{path}: "))
        return out

    def __iter__(self) -> Iterator[tuple[int, dict[str, People2D]]]:
        for n in self.frames:
            yield n, self.frame(n)

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"PoseSequence({str(self.pose_dir)!r}, cameras={self.cameras}, frames={len(self)})"


def read_pose_dir(pose_dir: str | Path, camera_names: Sequence[str]) -> PoseSequence:
    """Index ``<pose_dir>/<camera>_json/*.json`` for the given cameras (see find_camera_dirs)."""
    pose_dir = Path(pose_dir)
    files: dict[str, dict[int, Path]] = {}
    skipped: list[tuple[Path, str]] = []
    for cam, folder in find_camera_dirs(pose_dir, camera_names).items():
        per: dict[int, Path] = {}
        for path in sorted(p for p in folder.iterdir() if p.suffix.lower() == ".json"):
            n = frame_number(path.name)
            if n is None:
                reason = "no frame number in the file name"
            elif n in per:
                reason = f"frame {n} already read from {per[n].name}"
            else:
                per[n] = path
                continue
            logger.warning("%s: skipped: %s", path, reason)
            skipped.append((path, reason))
        files[cam] = per
    seq = PoseSequence(pose_dir, files)
    seq.skipped.extend(skipped)
    return seq


def write_pose_frame(pose_dir: str | Path, camera: str, people: People2D) -> Path:
    """Write one camera's people at one frame; missing joints are written as 0, 0, 0.

    Returns ``<pose_dir>/<camera>_json/<camera>_<frame:012d>_keypoints.json``.
    """
    folder = Path(pose_dir) / f"{camera}_json"
    path = folder / f"{camera}_{people.frame:012d}_keypoints.json"
    records = []
    for i, kp in enumerate(people.keypoints):
        kp = np.where(np.isfinite(kp) & (kp[:, 2:3] > 0), kp, 0.0)
        rec: dict[str, object] = {
            "person_id": [-1],
            "pose_keypoints_2d": [float(v) for v in kp.ravel()],
        }
        if people.boxes is not None:
            rec["box_xyxy"] = [float(v) for v in people.boxes[i]]
        if people.scores is not None:
            rec["score"] = float(people.scores[i])
        records.append(rec)
    text = json.dumps({"version": 1.3, "people": records})
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    except OSError as e:
        raise KeypointsError(f"{folder}: cannot write keypoint files: {e.strerror}") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except OSError as e:
        Path(tmp).unlink(missing_ok=True)
        raise KeypointsError(f"{path}: cannot write: {e.strerror}") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
