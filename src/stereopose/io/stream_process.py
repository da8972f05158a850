"""A live camera decoded in a process of its own: a crash of FFmpeg blinds that camera alone.

`ProcessStream` is io.stream.LiveStream with its reading moved into a child process
(io.decoder: OpenCV's FFmpeg, the asked-for frames handed over in shared memory). The service's
thread for the camera follows the child over a pipe, copies each asked-for image out of shared
memory once, and watches it:
- the child dies (a segmentation fault, an abort, killed): its pipe closes, the camera is lost
  at once and a new child is started after the backoff;
- the child falls silent for twice `timeout_s` and a second (FFmpeg's own timeouts end an open
  or a read well before): it is hung, killed and started again;
- its resident memory passes `max_mb`: killed and started again.
Each is counted (`decoder_restarts`, by why) and logged with its reason. The other cameras are
other processes: they go on.

The newest-frame-first reading is the in-process one's: every frame is taken, only the frames
a step asked for (`request()`) are converted and handed over. A stream kept encoded for the
clips (packets) stays in-process: it demuxes, it never decodes.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
import time
from multiprocessing import shared_memory
from typing import TYPE_CHECKING

import numpy as np

from stereopose.io.stream import LiveStream, StreamWaits, _capture_params, why_not_open
from stereopose.secrets import redact

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from multiprocessing.process import BaseProcess

    from stereopose.io.packets import PacketRing
    from stereopose.io.source import Clock

logger = logging.getLogger(__name__)

POLL_S = 0.05  # the pipe looked at this often (a dead child is seen within this)
MAX_DECODER_MB = 2048.0  # a decoder's resident memory at most
MEMORY_EVERY_S = 1.0  # its memory read this often
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


class ProcessStream(LiveStream):
    """See the module. max_mb: the decoder's resident memory at most, MB."""

    def __init__(
        self,
        url: str,
        name: str | None = None,
        waits: StreamWaits | None = None,
        *,
        clock: Clock | None = None,
        notify: threading.Event | None = None,
        packets: PacketRing | None = None,
        max_mb: float = MAX_DECODER_MB,
    ) -> None:
        self.max_mb = float(max_mb)
        self.decoder_restarts: dict[str, int] = {}  # why -> times a decoder was replaced
        self.decoder_pid: int | None = None
        self._child_want = None
        if packets is not None:
            raise ValueError("a stream kept encoded (packets) is read in-process")
        super().__init__(url, name, waits or StreamWaits(), clock=clock, notify=notify)

    def request(self) -> None:
        super().request()
        want = self._child_want
        if want is not None:
            want.set()

    def _run(self) -> None:
        delay = self.backoff_s
        while not self._stop.is_set():
            got_frame, problem = self._follow()
            if self._stop.is_set():
                break
            if got_frame:
                delay = self.backoff_s
                self._lost(delay)
                self.problem = problem
            elif problem == "not opened":
                self._waiting(why_not_open(self.url, self.timeout_s), delay)
            else:
                self._waiting(problem, delay)
            if self._stop.wait(delay):
                break
            delay = min(delay * 2, self.max_backoff_s)

    def _follow(self) -> tuple[bool, str]:
        """One decoder process, from its start to its end: whether it gave a frame, and why
        it ended."""
        from stereopose.io.decoder import decode

        ctx = multiprocessing.get_context("spawn")
        recv, send = ctx.Pipe(duplex=False)
        want, stop = ctx.Event(), ctx.Event()
        if self._want.is_set():
            want.set()
        self._child_want = want
        proc = ctx.Process(
            target=decode,
            args=(self.url, _capture_params(self.timeout_s), send, want, stop),
            name=f"decoder-{self.name}",
            daemon=True,
        )
        proc.start()
        send.close()
        self.decoder_pid = proc.pid
        state = _Child(proc)
        try:
            return self._messages(recv, state)
        finally:
            self._child_want = None
            stop.set()
            proc.join(0.5)
            if proc.is_alive():
                proc.kill()
                proc.join(2.0)
            recv.close()
            state.release()

    def _messages(self, recv: Connection, child: _Child) -> tuple[bool, str]:
        got_frame = False
        heard = time.monotonic()
        while not self._stop.is_set():
            if not recv.poll(POLL_S):
                why = child.trouble(heard, 2 * self.timeout_s + 1.0, self.max_mb)
                if why is not None:
                    return got_frame, self._replaced(why)
                continue
            try:
                msg = recv.recv()
            except (EOFError, OSError):  # the pipe closed: the decoder died
                return got_frame, self._replaced(child.death())
            heard = time.monotonic()
            kind = msg[0]
            if kind == "opened":
                if 0 < msg[1] < 1000:
                    self.fps = float(msg[1])
            elif kind == "memory":
                child.attach(msg[1], (msg[2], msg[3]))
            elif kind in ("frame", "alive"):
                got_frame = self._frame(child, msg, got_frame)
            elif kind == "ended":
                return got_frame, str(msg[1])
        return got_frame, "stopped"

    def _frame(self, child: _Child, msg: tuple, got_frame: bool) -> bool:
        """A frame message ("frame", slot, arrived, grabbed) or ("alive", grabbed, last)."""
        frame = msg[0] == "frame"
        grabbed = int(msg[3] if frame else msg[1])
        now = float(msg[2])
        new = max(grabbed - child.grabbed, 0)
        child.grabbed = grabbed
        self.last_frame_at = now
        self.stats.grabbed += new
        if not got_frame:
            self._went_up(now)
        if not frame:
            with self._lock:
                self._seq += new
                self.stats.dropped += new  # arrived while no step wanted a frame
            return True
        image = child.image(int(msg[1]))
        if image is None:
            return True
        self._want.clear()
        self.stats.decoded += 1
        with self._lock:
            self.stats.dropped += max(new - 1, 0)
            if self._latest is not None and self._read_seq < self._latest[0]:
                self.stats.dropped += 1
            self._seq += new
            self._latest = (self._seq, self.clock.since(now), image)
            self.shape = image.shape[:2]
        if self._notify is not None:
            self._notify.set()
        return True

    def _replaced(self, why: str) -> str:
        """A decoder that died, hung or grew too large: counted and logged."""
        kind = why.split(":")[0]
        self.decoder_restarts[kind] = self.decoder_restarts.get(kind, 0) + 1
        logger.warning(
            "camera %s (%s): %s; its decoder is started again", self.name, redact(self.url), why
        )
        return why


