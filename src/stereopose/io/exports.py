"""Per-person TRC files (OpenSim, Pose2Sim) and a flat CSV of every joint.

TRC axes: OpenSim and Pose2Sim expect y up, so a TRC row holds world (y, z, x) as its
(X, Y, Z): the same cyclic exchange as Pose2Sim's `zup2yup`, a rotation (right-handed, metres).
Joints not reconstructed in a frame are empty cells. One file per person, `person_<id>.trc`,
covering that person's first to last frame.

CSV: one row per reconstructed joint: frame, t, id, joint, x, y, z, conf (world frame, metres);
joints not reconstructed have no row.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import IO

import numpy as np

from stereopose.errors import StereoposeError
from stereopose.skeleton import JOINTS, NUM_JOINTS
from stereopose.types import People3D

_TO_TRC = np.array([1, 2, 0])  # TRC (X, Y, Z) = world (y, z, x)
_FROM_TRC = np.argsort(_TO_TRC)


def _open(path: Path, what: str) -> IO[str]:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return path.open("w", encoding="utf-8", newline="")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write {what}: {e.strerror}") from None


def write_trc(path: str | Path, frames: np.ndarray, joints: np.ndarray, fps: float) -> None:
    """One person's joints as a TRC file.

    frames: (F,) frame numbers, increasing; joints: (F, 17, 3) world metres, NaN where missing.
    """
    path = Path(path)
    frames = np.asarray(frames, dtype=np.int64)
    data = np.asarray(joints, dtype=np.float64)[..., _TO_TRC]
    F = frames.size
    first, last = (int(frames[0]), int(frames[-1])) if F else (0, 0)
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame"
        "\tOrigNumFrames",
        f"{fps:g}\t{fps:g}\t{F}\t{NUM_JOINTS}\tm\t{fps:g}\t{first}\t{last}",
        "Frame#\tTime\t" + "\t\t\t".join(JOINTS) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(NUM_JOINTS)),
    ]
    for f, row in zip(frames, data, strict=True):
        cells = ["" if not np.isfinite(v) else f"{v:.5f}" for v in row.reshape(-1)]
        lines.append(f"{f}\t{f / fps:.6f}\t" + "\t".join(cells))
    with _open(path, "TRC") as fh:
        fh.write("\n".join(lines) + "\n")


def read_trc(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str], float]:
    """A TRC file back: frames (F,), times (F,), joints (F, M, 3) in the world frame (z up,
    undoing the y-up exchange), marker names, data rate."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
        rate = float(lines[2].split("\t")[0])
        names = [n for n in lines[3].split("\t")[2:] if n]
        rows = [ln.split("\t") for ln in lines[5:] if ln.strip()]
        frames = np.array([int(r[0]) for r in rows], dtype=np.int64)
        times = np.array([float(r[1]) for r in rows])
        vals = np.array(
            [[float(c) if c else np.nan for c in r[2 : 2 + 3 * len(names)]] for r in rows]
        ).reshape(len(rows), len(names), 3)
    except (OSError, IndexError, ValueError) as e:
        raise StereoposeError(f"{path}: not a readable TRC file: {e}") from None
    return frames, times, vals[..., _FROM_TRC], names, rate


class TrcExporter:
    """Collects each person's joints while a run goes on; `close` writes one TRC per person."""

    def __init__(self, out_dir: str | Path, fps: float) -> None:
        self.out_dir = Path(out_dir)
        self.fps = float(fps)
        self._frames: dict[int, list[int]] = {}
        self._joints: dict[int, list[np.ndarray]] = {}
        self.paths: list[Path] = []

    def add(self, people: People3D) -> None:
        for p in range(len(people)):
            i = int(people.ids[p])
            self._frames.setdefault(i, []).append(people.frame)
            self._joints.setdefault(i, []).append(people.joints[p])

    def close(self) -> list[Path]:
        for i in sorted(self._frames):
            got = np.array(self._frames[i])
            frames = np.arange(got[0], got[-1] + 1)
            joints = np.full((frames.size, NUM_JOINTS, 3), np.nan)
            joints[got - got[0]] = np.stack(self._joints[i])
            path = self.out_dir / f"person_{i}.trc"
            write_trc(path, frames, joints, self.fps)
            self.paths.append(path)
        self._frames.clear()
        self._joints.clear()
        return self.paths


class CsvExporter:
    """Streams frame, t, id, joint, x, y, z, conf rows, flushed every frame."""

    HEADER = ("frame", "t", "id", "joint", "x", "y", "z", "conf")

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self._f = _open(self.path, "CSV")
        self._w = csv.writer(self._f, lineterminator="\n")
        self._w.writerow(self.HEADER)

    def add(self, people: People3D) -> None:
        t = round(people.frame / self.fps, 6)
        ok = np.isfinite(people.joints).all(-1)
        for p, j in zip(*np.nonzero(ok), strict=True):
            x, y, z = people.joints[p, j]
            self._w.writerow(
                (
                    people.frame,
                    t,
                    int(people.ids[p]),
                    JOINTS[j],
                    f"{x:.4f}",
                    f"{y:.4f}",
                    f"{z:.4f}",
                    f"{people.conf[p, j]:.3f}",
                )
            )
        self._f.flush()

    def close(self) -> None:
        self._f.close()
