"""Native faults logged: `faulthandler` writes the Python stack of every thread to standard
error (the journal under systemd) on a segmentation fault, an abort (systemd's watchdog kills a
hung service with SIGABRT) or a bus error in native code (FFmpeg, ONNX Runtime, OpenVINO),
before the process dies. Every command turns it on first (cli.main); nothing heavy is imported
here, so a command's early errors still come before the 3D stage loads."""

from __future__ import annotations

import faulthandler
import logging
import sys

logger = logging.getLogger(__name__)


def log_native_faults() -> None:
    """The Python stack of every thread written to standard error on a native fault."""
    if not faulthandler.is_enabled():
        try:
            faulthandler.enable(file=sys.stderr, all_threads=True)
        except (AttributeError, ValueError, OSError) as e:  # stderr closed or not a file
            logger.warning("native faults will not be logged with their stack: %s", e)
