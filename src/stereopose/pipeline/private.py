"""The service's data folder is private: files 0600 and folders 0700 whatever the umask.

`stereopose serve` keeps people's movements (pose segments, clips), the event log, the
console's users and its status in its data folder. Under the systemd unit its UMask keeps
them from other users; started by hand under a usual umask of 022 they would be readable by
every user of the machine. `private_files()` narrows the process's umask to 077 for the
service's life (a stricter one is kept), and `tighten(folder)` takes group and other
permissions off what an earlier run left there.
"""

from __future__ import annotations

import contextlib
import logging
import os
import stat
from collections.abc import Iterator
from pathlib import Path

logger = logging.getLogger(__name__)

PRIVATE = 0o077  # the permission bits of group and others


@contextlib.contextmanager
def private_files() -> Iterator[None]:
    """The umask with PRIVATE added while inside; the previous one restored after."""
    previous = os.umask(PRIVATE)
    os.umask(previous | PRIVATE)
    try:
        yield
    finally:
        os.umask(previous)


def tighten(folder: Path) -> int:
    """Group and other permissions removed from `folder` and everything under it (links
    not followed, nor changed); how many were changed. What cannot be changed (another
    owner's file) is logged once and left."""
    changed, refused = 0, None
    if not folder.is_dir():
        return 0
    paths = [folder]
    for root, dirs, files in os.walk(folder):
        paths += [Path(root, name) for name in (*dirs, *files)]
    for path in paths:
        try:
            st = path.lstat()
            if stat.S_ISLNK(st.st_mode) or not st.st_mode & PRIVATE:
                continue
            os.chmod(path, stat.S_IMODE(st.st_mode) & ~PRIVATE)
            changed += 1
        except FileNotFoundError:  # removed meanwhile (retention of a run still closing)
            continue
        except OSError as e:
            refused = refused or f"{path}: {e.strerror}"
    if refused is not None:
        logger.warning("data folder %s: cannot make every file private (%s)", folder, refused)
    if changed:
        logger.info(
            "data folder %s: %d file(s) and folder(s) made private (0600/0700)", folder, changed
        )
    return changed
