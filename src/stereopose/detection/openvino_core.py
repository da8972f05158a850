"""The process's one OpenVINO Core, made at its first use and kept until the process ends.

OpenVINO's CPU plugin (made by a Core for its first CPU model or query, and kept alive by the
Core and by every model compiled with it) gives the thread that makes it a signal alternate
stack of its own (mmap), so that a signal on a thread using AMX has room for its larger
register state. When the plugin is destroyed it unmaps that stack, and puts the previous one
back only if the destroying thread is the one using it. A plugin made on the main thread and
destroyed on another thread (a detector dropped by a worker thread, or collected there by the
garbage collector) therefore leaves the main thread's alternate stack unmapped: the next
signal the main thread handles (Ctrl-C, SIGTERM, SIGHUP: Python's handlers run on the
alternate stack) kills the process with a segmentation fault that no fault handler can report,
since the kernel cannot even write the signal's frame.

One Core for the life of the process makes the plugin once and never destroys it while the
process runs, whatever thread makes or drops the detectors.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import openvino as ov

__all__ = ["cpu_has_bf16", "ov_core"]

_lock = threading.Lock()
_core = None


def ov_core() -> ov.Core:
    """The process's openvino.Core (ImportError without OpenVINO)."""
    global _core
    with _lock:
        if _core is None:
            import openvino as ov

            _core = ov.Core()
        return _core


def cpu_has_bf16() -> bool:
    """Whether OpenVINO finds bfloat16 instructions on this CPU (AVX512_BF16 or AMX)."""
    return "BF16" in ov_core().get_property("CPU", "OPTIMIZATION_CAPABILITIES")
