"""Demo files of Pose2Sim (BSD-3-Clause): a Qualisys calibration, two real 4-camera
recordings of the same rig (Demo_MultiPerson: three people; Demo_SinglePerson: one walking),
checkerboards. The wheel's Demo_Batch trials are byte-for-byte copies of these two recordings
(Trial_1 of Demo_SinglePerson, Trial_2 of Demo_MultiPerson) and are not extracted.

``pose2sim_demo_dir()`` downloads the ``pose2sim`` wheel once with pip, extracts only the demo
calibration and video folders into a cache folder and returns that folder. Run
``python -m stereopose.io.pose2sim_data`` to fetch them ahead of time.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import tempfile
from pathlib import Path

from stereopose.cache import cache_root, download_wheel, extract_members
from stereopose.errors import StereoposeError

logger = logging.getLogger(__name__)

POSE2SIM_VERSION = "0.10.49"
_PREFIX = "Pose2Sim/"
_MEMBERS = (
    "Pose2Sim/Demo_MultiPerson/calibration/",
    "Pose2Sim/Demo_MultiPerson/videos/",
    "Pose2Sim/Demo_SinglePerson/calibration/",
    "Pose2Sim/Demo_SinglePerson/videos/",
)
_MARKER = ".complete"


def _complete(target: Path) -> bool:
    """Extracted, with every member folder (an older cache may lack a newer one)."""
    return (target / _MARKER).is_file() and all(
        (target / m[len(_PREFIX) :]).is_dir() for m in _MEMBERS
    )


def pose2sim_demo_dir(cache: Path | None = None) -> Path:
    """Folder with ``Demo_MultiPerson`` and ``Demo_SinglePerson``, each with its
    ``calibration`` and ``videos``.

    cache: cache root (default $STEREOPOSE_CACHE or ~/.cache/stereopose); the files go to
    ``<cache>/pose2sim-<version>``. Downloads and extracts on first use.
    """
    root = cache_root(cache)
    target = root / f"pose2sim-{POSE2SIM_VERSION}"
    if _complete(target):
        return target
    root.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=root))
    try:
        wheel = download_wheel(f"pose2sim=={POSE2SIM_VERSION}", work / "wheel")
        staged = work / "files"
        n = extract_members(wheel, _MEMBERS, _PREFIX, staged)
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
