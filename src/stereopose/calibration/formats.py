"""Native calibration files (Pose2Sim's ``Calib.toml`` layout): read, validate, write.

One table per camera (every top-level table with a ``matrix`` key), see docs/formats.md:
``size`` (width, height) px, ``matrix`` (3, 3) K px, ``distortions`` (4,) or (5,) OpenCV order,
``rotation`` (3,) Rodrigues world -> camera (a (3, 3) matrix is also accepted when reading),
``translation`` (3,) metres world -> camera, ``fisheye`` bool.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
import tomllib
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from stereopose.checks import read_limited
from stereopose.errors import CalibrationError
from stereopose.types import Camera, Rig

REQUIRED_KEYS: tuple[str, ...] = ("size", "matrix", "distortions", "rotation", "translation")
_SHAPES: dict[str, tuple[tuple[int, ...], ...]] = {
    "size": ((2,),),
    "matrix": ((3, 3),),
    "distortions": ((4,), (5,)),
    "rotation": ((3,), (3, 3)),
    "translation": ((3,),),
}
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _is_qca(path: Path, head: bytes) -> bool:
    return path.name.lower().endswith(".qca.txt") or head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(
        b"<?xml"
    )


def load_calibration(path: str | Path, min_cameras: int = 2) -> Rig:
    """Read a calibration file into a Rig (cameras in file order).

    Native TOML, a Qualisys ``.qca.txt`` export (XML), recognised by its name or content, or
    OpenCV YAML (EasyMocap's intri.yml and extri.yml: either file, or their folder). Raises
    CalibrationError naming the file, the camera table and the problem.
    """
    path = Path(path)
    if (path.is_dir() and (path / "intri.yml").is_file()) or path.suffix.lower() in (
        ".yml",
        ".yaml",
    ):
        from stereopose.calibration.opencv_yaml import read_opencv_yaml

        rig = read_opencv_yaml(path)
        if len(rig) < min_cameras:
            raise CalibrationError(
                f"{path}: calibration needs at least {min_cameras} cameras, found {len(rig)}"
            )
        return rig
    raw = read_limited(path, "calibration file", CalibrationError)
    if _is_qca(path, raw[:64]):
        from stereopose.calibration.qualisys import read_qca

        rig = read_qca(path)
    else:
        rig = _parse_toml(path, raw)
    if len(rig) < min_cameras:
        raise CalibrationError(
            f"{path}: calibration needs at least {min_cameras} cameras, found {len(rig)}"
            + (f" ({', '.join(rig.names)})" if len(rig) else "")
        )
    return rig


def _parse_toml(path: Path, raw: bytes) -> Rig:
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise CalibrationError(f"{path}: not UTF-8 text (byte {e.start}); expected TOML") from None
    except ValueError as e:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise CalibrationError(f"{path}: not valid TOML: {e}") from None
    except RecursionError:  # tomllib recurses once per level of nested arrays or tables
        raise CalibrationError(f"{path}: not valid TOML: nested too deeply") from None
    cameras: list[Camera] = []
    table_of: dict[str, str] = {}
    for key, table in doc.items():
        if not isinstance(table, dict) or "matrix" not in table:
            continue
        cam = _camera_from_table(path, key, table)
        if cam.name in table_of:
            raise CalibrationError(
                f"{path}: camera [{key}]: duplicate camera name {cam.name!r} "
                f"(also used by table [{table_of[cam.name]}])"
            )
        table_of[cam.name] = key
        cameras.append(cam)
    if not cameras:
        found = ", ".join(f"[{k}]" for k, v in doc.items() if isinstance(v, dict)) or "none"
        raise CalibrationError(
            f"{path}: no camera tables found (a camera table has a 'matrix' key); tables: {found}"
        )
    return Rig(tuple(cameras))


def _numbers(path: Path, key: str, what: str, value: object) -> np.ndarray:
    """Nested lists of int/float (not bool, not str) with an allowed shape -> float array."""
    where = f"{path}: camera [{key}]: {what}"

    def check(v: object, depth: int) -> None:
        if isinstance(v, list) and depth < 2:
            for x in v:
                check(x, depth + 1)
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            shown = repr(v) if len(repr(v)) <= 60 else repr(v)[:57] + "..."
            raise CalibrationError(f"{where} must contain only numbers, found {shown}")
        elif isinstance(v, int) and abs(v) > 2**63:
            raise CalibrationError(f"{where}: an integer of {v.bit_length()} bits is too large")

    check(value, 0)
    shapes = _SHAPES[what]
    expected = " or ".join(str(s) for s in shapes)
    try:
        a = np.array(value, dtype=np.float64)
    except ValueError:
        raise CalibrationError(f"{where} must have shape {expected}, got ragged rows") from None
    if a.shape not in shapes:
        raise CalibrationError(f"{where} must have shape {expected}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{where} contains NaN or infinite values: {a.tolist()}")
    return a


def _camera_from_table(path: Path, key: str, table: dict) -> Camera:
    missing = [k for k in REQUIRED_KEYS if k not in table]
    if missing:
        raise CalibrationError(f"{path}: camera [{key}]: missing keys: {', '.join(missing)}")
    name = table.get("name", key)
    if not isinstance(name, str) or not name:
        raise CalibrationError(
            f"{path}: camera [{key}]: name must be a non-empty string, got {name!r}"
        )
    fisheye = table.get("fisheye", False)
    if not isinstance(fisheye, bool):
        raise CalibrationError(
            f"{path}: camera [{key}]: fisheye must be true or false, got {fisheye!r}"
        )
    arrays = {k: _numbers(path, key, k, table[k]) for k in REQUIRED_KEYS}
    if arrays["matrix"][0, 0] <= 0 or arrays["matrix"][1, 1] <= 0:
        raise CalibrationError(
            f"{path}: camera [{key}]: focal lengths must be positive, "
            f"got fx={arrays['matrix'][0, 0]}, fy={arrays['matrix'][1, 1]}"
        )
    try:
        return Camera(
            name=name,
            size=tuple(arrays["size"]),
            matrix=arrays["matrix"],
            distortions=arrays["distortions"],
            rotation=arrays["rotation"],
            translation=arrays["translation"],
            fisheye=fisheye,
        )
    except CalibrationError as e:
        raise CalibrationError(f"{path}: camera [{key}]: {e}") from None


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else _toml_str(key)


def _toml_str(s: str) -> str:
    # JSON strings are TOML basic strings, except that TOML also forbids a raw DEL.
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_float(x: float | np.floating) -> str:
    x = float(x)
    if not math.isfinite(x):
        return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return repr(x)  # shortest string that reads back to the same float


def _toml_list(a: np.ndarray) -> str:
    if a.ndim == 1:
        return "[ " + ", ".join(_toml_float(x) for x in a) + "]"
    return "[ " + ", ".join(_toml_list(row) for row in a) + "]"


def _toml_value(key: str, v: object) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return _toml_float(v)
    if isinstance(v, str):
        return _toml_str(v)
    raise CalibrationError(
        f"metadata {key!r}: values must be bool, int, float or str, got {type(v).__name__}"
    )


def format_calibration(rig: Rig, metadata: Mapping[str, object] | None = None) -> str:
    """The native TOML text of a rig (and an optional flat ``[metadata]`` table)."""
    if metadata is not None and "metadata" in rig.names:
        raise CalibrationError("a camera named 'metadata' clashes with the [metadata] table")
    lines: list[str] = []
    for cam in rig:
        lines += [
            f"[{_toml_key(cam.name)}]",
            f"name = {_toml_str(cam.name)}",
            f"size = {_toml_list(np.asarray(cam.size))}",
            f"matrix = {_toml_list(cam.matrix)}",
            f"distortions = {_toml_list(cam.distortions)}",
            f"rotation = {_toml_list(cam.rotation)}",
            f"translation = {_toml_list(cam.translation)}",
            f"fisheye = {'true' if cam.fisheye else 'false'}",
            "",
        ]
    if metadata is not None:
        lines.append("[metadata]")
        lines += [f"{_toml_key(str(k))} = {_toml_value(str(k), v)}" for k, v in metadata.items()]
        lines.append("")
    return "\n".join(lines)


def save_calibration(
    path: str | Path, rig: Rig, metadata: Mapping[str, object] | None = None
) -> None:
    """Write a rig in the native format; floats are written so that they read back bit-exact.

    The file is replaced atomically (written beside it, then renamed).
    """
    path = Path(path)
    text = format_calibration(rig, metadata)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