class _Child:
    """What the service holds of one decoder process: its shared memory, its frames taken."""

    def __init__(self, proc: BaseProcess) -> None:
        self.proc = proc
        self.grabbed = 0
        self._memory: shared_memory.SharedMemory | None = None
        self._slots: np.ndarray | None = None
        self._checked = time.monotonic()

    def attach(self, name: str, size: tuple[int, int]) -> None:
        self.release()  # a new size: the old memory is done with
        self._memory = shared_memory.SharedMemory(name=name)
        self._slots = np.ndarray((2, size[0], size[1], 3), np.uint8, buffer=self._memory.buf)

    def image(self, slot: int) -> np.ndarray | None:
        """The image in `slot`, copied out (the decoder writes the slot again two frames on)."""
        if self._slots is None or slot not in (0, 1):
            return None
        return np.array(self._slots[slot])

    def release(self) -> None:
        """The shared memory closed and removed (the decoder may have been killed before it
        could)."""
        self._slots = None
        if self._memory is not None:
            self._memory.close()
            with contextlib.suppress(FileNotFoundError):
                self._memory.unlink()
            self._memory = None

    def death(self) -> str:
        self.proc.join(1.0)
        code = self.proc.exitcode
        if code is not None and code < 0:
            try:
                return f"decoder died: killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"decoder died: killed by signal {-code}"
        return f"decoder died: exit code {code}"

    def trouble(self, heard: float, silent_s: float, max_mb: float) -> str | None:
        """Why the decoder must be replaced now (None: it is well)."""
        if not self.proc.is_alive():
            return self.death()
        now = time.monotonic()
        if now - heard > silent_s:
            return f"decoder hung: nothing from it for {now - heard:.0f} s, killed"
        if now - self._checked >= MEMORY_EVERY_S:
            self._checked = now
            pid = self.proc.pid  # a started process's
            mb = _resident_mb(pid) if pid is not None else None
            if mb is not None and mb > max_mb:
                return f"decoder over its memory: {mb:.0f} MB of {max_mb:.0f}, killed"
        return None


def _resident_mb(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * _PAGE / 1e6
    except (OSError, ValueError, IndexError):
        return None
