"""OpenCV YAML calibration files as EasyMocap writes them: `intri.yml` and `extri.yml`.

intri.yml: `names` (camera names), per camera `K_<name>` (3 x 3), `dist_<name>` (1 x 5: k1 k2
p1 p2 k3), and `H_<name>`, `W_<name>` (image size; when absent, taken as twice the principal
point, with a warning). extri.yml: `names`, per camera `R_<name>` (3 x 1 Rodrigues), `Rot_<name>`
(3 x 3) and `T_<name>` (3 x 1, metres), world -> camera.

Files are read by the small parser of `opencv_yaml_read` (the YAML that cv2.FileStorage
writes), not by cv2.FileStorage itself: on malformed input that one raises SystemError or
corrupts memory and aborts the process. Writing still uses cv2.FileStorage.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from stereopose.calibration.opencv_yaml_read import Node, number, read_yaml
from stereopose.checks import IMAGE_SIZE
from stereopose.errors import CalibrationError
from stereopose.types import Camera, Rig

logger = logging.getLogger(__name__)


def yaml_paths(path: str | Path) -> tuple[Path, Path]:
    """(intri.yml, extri.yml) from a folder holding both, or from either file."""
    path = Path(path)
    folder = path.parent if path.suffix.lower() in (".yml", ".yaml") else path
    return folder / "intri.yml", folder / "extri.yml"


def _names(doc: dict[str, Node], path: Path) -> list[str]:
    node = doc.get("names")
    if not isinstance(node, list) or not all(isinstance(n, str) for n in node):
        raise CalibrationError(f"{path}: no `names` list of cameras")
    if not node or any(not n for n in node):
        raise CalibrationError(f"{path}: `names` must list non-empty camera names, got {node!r}")
    return [str(n) for n in node]


def _mat(doc: dict[str, Node], key: str, shape: tuple[int, ...] | None, path: Path) -> np.ndarray:
    """The numbers of matrix `key`, (shape), or flat (N,) when shape is None."""
    node = doc.get(key)
    if node is None:
        raise CalibrationError(f"{path}: missing `{key}`")
    if isinstance(node, dict):  # !!opencv-matrix: rows, cols, dt, data
        data = node.get("data")
        if not isinstance(data, list):
            raise CalibrationError(f"{path}: `{key}` has no `data` list of numbers")
        dims = [number(node.get(k, "nan"), f"{path}: `{key}`: {k}") for k in ("rows", "cols")]
        if dims[0] * dims[1] != len(data):
            raise CalibrationError(
                f"{path}: `{key}`: rows x cols = {dims[0]:g} x {dims[1]:g} but data holds "
                f"{len(data)} numbers"
            )
    elif isinstance(node, list):
        data = node
    else:
        raise CalibrationError(f"{path}: `{key}` must be a matrix, got {node!r}")
    m = np.array([number(v, f"{path}: `{key}`") for v in data], dtype=np.float64)
    if shape is None:
        shape = (m.size,)
    if m.size != int(np.prod(shape)):
        raise CalibrationError(f"{path}: `{key}` must hold {np.prod(shape)} numbers, has {m.size}")
    if not np.isfinite(m).all():
        raise CalibrationError(f"{path}: `{key}` contains NaN or infinite values: {m.tolist()}")
    return m.reshape(shape)


def _size(doc: dict[str, Node], name: str, K: np.ndarray, path: Path) -> tuple[float, float]:
    if f"H_{name}" not in doc or f"W_{name}" not in doc:
        size = (float(round(2 * K[0, 2])), float(round(2 * K[1, 2])))
        logger.warning("%s: no image size for camera %s; taken as %s", path, name, size)
        return size
    w, h = (
        IMAGE_SIZE.check(number(doc[k], f"{path}: `{k}`"), f"{path}: `{k}`", CalibrationError)
        for k in (f"W_{name}", f"H_{name}")
    )
    return float(int(w)), float(int(h))


def read_opencv_yaml(path: str | Path) -> Rig:
    intri, extri = yaml_paths(path)
    for p in (intri, extri):
        if not p.is_file():
            raise CalibrationError(f"{p}: calibration file not found (intri.yml and extri.yml)")
    fi, fe = read_yaml(intri), read_yaml(extri)
    cams = []
    for name in _names(fi, intri):
        K = _mat(fi, f"K_{name}", (3, 3), intri)
        dist = _mat(fi, f"dist_{name}", None, intri) if f"dist_{name}" in fi else np.zeros(0)
        if dist.size < 4 or (dist.size > 5 and np.any(dist[5:] != 0)):
            raise CalibrationError(f"{intri}: `dist_{name}` needs k1 k2 p1 p2 (k3) only")
        size = _size(fi, name, K, intri)
        rvec = _mat(fe, f"R_{name}", (3,), extri)
        t = _mat(fe, f"T_{name}", (3,), extri)
        d = dist[:5] if dist.size >= 5 and dist[4] != 0 else dist[:4]
        try:
            cams.append(Camera(name, size, K, d, rvec, t))
        except CalibrationError as e:
            raise CalibrationError(f"{intri}: camera {name}: {e}") from None
    try:
        return Rig(tuple(cams))
    except CalibrationError as e:
        raise CalibrationError(f"{intri}: {e}") from None


def write_opencv_yaml(path: str | Path, rig: Rig) -> tuple[Path, Path]:
    intri, extri = yaml_paths(path)
    intri.parent.mkdir(parents=True, exist_ok=True)
    fi = cv2.FileStorage(str(intri), cv2.FILE_STORAGE_WRITE)
    fe = cv2.FileStorage(str(extri), cv2.FILE_STORAGE_WRITE)
    if not fi.isOpened() or not fe.isOpened():
        raise CalibrationError(f"{intri.parent}: cannot write intri.yml / extri.yml")
    for fs in (fi, fe):
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for cam in rig:
            fs.write("", cam.name)
        fs.endWriteStruct()
    for cam in rig:
        fi.write(f"K_{cam.name}", cam.matrix)
        fi.write(f"dist_{cam.name}", np.pad(cam.distortions, (0, 5 - len(cam.distortions)))[None])
        fi.write(f"H_{cam.name}", int(cam.size[1]))
        fi.write(f"W_{cam.name}", int(cam.size[0]))
        fe.write(f"R_{cam.name}", cv2.Rodrigues(cam.R)[0])
        fe.write(f"Rot_{cam.name}", cam.R)
        fe.write(f"T_{cam.name}", cam.translation.reshape(3, 1))
    fi.release()
    fe.release()
    return intri, extri
