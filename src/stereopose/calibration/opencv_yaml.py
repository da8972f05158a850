"""OpenCV YAML calibration files as EasyMocap writes them: `intri.yml` and `extri.yml`.

intri.yml: `names` (camera names), per camera `K_<name>` (3 x 3), `dist_<name>` (1 x 5: k1 k2
p1 p2 k3), and `H_<name>`, `W_<name>` (image size; when absent, taken as twice the principal
point, with a warning). extri.yml: `names`, per camera `R_<name>` (3 x 1 Rodrigues), `Rot_<name>`
(3 x 3) and `T_<name>` (3 x 1, metres), world -> camera.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from stereopose.errors import CalibrationError
from stereopose.types import Camera, Rig

logger = logging.getLogger(__name__)


def yaml_paths(path: str | Path) -> tuple[Path, Path]:
    """(intri.yml, extri.yml) from a folder holding both, or from either file."""
    path = Path(path)
    folder = path.parent if path.suffix.lower() in (".yml", ".yaml") else path
    return folder / "intri.yml", folder / "extri.yml"


def _names(fs: cv2.FileStorage, path: Path) -> list[str]:
    node = fs.getNode("names")
    if node.empty() or not node.isSeq():
        raise CalibrationError(f"{path}: no `names` list of cameras")
    return [node.at(i).string() or str(int(node.at(i).real())) for i in range(node.size())]


def _mat(fs: cv2.FileStorage, key: str, shape: tuple[int, ...], path: Path) -> np.ndarray:
    m = fs.getNode(key).mat()
    if m is None:
        raise CalibrationError(f"{path}: missing `{key}`")
    m = np.asarray(m, dtype=np.float64)
    if m.size != int(np.prod(shape)):
        raise CalibrationError(f"{path}: `{key}` must hold {np.prod(shape)} numbers, has {m.size}")
    return m.reshape(shape)


def read_opencv_yaml(path: str | Path) -> Rig:
    intri, extri = yaml_paths(path)
    for p in (intri, extri):
        if not p.is_file():
            raise CalibrationError(f"{p}: calibration file not found (intri.yml and extri.yml)")
    fi = cv2.FileStorage(str(intri), cv2.FILE_STORAGE_READ)
    fe = cv2.FileStorage(str(extri), cv2.FILE_STORAGE_READ)
    if not fi.isOpened() or not fe.isOpened():
        raise CalibrationError(f"{intri if not fi.isOpened() else extri}: not an OpenCV YAML file")
    try:
        cams = []
        for name in _names(fi, intri):
            K = _mat(fi, f"K_{name}", (3, 3), intri)
            node = fi.getNode(f"dist_{name}")
            dist = np.ravel(node.mat()) if not node.empty() else np.zeros(0)
            if dist.size < 4:
                raise CalibrationError(f"{intri}: `dist_{name}` needs k1 k2 p1 p2 at least")
            h, w = fi.getNode(f"H_{name}"), fi.getNode(f"W_{name}")
            if h.empty() or w.empty():
                size = (round(2 * K[0, 2]), round(2 * K[1, 2]))
                logger.warning("%s: no image size for camera %s; taken as %s", intri, name, size)
            else:
                size = (int(w.real()), int(h.real()))
            rvec = _mat(fe, f"R_{name}", (3,), extri)
            t = _mat(fe, f"T_{name}", (3,), extri)
            d = dist[:5] if dist.size >= 5 and dist[4] != 0 else dist[:4]
            try:
                cams.append(Camera(name, (float(size[0]), float(size[1])), K, d, rvec, t))
            except (ValueError, CalibrationError) as e:
                raise CalibrationError(f"{intri}: camera {name}: {e}") from None
    finally:
        fi.release()
        fe.release()
    return Rig(tuple(cams))


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
