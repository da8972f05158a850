"""Import of Qualisys Track Manager calibration exports (``.qca.txt``, XML).

Qualisys stores intrinsics in 1/64 pixel of the sensor, the camera pose as a camera -> world
rotation ``M`` (rows r1*, r2*, r3*) and the camera centre ``C`` in millimetres, in a camera frame
whose y and z axes point opposite to OpenCV's (a rotation of pi about x).
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np

from stereopose.checks import MAX_TRANSLATION_M, Range, read_limited
from stereopose.errors import CalibrationError
from stereopose.types import Camera, Rig

_UNITS_PER_PX = 64.0
_FLIP = np.diag([1.0, -1.0, -1.0])  # Qualisys camera frame -> OpenCV camera frame
_ROTATION_TOL = 1e-4  # exports round the matrix entries
_CENTRE_MM = Range(gt=-1000 * MAX_TRANSLATION_M, lt=1000 * MAX_TRANSLATION_M)


def _natural_key(name: str) -> list[object]:
    # digit runs compared by length, then text: numeric order without int() (no digit limit)
    return [
        (0, len(p.lstrip("0")), p.lstrip("0")) if p.isdigit() else (1, 0, p)
        for p in re.split(r"(\d+)", name)
        if p
    ]


def _float_attrs(
    path: Path, cam: str, el: ET.Element | None, tag: str, names: list[str]
) -> list[float]:
    if el is None:
        raise CalibrationError(f"{path}: camera {cam!r}: missing <{tag}> element")
    missing = [n for n in names if n not in el.attrib]
    if missing:
        raise CalibrationError(
            f"{path}: camera {cam!r}: <{tag}> lacks attributes: {', '.join(missing)}"
        )
    out = []
    for n in names:
        try:
            v = float(el.attrib[n])
        except ValueError:
            raise CalibrationError(
                f"{path}: camera {cam!r}: <{tag}> attribute {n}={el.attrib[n]!r} is not a number"
            ) from None
        if not np.isfinite(v):
            raise CalibrationError(f"{path}: camera {cam!r}: <{tag}> attribute {n} is {v}")
        out.append(v)
    return out


def _camera(path: Path, name: str, el: ET.Element) -> Camera:
    left, top, right, bottom = _float_attrs(
        path, name, el.find("fov_video"), "fov_video", ["left", "top", "right", "bottom"]
    )
    fu, fv, cu, cv, k1, k2, p1, p2 = (
        v / _UNITS_PER_PX
        for v in _float_attrs(
            path,
            name,
            el.find("intrinsic"),
            "intrinsic",
            [
                "focalLengthU",
                "focalLengthV",
                "centerPointU",
                "centerPointV",
                "radialDistortion1",
                "radialDistortion2",
                "tangentalDistortion1",
                "tangentalDistortion2",
            ],
        )
    )
    keys = ["r11", "r12", "r13", "r21", "r22", "r23", "r31", "r32", "r33", "x", "y", "z"]
    tr = _float_attrs(path, name, el.find("transform"), "transform", keys)
    for key, v in zip(keys[9:], tr[9:], strict=True):  # bounded before any arithmetic
        _CENTRE_MM.check(v, f"{path}: camera {name!r}: <transform> {key} (mm)", CalibrationError)
    M = np.array(tr[:9]).reshape(3, 3)
    C_mm = np.array(tr[9:])
    # the entries of a rotation lie in [-1, 1]; beyond, M M^T could overflow
    bounded = np.abs(M).max() <= 1.0 + _ROTATION_TOL
    err = float(np.abs(M @ M.T - np.eye(3)).max()) if bounded else math.inf
    if err > _ROTATION_TOL or np.linalg.det(M) <= 0:
        det = f"{np.linalg.det(M):.4f}" if bounded else "n/a"
        raise CalibrationError(
            f"{path}: camera {name!r}: <transform> r11..r33 is not a rotation matrix "
            f"(|M M^T - I| = {err:.2e}, det = {det})"
        )
    R = _FLIP @ M
    t = _FLIP @ (-M @ C_mm) / 1000.0
    try:
        return Camera(
            name=name,
            size=(right - left + 1.0, bottom - top + 1.0),
            matrix=np.array([[fu, 0.0, cu - left], [0.0, fv, cv - top], [0.0, 0.0, 1.0]]),
            distortions=np.array([k1, k2, p1, p2]),
            rotation=cv2.Rodrigues(R)[0].ravel(),
            translation=t,
        )
    except CalibrationError as e:
        raise CalibrationError(f"{path}: {e}") from None


def read_qca(path: str | Path) -> Rig:
    """Read a Qualisys ``.qca.txt`` calibration into a Rig, cameras in natural order of serial."""
    path = Path(path)
    raw = read_limited(path, "calibration file", CalibrationError)
    try:
        root = ET.fromstring(raw)
    except (ET.ParseError, ValueError, LookupError) as e:  # LookupError: unknown encoding
        raise CalibrationError(f"{path}: not a valid Qualisys XML file: {e}") from None
    elements = root.findall("cameras/camera")
    if not elements:
        raise CalibrationError(f"{path}: no <cameras>/<camera> elements in the Qualisys file")
    named: list[tuple[str, ET.Element]] = []
    for i, el in enumerate(elements, start=1):
        serial = el.attrib.get("serial", "").strip()
        if not serial:
            raise CalibrationError(f"{path}: camera #{i}: missing 'serial' attribute (its name)")
        named.append((serial, el))
    seen: set[str] = set()
    for serial, _ in named:
        if serial in seen:
            raise CalibrationError(f"{path}: camera {serial!r}: duplicate serial")
        seen.add(serial)
    named.sort(key=lambda item: _natural_key(item[0]))
    return Rig(tuple(_camera(path, name, el) for name, el in named))
