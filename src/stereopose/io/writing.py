"""Opening an output file: its folder made, a failure a clear error naming the file; and the
checks, made before any work, that an output written later can be written at all."""

from __future__ import annotations

import errno
import os
import sqlite3
import tempfile
from pathlib import Path
from typing import IO

from stereopose.errors import OutputError, StereoposeError

# what an output's write or close raises when the output, not the run, is at fault: the disk,
# the folder, the database (StereoposeError: a writer's own message naming its file)
OUTPUT_FAILURES: tuple[type[BaseException], ...] = (OSError, StereoposeError, sqlite3.Error)


def reason(e: BaseException) -> str:
    """The short reason of an output failure ("No space left on device")."""
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return str(e) or type(e).__name__


def make_folder(folder: Path) -> None:
    """`folder` and its parents made; a file where a folder should be is named (mkdir itself
    says only "File exists")."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        above = next(p for p in (folder, *folder.parents) if p.exists())
        raise NotADirectoryError(
            errno.ENOTDIR, f"{above} is a file, not a folder", str(folder)
        ) from None


def open_output(path: Path, what: str, newline: str | None = None) -> IO[str]:
    """`path` opened for writing (UTF-8), its parent folders made; an OSError becomes an
    OutputError "<path>: cannot write <what>: <reason>"."""
    try:
        make_folder(path.parent)
        return path.open("w", encoding="utf-8", newline=newline)
    except OSError as e:
        raise OutputError(f"{path}: cannot write {what}: {e.strerror}") from None


def _probe(folder: Path) -> None:
    """A file can be created in `folder` (made if missing): an unnamed temporary file, so
    nothing is left behind. Catches a read-only or vanished folder and a file in its place;
    permissions too, except for root."""
    make_folder(folder)
    with tempfile.TemporaryFile(dir=folder):
        pass


def probe_output(path: str | Path, what: str) -> None:
    """Raise an OutputError now if the file `path`, written later in the run, could not be:
    its folder is made and tried, and a folder in its place is refused."""
    path = Path(path)
    try:
        if path.is_dir():
            raise IsADirectoryError(errno.EISDIR, "a folder is in its place", str(path))
        _probe(path.parent)
    except OSError as e:
        raise OutputError(f"{path}: cannot write {what}: {e.strerror}") from None


def probe_folder(folder: str | Path, what: str) -> None:
    """Raise an OutputError now if files could not be written in `folder` (made if missing)."""
    folder = Path(folder)
    try:
        _probe(folder)
    except OSError as e:
        raise OutputError(f"{folder}: cannot write {what}: {e.strerror}") from None


def write_private(path: Path, data: bytes) -> None:
    """Written atomically (a temporary file renamed over it), readable by its owner only."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o600)
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
