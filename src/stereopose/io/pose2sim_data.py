"""Demo files of Pose2Sim (BSD-3-Clause): a Qualisys calibration, four videos, checkerboards.

``pose2sim_demo_dir()`` downloads the ``pose2sim`` wheel once with pip, extracts only the demo
calibration and video folders into a cache folder and returns that folder. Run
``python -m stereopose.io.pose2sim_data`` to fetch them ahead of time.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path, PurePosixPath

from stereopose.errors import StereoposeError

logger = logging.getLogger(__name__)

POSE2SIM_VERSION = "0.10.49"
_PREFIX = "Pose2Sim/"
_MEMBERS = (
    "Pose2Sim/Demo_MultiPerson/calibration/",
    "Pose2Sim/Demo_MultiPerson/videos/",
    "Pose2Sim/Demo_SinglePerson/calibration/",
)
_MARKER = ".complete"


def cache_root(cache: Path | None = None) -> Path:
    """``cache``, else $STEREOPOSE_CACHE, else ~/.cache/stereopose."""
    if cache is not None:
        return Path(cache)
    env = os.environ.get("STEREOPOSE_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "stereopose"


def _download_wheel(dest: Path) -> Path:
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        f"pose2sim=={POSE2SIM_VERSION}",
        "-d",
        str(dest),
    ]
    logger.info("downloading pose2sim %s: %s", POSE2SIM_VERSION, " ".join(cmd))
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    except OSError as e:
        raise StereoposeError(f"cannot run pip to download pose2sim: {e}") from None
    wheels = sorted(dest.glob("pose2sim-*.whl"))
    if proc.returncode != 0 or not wheels:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-5:]
        raise StereoposeError(
            f"downloading pose2sim=={POSE2SIM_VERSION} with pip failed (exit {proc.returncode}); "
            "it needs network access to PyPI. pip said:\n  " + "\n  ".join(tail)
        )
    return wheels[0]


def _extract(wheel: Path, dest: Path) -> int:
    count = 0
    with zipfile.ZipFile(wheel) as zf:
        for info in zf.infolist():
            if info.is_dir() or not info.filename.startswith(_MEMBERS):
                continue
            rel = PurePosixPath(info.filename[len(_PREFIX) :])
            if rel.is_absolute() or ".." in rel.parts:
                raise StereoposeError(f"{wheel}: unsafe member path {info.filename!r}")
            target = dest.joinpath(*rel.parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            with zf.open(info) as src, open(target, "wb") as out:
                shutil.copyfileobj(src, out)
            count += 1
    if count == 0:
        raise StereoposeError(f"{wheel}: no demo files under {', '.join(_MEMBERS)}")
    return count


def pose2sim_demo_dir(cache: Path | None = None) -> Path:
    """Folder with ``Demo_MultiPerson/{calibration,videos}``, ``Demo_SinglePerson/calibration``.

    cache: cache root (default $STEREOPOSE_CACHE or ~/.cache/stereopose); the files go to
    ``<cache>/pose2sim-<version>``. Downloads and extracts on first use.
    """
    root = cache_root(cache)
    target = root / f"pose2sim-{POSE2SIM_VERSION}"
    if (target / _MARKER).is_file():
        return target
    root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=root))
    try:
        wheel = _download_wheel(work / "wheel")
        staged = work / "files"
        n = _extract(wheel, staged)
        wheel.unlink()
        (staged / _MARKER).write_text(f"pose2sim {POSE2SIM_VERSION}: {n} files\n")
        if target.exists():  # an earlier, interrupted extraction
            shutil.rmtree(target)
        os.replace(staged, target)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    logger.info("pose2sim demo files in %s", target)
    return target


def main() -> None:
    """Fetch the demo files and print their folder."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        print(pose2sim_demo_dir())
    except StereoposeError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(1) from None


if __name__ == "__main__":
    main()
