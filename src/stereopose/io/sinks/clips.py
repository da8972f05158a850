"""Event clips: for each alarm, a short MP4 per camera that saw the person, from `pre_s`
before the event to `post_s` after it, in `clips/<UTC time>_<person>_<zone>_<camera>.mp4`.

The frame loop only hands each frame over (a bounded queue: a frame that finds it full is
dropped and counted; its events are kept). A buffer thread draws each camera's frame (`draw`,
e.g. viz.clips.clip_drawer: skeletons and ids), JPEG-encodes it and keeps the last `pre_s`
seconds per camera, bounded by count and by bytes (the oldest dropped and counted). An alarm
opens a clip on each camera that saw its person, starting with what the buffer holds; a later
alarm on a camera whose clip is still open extends that clip (to `clip_max_s` at most), so
events close together share one clip and no frame is written twice. A writer thread encodes
the clips as `<name>.part.mp4`, checks that the file decodes, and renames it to `<name>.mp4`
(never over an existing file). A clip that cannot be written (disk full, folder gone) is
logged (once per spell), counted and removed; later clips are tried again.

A camera whose full stream is kept encoded (io.packets: it has a detection substream) gets its
clip drawn on the substream's frames, at the same size as a full one's, and beside it
`<name>.full.mp4`: its full stream over the same span, a stream copy (no re-encoding, nothing
drawn), from the keyframe before the clip's start, written as the clip goes on (so a clip
extended by later alarms has all of it). A copy that cannot be written is logged and counted
(copies_failed) and leaves its drawn clip alone.

Times are the frames' own (`FrameResult.t`); names use wall time `wall_start + t` (UTC). The
clip's frame rate is the run's `fps`, so its duration is its frame count / fps.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from stereopose.errors import StereoposeError
from stereopose.io.datafolder import CLIPS_DIR
from stereopose.io.mp4 import FrameWriter
from stereopose.io.packets import PacketRing, StreamCopy
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.sinks.clip_parts import (
    CLIP_SUFFIX,
    EPS,
    FULL_SUFFIX,
    MAX_TWINS,
    PART_SUFFIX,
    ClipSettings,
    Draw,
    FrameRing,
    OpenClip,
    clip_name,
    is_alarm,
    plain_picture,
)
from stereopose.io.writing import make_folder, probe_folder, reason
from stereopose.types import Event, People2D, People3D

__all__ = [
    "CLIP_SUFFIX",
    "FULL_SUFFIX",
    "PART_SUFFIX",
    "ClipSettings",
    "ClipSink",
    "Draw",
    "clip_name",
    "is_alarm",
]

logger = logging.getLogger(__name__)


class ClipSink(ClosesOnce):
    """Event clips in `<out_dir>/clips/` (see the module).

    cameras: the rig's camera names in order (People3D.detections' columns: who saw whom);
    fps: the clips' frame rate; wall_start: the Unix time of t = 0; draw: how a kept frame is
    drawn (default: the image alone, scaled); alarm: which events make clips. `close` returns
    the clips written. Counted: frames_dropped (the frame queue was full), buffer_dropped (a
    camera's buffer was full), clips_written, clips_failed, errors (frames that could not be
    drawn or encoded).
    """

    stage = "write"

    def __init__(
        self,
        out_dir: str | Path,
        cameras: Sequence[str],
        fps: float,
        *,
        wall_start: float,
        draw: Draw | None = None,
        alarm: Callable[[Event], bool] = is_alarm,
        settings: ClipSettings | None = None,
        packets: Mapping[str, PacketRing] | None = None,
    ) -> None:
        if isinstance(wall_start, bool) or not isinstance(wall_start, (int, float)):
            raise StereoposeError(f"clips: wall_start must be a Unix time, got {wall_start!r}")
        if not math.isfinite(wall_start) or not 0 <= wall_start < 2**33:
            raise StereoposeError(f"clips: wall_start must be a Unix time, got {wall_start!r}")
        if not (isinstance(fps, (int, float)) and math.isfinite(fps) and 0.1 <= fps <= 1000):
            raise StereoposeError(f"clips: fps must be in [0.1, 1000], got {fps!r}")
        self.settings = s = settings or ClipSettings()
        self.folder = Path(out_dir) / CLIPS_DIR
        probe_folder(self.folder, "event clips")
        self.cameras, self.fps, self.wall_start = list(cameras), float(fps), float(wall_start)
        self.draw = draw or (lambda cam, image, p2, p3, scale, label: plain_picture(image, scale))
        self.alarm = alarm
        self.frames_dropped = self.clips_written = self.clips_failed = self.errors = 0
        self.packets = dict(packets or {})
        self.copies_written = self.copies_failed = 0
        self.last_error: str | None = None
        self.incomplete: str | None = None
        self.written: list[Path] = []
        keep = s.clip_pre_s
        self._rings = {
            c: FrameRing(keep, s.clip_buffer_frames, s.clip_buffer_bytes) for c in cameras
        }
        self._open: dict[str, OpenClip] = {}  # camera -> its clip under way (buffer thread)
        self._done_t: dict[str, float] = {}  # camera -> time of the last frame in a clip
        self._frames: queue.Queue = queue.Queue(s.clip_queue_frames)
        self._late: deque[Event] = deque(maxlen=10_000)  # alarms of dropped frames
        self._jobs: queue.Queue = queue.Queue(256)
        self._failing = False  # within a spell of failed clips (logged once)
        self._dropping = False
        self._lock = threading.Lock()
        self._buffer = threading.Thread(target=self._buffer_loop, name="clips-buffer", daemon=True)
        self._writer = threading.Thread(target=self._write_loop, name="clips-writer", daemon=True)
        self._buffer.start()
        self._writer.start()

    @property
    def buffer_dropped(self) -> int:
        return sum(r.dropped for r in self._rings.values())

    # -- the frame loop's side ---------------------------------------------------------------

    def write(self, frame: FrameResult) -> None:
        alarms = tuple(e for e in frame.events if self.alarm(e))
        images = {c: im for c, im in (frame.images or {}).items() if im is not None}
        if not images and not alarms:
            return
        item = (float(frame.t), images, dict(frame.people2d), frame.people3d, alarms)
        try:
            self._frames.put_nowait(item)
        except queue.Full:
            self.frames_dropped += 1
            self._late.extend(alarms)
            if not self._dropping:
                logger.warning(
                    "event clips: the buffer thread is behind; frames dropped (%d so far)",
                    self.frames_dropped,
                )
            self._dropping = True
            return
        self._dropping = False

    # -- the buffer thread -------------------------------------------------------------------

    def _buffer_loop(self) -> None:
        last_t = 0.0
        while True:
            item = self._frames.get()
            if item is None:
                break
            last_t = item[0]
            try:
                self._take(*item)
            except Exception:  # a bug must not stop the clips: logged, counted
                self.errors += 1
                logger.exception("event clips: a frame could not be kept")
        if self._late:  # alarms of frames dropped at the end: clips of what the buffers hold
            self._take(last_t, {}, {}, People3D.empty(0, 0), ())
        for clip in list(self._open.values()):
            self._finish(clip)
        self._jobs.put(None)

    def _take(
        self,
        t: float,
        images: Mapping[str, np.ndarray],
        people2d: Mapping[str, People2D],
        people3d: People3D,
        alarms: Sequence[Event],
    ) -> None:
        stamp = datetime.fromtimestamp(self.wall_start + t, UTC).strftime("%H:%M:%S")
        for camera, image in images.items():
            ring = self._rings.get(camera)
            if ring is None:
                continue
            jpeg = self._encode(camera, image, people2d.get(camera), people3d, f"{camera} {stamp}")
            if jpeg is not None:
                ring.push(t, jpeg)
        late = [self._late.popleft() for _ in range(len(self._late))]
        for e in (*late, *alarms):
            for camera in self._witnesses(e, people3d, images):
                self._alarm(camera, e, t)
        for camera, clip in list(self._open.items()):
            ring = self._rings[camera]
            if ring.frames and ring.frames[-1][0] == t and t > clip.last_t + EPS:
                self._send(clip, [ring.frames[-1]])
            if t >= clip.end_t - EPS:
                self._finish(clip)

    def _encode(
        self, camera: str, image: np.ndarray, p2: People2D | None, p3: People3D, label: str
    ) -> bytes | None:
        try:
            picture = self.draw(camera, image, p2, p3, self.settings.clip_scale, label)
            ok, buf = cv2.imencode(
                ".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, self.settings.clip_jpeg_quality]
            )
        except (cv2.error, ValueError, TypeError) as e:
            self.errors += 1
            logger.debug("event clips: camera %s: frame not kept: %s", camera, e)
            return None
        if not ok:
            self.errors += 1
            logger.debug("event clips: camera %s: frame not kept: not encoded", camera)
            return None
        return buf.tobytes()

    def _witnesses(self, e: Event, people3d: People3D, images: Mapping) -> list[str]:
        """The cameras that saw the event's person at this frame (by the detections used);
        every camera with a frame when that is not known."""
        rows = np.flatnonzero(people3d.ids == e.person)
        det = people3d.detections
        if len(rows) and det.shape[1] == len(self.cameras):
            seen = [c for c, d in zip(self.cameras, det[rows[0]], strict=True) if d >= 0]
            if seen:
                return seen
        return [c for c in self.cameras if c in images or self._rings[c].frames]

    def _alarm(self, camera: str, e: Event, t: float) -> None:
        """Extend the camera's open clip, or open one from what its buffer holds."""
        s = self.settings
        clip = self._open.get(camera)
        if clip is not None and e.t <= clip.end_t + EPS:
            clip.end_t = min(max(clip.end_t, e.t + s.clip_post_s), clip.limit_t)
            clip.events.append(e)
            return
        if clip is not None:
            self._finish(clip)
        done = self._done_t.get(camera, -math.inf)  # frames up to it are in an earlier clip
        frames = [
            f for f in self._rings[camera].since(e.t - s.clip_pre_s) if done + EPS < f[0] <= t + EPS
        ]
        start = frames[0][0] if frames else max(e.t - s.clip_pre_s, done)
        name = clip_name(self.wall_start + e.t, e.person, e.zone, camera)
        limit = start + s.clip_max_s
        clip = OpenClip(camera, name, start, min(e.t + s.clip_post_s, limit), limit, events=[e])
        self._open[camera] = clip
        self._jobs.put(("open", clip))
        if frames:
            self._send(clip, frames)

    def _send(self, clip: OpenClip, frames: list[tuple[float, bytes]]) -> None:
        clip.last_t = frames[-1][0]
        self._done_t[clip.camera] = clip.last_t
        self._jobs.put(("frames", clip, [jpeg for _, jpeg in frames], clip.last_t))

    def _finish(self, clip: OpenClip) -> None:
        self._open.pop(clip.camera, None)
        self._jobs.put(("close", clip))

    # -- the writer thread -------------------------------------------------------------------

    def _write_loop(self) -> None:
        while (job := self._jobs.get()) is not None:
            kind, clip, *rest = job
            if clip.failed:
                continue
            try:
                if kind == "open":
                    self._start(clip)
                elif kind == "frames":
                    self._write_frames(clip, rest[0])
                    self._copy_more(clip, rest[1])
                else:
                    self._end(clip)
            except (OSError, cv2.error, StereoposeError) as e:
                self._clip_failed(clip, e)
            except Exception as e:  # a bug must not stop the writer: that clip is lost
                logger.exception("event clips: %s failed", clip.name)
                self._clip_failed(clip, e)

    def _start(self, clip: OpenClip) -> None:
        make_folder(self.folder)
        for n in range(MAX_TWINS + 1):
            stem = f"{clip.name}_{n:03d}" if n else clip.name
            part = self.folder / (stem + PART_SUFFIX)
            if (self.folder / (stem + CLIP_SUFFIX)).exists():
                continue
            try:
                part.open("xb").close()  # the name is ours
            except FileExistsError:
                continue
            clip.part, clip.name = part, stem
            return
        raise FileExistsError(f"{self.folder}: every name for {clip.name} is taken")

    def _write_frames(self, clip: OpenClip, frames: list[bytes]) -> None:
        part = clip.part
        assert part is not None  # named when the clip was opened
        for jpeg in frames:
            image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
            if image is None:
                continue
            if clip.writer is None:
                clip.writer = FrameWriter(part, self.fps, "the clip")
            clip.writer.write(image)
            clip.frames += 1

    def _end(self, clip: OpenClip) -> None:
        part = clip.part
        assert part is not None  # named when the clip was opened
        if clip.writer is None:  # no frame came: nothing to keep
            part.unlink(missing_ok=True)
            return
        clip.writer.close()
        clip.writer = None
        self._copy_more(clip, clip.last_t)
        cap = cv2.VideoCapture(str(clip.part))
        decoded = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        cap.release()
        if decoded != clip.frames:
            raise StereoposeError(
                f"{clip.part}: {decoded} of {clip.frames} frames decode (disk full?)"
            )
        final = self._publish(clip)
        with self._lock:
            self.written.append(final)
            self.clips_written += 1
        if clip.copy is not None:
            self._finish_copy(clip, final)
        if self._failing:
            logger.warning("event clips written again (%d failed)", self.clips_failed)
            self._failing = False

    def _publish(self, clip: OpenClip) -> Path:
        """The finished part renamed to its clip name, never over another file."""
        part = clip.part
        assert part is not None  # named when the clip was opened
        for n in range(MAX_TWINS + 1):
            final = self.folder / ((f"{clip.name}_{n:03d}" if n else clip.name) + CLIP_SUFFIX)
            try:
                os.link(part, final)
            except FileExistsError:
                continue
            part.unlink()
            return final
        raise FileExistsError(f"{self.folder}: every name for {clip.name} is taken")

    def _copy_part(self, clip: OpenClip) -> Path:
        return self.folder / (clip.name + ".full" + PART_SUFFIX)

    def _copy_more(self, clip: OpenClip, t: float) -> None:
        """The clip's full-stream copy brought up to `t`: opened on the first call, from the
        keyframe before the clip's start; then the packets since the last call."""
        ring = self.packets.get(clip.camera)
        if ring is None or clip.copy_failed or clip.part is None:
            return
        try:
            if clip.copy is None:
                packets = ring.between(clip.start_t, t)
                if ring.format is None or not packets:
                    return  # nothing kept yet: tried again with the clip's next frames
                clip.copy = StreamCopy(self._copy_part(clip), ring.format)
            else:
                packets = ring.after(clip.copy_t, t)
            if packets:
                clip.copy.write(packets)
                clip.copy_t = packets[-1][0]
        except (OSError, cv2.error, StereoposeError) as e:
            self._copy_failed(clip, e)

    def _finish_copy(self, clip: OpenClip, drawn: Path) -> None:
        """The copy closed, checked and named after the drawn clip `drawn`."""
        part = self._copy_part(clip)
        final = self.folder / (drawn.name[: -len(CLIP_SUFFIX)] + FULL_SUFFIX)
        try:
            if clip.copy is not None:
                clip.copy.close()
            os.link(part, final)
            part.unlink()
        except (OSError, cv2.error, StereoposeError) as e:
            self._copy_failed(clip, e)
            return
        clip.copy = None
        with self._lock:
            self.written.append(final)
            self.copies_written += 1

    def _copy_failed(self, clip: OpenClip, e: BaseException) -> None:
        clip.copy_failed = True
        if clip.copy is not None:
            clip.copy.release()
            clip.copy = None
        with contextlib.suppress(OSError):
            self._copy_part(clip).unlink(missing_ok=True)
        self.copies_failed += 1
        logger.warning("event clips: %s: full-stream copy not written (%s)", clip.name, reason(e))

    def _clip_failed(self, clip: OpenClip, e: BaseException) -> None:
        clip.failed = True
        if clip.writer is not None:
            clip.writer.close()
            clip.writer = None
        if clip.copy is not None:
            clip.copy.release()
            clip.copy = None
            with contextlib.suppress(OSError):
                self._copy_part(clip).unlink(missing_ok=True)
        if clip.part is not None:
            try:
                clip.part.unlink(missing_ok=True)
            except OSError as gone:
                logger.debug("%s: cannot remove: %s", clip.part, gone)
        self.clips_failed += 1
        self.last_error = reason(e)
        if not self._failing:
            logger.error(
                "event clips: %s: not written (%s); counted, later clips tried again",
                clip.name,
                self.last_error,
            )
        self._failing = True

    # -- closing -----------------------------------------------------------------------------

    def queued(self) -> int:
        """Frames waiting for the buffer thread."""
        return self._frames.qsize()

    def figures(self) -> dict:
        """status.json's `clips`."""
        return {
            "written": self.clips_written,
            "failed": self.clips_failed,
            "frames_dropped": self.frames_dropped,
            "full_copies_written": self.copies_written,
            "full_copies_failed": self.copies_failed,
        }

    def _close(self) -> list[Path]:
        deadline = time.monotonic() + self.settings.clip_close_timeout_s
        with contextlib.suppress(queue.Full):  # the buffer thread is stuck: joins time out
            self._frames.put(None, timeout=max(0.0, deadline - time.monotonic()))
        for thread in (self._buffer, self._writer):
            thread.join(max(0.0, deadline - time.monotonic()))
        problems = []
        if self._buffer.is_alive() or self._writer.is_alive():
            problems.append("clips still being written at close (left as *.part.mp4)")
        if self.clips_failed:
            problems.append(f"{self.clips_failed} event clip(s) not written ({self.last_error})")
        self.incomplete = "; ".join(problems) or None
        with self._lock:
            return list(self.written)
