"""A live camera's decoder in a process of its own (the child side of io.stream_process).

The process opens the stream with OpenCV's FFmpeg, takes every frame that arrives (``grab``)
and converts the one the service asked for (``want``) to a BGR image in shared memory, in one
of two slots in turn, telling the service over a pipe. A segmentation fault, an abort or a hang
inside FFmpeg on a corrupt or hostile stream then ends or stops this process only: the service
sees its pipe close or fall silent, says the camera is down, and starts another.

Messages to the service, each a tuple:
- ("opened", fps, width, height): the stream opened (fps 0: unknown);
- ("memory", name, height, width): the shared memory of two frame slots, made at the first frame
  and again when the frames' size changes; the service unlinks it (this process may be killed
  before it could);
- ("frame", slot, arrived, grabbed): the asked-for image is in `slot`; arrived: its time on
  time.monotonic(); grabbed: frames taken so far;
- ("alive", grabbed, last): every ALIVE_S while frames come (last: the newest frame's time);
- ("ended", reason): the stream failed or closed; the process then exits.

Only NumPy and OpenCV are imported here: the process starts in a fraction of a second.
"""

from __future__ import annotations

import os
import time
from multiprocessing import shared_memory

os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # as in the service (io.video)
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from multiprocessing.synchronize import Event as EventType

# OpenCV's own warnings (a refused connection, at each try) stay out of the journal, as in
# the service: the service logs what the decoder tells it
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)

ALIVE_S = 0.25  # the service is told frames still come at least this often


def decode(url: str, params: list[int], conn: Connection, want: EventType, stop: EventType) -> None:
    """The process's body: url, params (cv2.VideoCapture's open parameters), conn (the pipe's
    sending end), want and stop (multiprocessing Events set by the service)."""
    cap = cv2.VideoCapture(url, cv2.CAP_FFMPEG, params)
    memory: shared_memory.SharedMemory | None = None
    try:
        if not cap.isOpened():
            conn.send(("ended", "not opened"))
            return
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        conn.send(("opened", float(cap.get(cv2.CAP_PROP_FPS) or 0.0), w, h))
        grabbed, slot, told, shape = 0, 1, 0.0, None
        slots: np.ndarray | None = None
        while not stop.is_set():
            if not cap.grab():
                conn.send(("ended", "stream failed or closed"))
                return
            now = time.monotonic()
            grabbed += 1
            if want.is_set():
                ok, image = cap.retrieve()
                if not ok or image is None:
                    conn.send(("ended", "a frame could not be decoded"))
                    return
                want.clear()
                if image.shape != shape:  # the first frame, or the stream's size changed
                    if memory is not None:
                        memory.close()  # the service unlinks it (it owns every one made)
                    shape = image.shape
                    memory = shared_memory.SharedMemory(create=True, size=2 * image.nbytes)
                    slots = np.ndarray((2, *shape), np.uint8, buffer=memory.buf)
                    conn.send(("memory", memory.name, shape[0], shape[1]))
                slot = 1 - slot
                assert slots is not None
                slots[slot] = image
                conn.send(("frame", slot, now, grabbed))
                told = now
            elif now - told >= ALIVE_S:
                conn.send(("alive", grabbed, now))
                told = now
    except (BrokenPipeError, EOFError, OSError):  # the service went away: nothing to tell
        return
    finally:
        cap.release()
        if memory is not None:
            memory.close()
