"""2D keypoints on disk in the OpenPose / Pose2Sim layout.

``<pose_dir>/<camera>_json/<anything>_<frame>_keypoints.json``, one file per camera and frame:
``{"people": [{"pose_keypoints_2d": [x0, y0, c0, ..., x16, y16, c16]}, ...]}`` in COCO-17 order,
pixels of the original image, c = 0 (or null) for a missing joint. Optional per person:
``box_xyxy`` (x1, y1, x2, y2 pixels) and ``score``.

Every file is hostile until read: only regular files are opened (a named pipe called
``*_keypoints.json`` would block), files over MAX_FILE_BYTES and frames with more than
MAX_PEOPLE_PER_VIEW people are refused before any work that grows with them, and any JSON
(nested, huge numbers, NaN) ends as people or as a KeypointsError naming the file.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import stat
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TypeGuard

import numpy as np
import orjson

from stereopose.errors import KeypointsError
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import People2D

logger = logging.getLogger(__name__)

_INT = re.compile(r"\d+")
_NUM_VALUES = NUM_JOINTS * 3

# A camera frame of a substation holds a handful of people; association costs memory that
# grows with the people of a view squared, so a file beyond this is refused, not read.
MAX_PEOPLE_PER_VIEW = 100
# 100 people of 51 values take about 150 kB as text: a file far larger is not keypoints.
MAX_FILE_BYTES = 8 * 1024 * 1024
# Frame numbers stay exact as float times (t = frame / fps) and fit 64-bit integer columns.
MAX_FRAME = 2**53
# A joint further than this from the image (pixels) is not a detection: it is read as missing.
MAX_COORD_PX = 1e6


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
    try:
        found = sorted(p.name for p in pose_dir.iterdir() if p.is_dir())
    except OSError as e:
        raise KeypointsError(
            f"{pose_dir}: cannot list the keypoints folder: {e.strerror}"
        ) from None
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


def _is_number(v: object) -> TypeGuard[int | float]:
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


def _finite(v: object) -> float | None:
    """v as a finite float, None if it is not a number or not finite (or beyond a float)."""
    if not _is_number(v):
        return None
    try:
        x = float(v)
    except OverflowError:
        return None
    return x if math.isfinite(x) else None


def _boxes(boxes: list[list | None]) -> np.ndarray | None:
    """(P, 4) boxes when every person has a finite one, else None (boxes are optional)."""
    if not boxes or any(b is None for b in boxes):
        return None
    a = _array([b for b in boxes if b is not None], (-1, 4))
    return a if a is not None and np.isfinite(a).all() else None


def _far_joints_missing(path: Path, keypoints: np.ndarray) -> np.ndarray:
    """Joints further than MAX_COORD_PX from the image marked missing, with a warning."""
    with np.errstate(invalid="ignore"):
        far = (np.abs(keypoints[..., :2]) > MAX_COORD_PX).any(-1)
    if far.any():
        logger.warning(
            "%s: %d joint(s) more than %g pixels from the image read as missing",
            path,
            int(far.sum()),
            MAX_COORD_PX,
        )
        keypoints[far] = np.nan
    return keypoints


def _kind(mode: int) -> str:
    """What a file that is not a regular file is, for messages."""
    for test, name in (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a named pipe"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a device"),
        (stat.S_ISBLK, "a device"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def _read_bytes(path: Path) -> bytes:
    """The bytes of a regular file of at most MAX_FILE_BYTES; KeypointsError otherwise.

    Opened without blocking and checked on the open descriptor, so a named pipe (or one
    swapped in after the folder was listed) is refused instead of waiting for a writer."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    except OSError as e:
        raise KeypointsError(f"{path}: cannot read: {e.strerror}") from None
    with os.fdopen(fd, "rb") as f:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise KeypointsError(f"{path}: {_kind(mode)}, not a keypoint file")
        try:
            raw = f.read(MAX_FILE_BYTES + 1)
        except OSError as e:
            raise KeypointsError(f"{path}: cannot read: {e.strerror}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise KeypointsError(
            f"{path}: larger than {MAX_FILE_BYTES // 2**20} MiB, too large for a keypoint file"
        )
    return raw


