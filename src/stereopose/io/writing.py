"""Opening an output file: its folder made, a failure a clear error naming the file."""

from __future__ import annotations

from pathlib import Path
from typing import IO

from stereopose.errors import StereoposeError


def open_output(path: Path, what: str, newline: str | None = None) -> IO[str]:
    """`path` opened for writing (UTF-8), its parent folders made; an OSError becomes a
    StereoposeError "<path>: cannot write <what>: <reason>"."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return path.open("w", encoding="utf-8", newline=newline)
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write {what}: {e.strerror}") from None
