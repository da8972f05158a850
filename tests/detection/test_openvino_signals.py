"""OpenVINO detectors dropped on another thread than the one that made them leave the main
thread able to take signals (detection.openvino_core): OpenVINO's CPU plugin gives the thread
that makes it an alternate signal stack of its own and unmaps it when destroyed, in whichever
thread that is. Before one Core was kept for the process, a detector made on the main thread
and collected on a worker left the main thread's alternate stack unmapped, and the next
Ctrl-C killed the process with a segmentation fault (the test suite's, twice). Run in a child
process, so that a regression kills only it."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("openvino")

CHILD = r"""
import ctypes, gc, signal, sys, threading
from stereopose.detection import make_detector

libc = ctypes.CDLL(None)

class Stack(ctypes.Structure):
    _fields_ = [("sp", ctypes.c_void_p), ("flags", ctypes.c_int), ("size", ctypes.c_size_t)]

def alternate_stack_mapped() -> bool:
    now = Stack()
    libc.sigaltstack(None, ctypes.byref(now))
    if not now.sp or now.flags & 2:  # none, or SS_DISABLE
        return True
    for line in open("/proc/self/maps"):
        lo, hi = (int(x, 16) for x in line.split()[0].split("-"))
        if lo <= now.sp < hi:
            return True
    return False

made = [make_detector("openvino", imgsz=320)]  # on the main thread

def worker():
    made.clear()  # dropped, and collected, here
    gc.collect()
    other = make_detector("openvino", imgsz=320)  # made and dropped on the worker
    del other
    gc.collect()

t = threading.Thread(target=worker)
t.start()
t.join()
print("mapped" if alternate_stack_mapped() else "unmapped", flush=True)
signal.signal(signal.SIGINT, lambda *a: print("handled", flush=True))
signal.raise_signal(signal.SIGINT)
"""


@pytest.mark.slow
def test_a_detector_dropped_on_a_worker_leaves_the_main_thread_its_signals() -> None:
    from stereopose.detection import ModelError
    from stereopose.detection.models import default_onnx

    try:
        default_onnx(export=False)
    except ModelError as e:
        pytest.skip(str(e))
    done = subprocess.run(
        [sys.executable, "-X", "faulthandler", "-c", CHILD],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, f"exit {done.returncode}:\n{done.stdout}\n{done.stderr[-3000:]}"
    assert done.stdout.split() == ["mapped", "handled"]
