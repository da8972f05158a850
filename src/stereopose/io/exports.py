"""Per-person TRC files (OpenSim, Pose2Sim) and a flat CSV of every joint.

TRC axes: OpenSim and Pose2Sim expect y up, so a TRC row holds world (y, z, x) as its
(X, Y, Z): the same cyclic exchange as Pose2Sim's `zup2yup`, a rotation (right-handed, metres).
Joints not reconstructed in a frame are empty cells. One file per person, `person_<id>.trc`,
covering that person's first to last frame; `TrcExporter` streams them as a run goes on.

CSV: one row per reconstructed joint: frame, t, id, joint, x, y, z, conf (world frame, metres);
joints not reconstructed have no row.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import IO

import numpy as np

from stereopose.errors import StereoposeError
from stereopose.io.writing import open_output
from stereopose.skeleton import JOINTS, NUM_JOINTS
from stereopose.types import People3D

_TO_TRC = np.array([1, 2, 0])  # TRC (X, Y, Z) = world (y, z, x)
_FROM_TRC = np.argsort(_TO_TRC)


def _trc_header(name: str, fps: float, num_frames: str, first: int, last: str) -> str:
    """The five header lines of a TRC file (NumFrames and the last frame given as text)."""
    return (
        "\n".join(
            [
                f"PathFileType\t4\t(X/Y/Z)\t{name}",
                "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate"
                "\tOrigDataStartFrame\tOrigNumFrames",
                f"{fps:g}\t{fps:g}\t{num_frames}\t{NUM_JOINTS}\tm\t{fps:g}\t{first}\t{last}",
                "Frame#\tTime\t" + "\t\t\t".join(JOINTS) + "\t\t",
                "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(NUM_JOINTS)),
            ]
        )
        + "\n"
    )


def _trc_row(frame: int, joints: np.ndarray | None, fps: float) -> str:
    """One TRC data line: joints (17, 3) world metres, NaN (or None: all) empty cells."""
    if joints is None:
        cells = [""] * (3 * NUM_JOINTS)
    else:
        row = np.asarray(joints, dtype=np.float64)[..., _TO_TRC].reshape(-1)
        cells = ["" if not np.isfinite(v) else f"{v:.5f}" for v in row]
    return f"{frame}\t{frame / fps:.6f}\t" + "\t".join(cells) + "\n"


def write_trc(path: str | Path, frames: np.ndarray, joints: np.ndarray, fps: float) -> None:
    """One person's joints as a TRC file.

    frames: (F,) frame numbers, increasing; joints: (F, 17, 3) world metres, NaN where missing.
    """
    path = Path(path)
    frames = np.asarray(frames, dtype=np.int64)
    data = np.asarray(joints, dtype=np.float64)
    F = frames.size
    first, last = (int(frames[0]), int(frames[-1])) if F else (0, 0)
    text = _trc_header(path.name, fps, str(F), first, str(last))
    text += "".join(_trc_row(int(f), row, fps) for f, row in zip(frames, data, strict=True))
    with open_output(path, "TRC", newline="") as fh:
        fh.write(text)


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


_WIDTH = 10  # digits of the header fields patched as a file grows (NumFrames, last frame)


class _TrcFile:
    """One person's TRC file, open for appending rows (binary, so the header can be patched).

    The header's NumFrames and last-frame fields are zero-padded to a fixed width and rewritten
    in place at every flush, so the file is a complete TRC after each frame.
    """

    def __init__(self, path: Path, fh: IO[bytes], fps: float, first: int, last: int) -> None:
        self.path, self._f, self.fps = path, fh, fps
        self.first, self.last = first, last
        head = _trc_header(path.name, fps, "#", first, "#").encode()
        self._at_rows = head.index(b"#")  # offset of NumFrames
        self._at_last = head.index(b"#", self._at_rows + 1) + _WIDTH - 1

    @classmethod
    def create(cls, path: Path, fps: float, first: int) -> _TrcFile:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fh = path.open("w+b")
        except OSError as e:
            raise StereoposeError(f"{path}: cannot write TRC: {e.strerror}") from None
        f = cls(path, fh, fps, first, first - 1)
        fh.write(_trc_header(path.name, fps, "0" * _WIDTH, first, "0" * _WIDTH).encode())
        return f

    @classmethod
    def reopen(cls, path: Path, fps: float) -> _TrcFile:
        """A file this exporter closed earlier, to append to."""
        try:
            fh = path.open("r+b")
            fields = fh.read(4096).split(b"\n")[2].split(b"\t")
        except (OSError, IndexError) as e:
            raise StereoposeError(f"{path}: cannot append to the TRC file: {e}") from None
        first, last = int(fields[6]), int(fields[7])
        fh.seek(0, 2)
        return cls(path, fh, fps, first, last)

    def append(self, frame: int, joints: np.ndarray) -> None:
        """The row of `frame`, after empty rows for the frames missed since the last one."""
        if frame <= self.last:  # frames come in increasing order; a repeat is ignored
            return
        gap = "".join(_trc_row(f, None, self.fps) for f in range(self.last + 1, frame))
        self._f.write((gap + _trc_row(frame, joints, self.fps)).encode())
        self.last = frame

    def flush(self) -> None:
        end = self._f.tell()
        rows = self.last - self.first + 1
        self._f.seek(self._at_rows)
        self._f.write(f"{rows:0{_WIDTH}d}".encode())
        self._f.seek(self._at_last)
        self._f.write(f"{self.last:0{_WIDTH}d}".encode())
        self._f.seek(end)
        self._f.flush()

    def close(self) -> None:
        self.flush()
        self._f.close()


class TrcExporter:
    """Streams one TRC file per person, `person_<id>.trc`, while a run goes on.

    Rows are appended as frames come, a person's missed frames as empty rows, and each file is
    flushed (and its header updated) every frame, so what was written stays readable whatever
    stops the run. The content is that of `write_trc` over the person's first to last frame;
    only NumFrames and the last frame in the header are zero-padded to 10 digits. A person
    unseen for `idle_frames` frames has their file closed (reopened should they come back),
    so the exporter holds open files only for the people seen lately and nothing per frame.
    """

    def __init__(self, out_dir: str | Path, fps: float, idle_frames: int | None = None) -> None:
        self.out_dir = Path(out_dir)
        self.fps = float(fps)
        self.idle_frames = idle_frames
        self._open: dict[int, _TrcFile] = {}
        self._paths: dict[int, Path] = {}  # every person's file (one per person, not per frame)

    @property
    def paths(self) -> list[Path]:
        return [self._paths[i] for i in sorted(self._paths)]

    def add(self, people: People3D) -> None:
        """One frame's people (frames in increasing order)."""
        for p in range(len(people)):
            i = int(people.ids[p])
            f = self._open.get(i)
            if f is None:
                path = self._paths.get(i)
                if path is None:
                    path = self._paths[i] = self.out_dir / f"person_{i}.trc"
                    f = _TrcFile.create(path, self.fps, people.frame)
                else:
                    f = _TrcFile.reopen(path, self.fps)
                self._open[i] = f
            f.append(people.frame, people.joints[p])
        idle = self.idle_frames
        for i, f in list(self._open.items()):
            if idle is not None and people.frame - f.last > idle:
                f.close()
                del self._open[i]
            elif f.last == people.frame:
                f.flush()

    def close(self) -> list[Path]:
        """Close every file; the paths written, by person id."""
        for f in self._open.values():
            f.close()
        self._open.clear()
        return self.paths


class CsvExporter:
    """Streams frame, t, id, joint, x, y, z, conf rows, flushed every frame."""

    HEADER = ("frame", "t", "id", "joint", "x", "y", "z", "conf")

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self._f = open_output(self.path, "CSV", newline="")
        self._w = csv.writer(self._f, lineterminator="\n")
        self._w.writerow(self.HEADER)

    def add(self, people: People3D) -> None:
        t = round(people.time(self.fps), 6)
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