def _load(path: Path) -> object:
    """Parsed JSON of a file; errors name the file and the problem."""
    raw = _read_bytes(path)
    try:
        return orjson.loads(raw)
    except orjson.JSONDecodeError:
        pass
    # The standard parser decides what orjson refused (NaN, Infinity, a byte order mark, bad
    # UTF-8, integers beyond 64 bits), so such files are read, or rejected, as ever.
    try:
        return json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise KeypointsError(f"{path}: cannot read: {e}") from None
    except RecursionError:
        raise KeypointsError(f"{path}: not valid JSON: nested too deeply") from None
    except json.JSONDecodeError as e:
        raise KeypointsError(f"{path}: not valid JSON: {e}") from None
    except ValueError:  # an integer of thousands of digits
        raise KeypointsError(f"{path}: not valid JSON: a number of too many digits") from None


def read_pose_file(path: str | Path, camera: str, frame: int) -> People2D:
    """Read one keypoints file; raises KeypointsError naming the file and the problem.

    A person whose ``pose_keypoints_2d`` has a length other than 51 is skipped with a warning;
    ``null`` values count as missing, and so do non-finite ones and joints more than
    MAX_COORD_PX pixels away; confidences are clipped to [0, 1] (see People2D). A file of more
    than MAX_PEOPLE_PER_VIEW people is refused. Boxes and scores are kept only when every
    person has finite ones.
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
    if len(people) > MAX_PEOPLE_PER_VIEW:
        raise KeypointsError(
            f"{path}: {len(people)} people in one camera frame, more than the "
            f"{MAX_PEOPLE_PER_VIEW} a keypoint file may hold"
        )
    kps: list[list] = []
    boxes: list[list | None] = []
    scores: list[float | None] = []
    for i, person in enumerate(people):
        value = _person_values(path, i, person)
        if value is None:
            continue
        kps.append(value)
        box = person.get("box_xyxy")
        boxes.append(box if _values(box, 4) else None)
        scores.append(_finite(person.get("score")))
    if not kps:
        return People2D(camera, frame, np.zeros((0, NUM_JOINTS, 3)))
    # every person's values checked above: one conversion for the whole file
    keypoints = _array(kps, (-1, NUM_JOINTS, 3))
    if keypoints is None:
        raise KeypointsError(f"{path}: pose_keypoints_2d holds a number too large for a float")
    has_scores = all(s is not None for s in scores)
    return People2D(
        camera,
        frame,
        _far_joints_missing(path, keypoints),
        boxes=_boxes(boxes),
        scores=np.array(scores, dtype=np.float64) if has_scores else None,
    )


def _person_values(path: Path, i: int, person: object) -> list | None:
    """The 51 values of person i of a file, None (with a warning) when they are not 51."""
    if not isinstance(person, dict):
        raise KeypointsError(f"{path}: person {i} must be an object, got {type(person).__name__}")
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
        return None
    if not _VALUE_TYPES.issuperset(map(type, value)):
        bad = next(v for v in value if v is not None and not _is_number(v))
        raise KeypointsError(
            f"{path}: person {i}: pose_keypoints_2d must hold numbers or null, found {_short(bad)}"
        )
    return value


def _short(value: object, limit: int = 60) -> str:
    """repr of a value for a message, cut short (a hostile value can be megabytes)."""
    try:
        text = repr(value)
    except RecursionError:
        text = f"a deeply nested {type(value).__name__}"
    return text if len(text) <= limit else text[: limit - 3] + "..."


class PoseSequence:
    """Keypoint files of several cameras indexed by frame; files are parsed when a frame is read.

    cameras: matched camera names (with at least one file) in calibration order. frames: sorted
    frame numbers seen in any camera. skipped: (file, reason) of files left out (while
    indexing or reading); skipped_per_camera: how many per camera.
    """

    def __init__(self, pose_dir: Path, files: dict[str, dict[int, Path]]) -> None:
        self.pose_dir = pose_dir
        self._files = files
        self.cameras: tuple[str, ...] = tuple(files)
        self.frames: list[int] = sorted({f for per in files.values() for f in per})
        self.skipped: list[tuple[Path, str]] = []
        self.skipped_per_camera: dict[str, int] = {}

    def files(self, camera: str) -> dict[int, Path]:
        """Frame number -> file of one camera."""
        return dict(self._files[camera])

    def skip(self, camera: str, path: Path, reason: str, log: bool = True) -> None:
        """Count a file of `camera` left out, with a warning naming it (unless `log` is off)."""
        if log:
            logger.warning("%s: skipped: %s", path, reason)
        self.skipped.append((path, reason))
        self.skipped_per_camera[camera] = self.skipped_per_camera.get(camera, 0) + 1

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
                self.skip(cam, path, str(e).removeprefix(f"{path}: "))
        return out

    def __iter__(self) -> Iterator[tuple[int, dict[str, People2D]]]:
        for n in self.frames:
            yield n, self.frame(n)

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"PoseSequence({str(self.pose_dir)!r}, cameras={self.cameras}, frames={len(self)})"


def _index_folder(folder: Path) -> tuple[dict[int, Path], list[tuple[Path, str]]]:
    """Frame number -> keypoint file of one camera folder, and the files left out (why).

    Only regular files are taken (links to them included): a folder, named pipe, socket or
    device named ``*.json`` is left out, as is a frame number beyond MAX_FRAME."""
    try:
        entries = sorted(
            (e for e in os.scandir(folder) if e.name.lower().endswith(".json")),
            key=lambda e: e.name,
        )
    except OSError as e:
        return {}, [(folder, f"cannot list the folder: {e.strerror}")]
    per: dict[int, Path] = {}
    skipped: list[tuple[Path, str]] = []
    for entry in entries:
        path = Path(entry.path)
        n = frame_number(entry.name)
        if n is None:
            reason = "no frame number in the file name"
        elif n > MAX_FRAME:
            reason = f"frame number {n} in the file name is beyond {MAX_FRAME}"
        elif n in per:
            reason = f"frame {n} already read from {per[n].name}"
        elif not _is_regular(entry):
            reason = f"{_entry_kind(entry)}, not a keypoint file"
        else:
            per[n] = path
            continue
        skipped.append((path, reason))
    return per, skipped


def _is_regular(entry: os.DirEntry) -> bool:
    try:
        return entry.is_file()
    except OSError:
        return False


def _entry_kind(entry: os.DirEntry) -> str:
    try:
        return _kind(os.stat(entry.path).st_mode)
    except OSError:
        return "a broken link"


def read_pose_dir(pose_dir: str | Path, camera_names: Sequence[str]) -> PoseSequence:
    """Index ``<pose_dir>/<camera>_json/*.json`` for the given cameras (see find_camera_dirs).

    A camera whose folder holds no keypoint file is left out with a warning; KeypointsError if
    no camera has any."""
    pose_dir = Path(pose_dir)
    files: dict[str, dict[int, Path]] = {}
    skipped: list[tuple[str, Path, str]] = []
    empty: list[str] = []
    for cam, folder in find_camera_dirs(pose_dir, camera_names).items():
        per, left_out = _index_folder(folder)
        for path, reason in left_out:
            logger.warning("%s: skipped: %s", path, reason)
            skipped.append((cam, path, reason))
        if per:
            files[cam] = per
        else:
            empty.append(f"{cam} ({folder.name})")
            logger.warning(
                "camera %s: no keypoint files (*.json) in %s; camera left out", cam, folder
            )
    if not files:
        raise KeypointsError(
            f"{pose_dir}: no keypoint files (*.json) in the camera folders: {', '.join(empty)}"
        )
    seq = PoseSequence(pose_dir, files)
    for cam, path, reason in skipped:
        seq.skip(cam, path, reason, log=False)
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
