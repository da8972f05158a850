"""Several cameras read in step (io.video's sources), one FrameSet per time step.

Beyond io.video's rules (alignment, live newest frames, first-frame wait):

- ``loop``: recorded cameras played for ever, forward then backward (io.looping), all over the
  same length (the shortest camera's), so they turn in step;
- ``detect``: per camera an optional second source, a low-resolution substream, read in step
  with the camera's own (the full one, for clips); its frames go in ``FrameSet.detect``;
- ``packets``: per camera with a live substream, a ring (io.packets.PacketRing) that its full
  stream is kept in, encoded, never decoded; its FrameSet image is then the substream's frame
  (smaller than the calibration's size), so clips and pictures come from the substream;
- ``detect_fps``: at most this many steps per second (recorded: of the files' time, the frames
  in between passed over without decoding; live: of wall-clock time, and a live camera converts
  to an image only the frame a step asked for);
- ``wall_clock``: recorded files stamped as live frames are: a step's t is when its frames were
  read, seconds on the set's clock (strictly increasing), so wall time = clock.start_epoch + t
  (a service plays its files as live cameras; a run on files keeps frame / fps);
- ``read_ahead``: recorded cameras (not on the wall clock) decoded this many steps ahead on a
  thread of their own (io.readahead) while the caller works on the current step: the same
  steps in their order; close() stops and joins that thread before any reader is closed.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

from stereopose.io.packets import PacketRing
from stereopose.io.readahead import ReadAhead
from stereopose.io.source import JOIN_S, Clock, SourceStats, VideoError, check_fps, source_name
from stereopose.io.stream import LiveStream, StreamWaits
from stereopose.io.video import (
    FrameSet,
    ImageFolder,
    Source,
    VideoFile,
    _check_timeouts,
    is_stream,
    open_source,
)

logger = logging.getLogger(__name__)

GATHER_S = 0.2  # after a step's first live frame, how long the others are waited for
RECENT_S = 1.0  # a live camera whose newest frame is older than this is not waited for


def _per_camera(value: object, n: int, what: str) -> list:
    if value is None or isinstance(value, (bool, str)):
        return [value] * n
    if not isinstance(value, Iterable):
        raise VideoError(f"{what}: one value, or one value per camera, not {value!r}")
    values = list(value)
    if len(values) != n:
        raise VideoError(f"{len(values)} {what} values for {n} cameras")
    return values


Recording = VideoFile | ImageFolder  # a recorded camera's reader


def _recordings(sources: Sequence[Source]) -> list[Recording]:
    """The recorded cameras' readers of `sources` (all of a recorded set's)."""
    return [s for s in sources if not isinstance(s, LiveStream)]


def _streams(sources: Sequence[Source]) -> list[LiveStream]:
    """The live streams of `sources` (all of a live set's)."""
    return [s for s in sources if isinstance(s, LiveStream)]


def _packets_only(s: Source) -> bool:
    return isinstance(s, LiveStream) and s.packets is not None


class CameraSet:
    """Several cameras read in step; iterate for FrameSets; close() ends every reader.

    open_timeout_s: a live stream's open and read timeout; first_frame_timeout_s: how long
    opening live cameras waits for the first frame of any of them (None: for ever; Ctrl-C
    ends the wait). clock: the live frames' time origin (None: read when the set is created;
    a service gives its own, read when it was built).
    loop (one for all, or per camera), detect (per camera: a substream, or None / ""),
    detect_fps: see the module's docstring. decoders: "process" decodes each live stream in a
    process of its own (io.stream_process). wait_first_frame=False: opening does not wait for
    a first frame (a service starts at once and reports its blind cameras). wall_clock: see the
    module's docstring.
    """

    def __init__(
        self,
        specs: Sequence[str | Path],
        names: Sequence[str] | None = None,
        sync: str = "index",
        fps: float | None = None,
        max_frames: int | None = None,
        *,
        open_timeout_s: float = 5.0,
        first_frame_timeout_s: float | None = 30.0,
        loop: bool | Sequence[bool] = False,
        detect: Sequence[str | Path | None] | None = None,
        detect_fps: float | None = None,
        wait_first_frame: bool = True,
        packets: Mapping[str, PacketRing] | None = None,
        wall_clock: bool = False,
        read_ahead: int = 0,
        decoders: str = "thread",
        clock: Clock | None = None,
    ) -> None:
        if not specs:
            raise VideoError("no camera sources given")
        if names is not None and len(names) != len(specs):
            raise VideoError(f"{len(names)} camera names for {len(specs)} sources")
        names = list(names) if names is not None else [source_name(str(s)) for s in specs]
        if len(set(names)) != len(names):
            raise VideoError(f"camera names must be unique, got {', '.join(names)}; use --names")
        if sync not in ("index", "time"):
            raise VideoError(f"sync must be 'index' or 'time', got {sync!r}")
        fps = check_fps(fps, "fps (time steps per second)")
        self.detect_fps = check_fps(detect_fps, "detect_fps (detection steps per second)")
        _check_timeouts(open_timeout_s, first_frame_timeout_s)
        if max_frames is not None and max_frames < 0:
            raise VideoError(f"max_frames must be at least 0, got {max_frames}")
        loops = [bool(x) for x in _per_camera(loop, len(specs), "loop")]
        substreams = [str(x) if x else None for x in _per_camera(detect, len(specs), "detect")]
        self.sync, self.max_frames = sync, max_frames
        self.wall_clock = bool(wall_clock)
        self.read_ahead = int(read_ahead)
        self.decoders = decoders
        self._ahead: ReadAhead[FrameSet] | None = None
        self.first_frame_timeout_s = first_frame_timeout_s
        self.clock = clock or Clock.now()
        self._fresh = threading.Event()  # set by a live camera at each new image
        self._closing = threading.Event()
        self.sources: list[Source] = []
        self.detect_sources: dict[str, Source] = {}
        try:
            for spec, name, lp, sub in zip(specs, names, loops, substreams, strict=False):
                ring = (packets or {}).get(name) if sub is not None else None
                self.sources.append(self._open(spec, name, fps, lp, open_timeout_s, ring))
                if sub is not None:
                    self.detect_sources[name] = self._open(sub, name, fps, lp, open_timeout_s)
            self._check_kinds()
            if self.live and wait_first_frame:
                self._wait_first_frame()
        except BaseException:  # the error, or Ctrl-C: no camera thread is left running
            self.close()
            raise
        self.loop = any(loops)
        self._loop_in_step()
        rates = [s.fps for s in self.sources if s.fps]
        self.fps = float(fps or (rates[0] if rates else 25.0))
        self._ended: set[str] = set()
        self._ended_ids: set[int] = set()  # readers ended, substreams included

    def _open(
        self,
        spec: str | Path,
        name: str,
        fps: float | None,
        loop: bool,
        timeout: float,
        packets: PacketRing | None = None,
    ) -> Source:
        if self.decoders == "process" and is_stream(str(spec)) and packets is None:
            from stereopose.io.stream_process import ProcessStream

            if loop:
                raise VideoError(
                    f"camera {name}: loop is for recorded files, {spec} is a live stream"
                )

            waits = StreamWaits(timeout_s=timeout)
            return ProcessStream(str(spec), name, waits, clock=self.clock, notify=self._fresh)
        source = open_source(
            spec,
            name,
            fps,
            clock=self.clock,
            notify=self._fresh,
            open_timeout_s=timeout,
            loop=loop,
            packets=packets if is_stream(str(spec)) else None,
        )
        if loop and source.live:
            source.close()
            raise VideoError(f"camera {name}: loop is for recorded files, {spec} is a live stream")
        return source

    def _check_kinds(self) -> None:
        every = self.all_sources
        self.live = any(s.live for s in every)
        if self.live and not all(s.live for s in every):
            raise VideoError("mixing live streams with recorded files is not supported")

    def _loop_in_step(self) -> None:
        """Looped cameras play the same length: the shortest one's (in frames, or in time
        when aligned by time)."""
        looped = [s for s in _recordings(self.all_sources) if s.loop]
        if not looped:
            return
        if self.sync == "index":
            n = min(s.count or 0 for s in looped)  # a looped file knows its length
            for s in looped:
                s.set_period(n)
            return
        period_s = min((s.count or 0) / s.fps for s in looped)
        for s in looped:
            s.set_period(max(1, round(period_s * s.fps)))

    @property
    def all_sources(self) -> list[Source]:
        """Every reader: the cameras' own, then their detection substreams."""
        return [*self.sources, *self.detect_sources.values()]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.sources]

    @property
    def rate(self) -> float:
        """Steps per second of source time (recorded) or at most (live)."""
        return min(self.fps, self.detect_fps) if self.detect_fps else self.fps

    @property
    def count(self) -> int | None:
        """Number of steps of a recorded set (longest camera), or None if unknown, looped or
        live."""
        if self.live or self.loop:
            return None
        known = [(s.count, s.fps) for s in _recordings(self.sources) if s.count is not None]
        if len(known) < len(self.sources):
            return None
        if self.sync == "index":
            n = math.ceil(max(c for c, _ in known) * self.rate / self.fps)
        else:
            n = max(math.ceil(c / fps * self.rate) for c, fps in known)
        return min(n, self.max_frames) if self.max_frames else n

    def __iter__(self) -> Iterator[FrameSet]:
        if self.live:
            return self._live()
        if self.read_ahead and not self.wall_clock:  # decoded on a thread, joined by close()
            if self._ahead is not None:
                self._ahead.close()
            self._ahead = ReadAhead(self._recorded(), self.read_ahead, "camera-read-ahead")
            return self._ahead
        return self._recorded()

    # recorded

    def _recorded(self) -> Iterator[FrameSet]:
        half = 0.5 / self.fps
        step = 0
        last_read = -math.inf  # wall_clock: the last step's time
        while self.max_frames is None or step < self.max_frames:
            if self._closing.is_set():
                return
            t_step = step / self.rate
            # index alignment: the first frame at or after the step's time, on the set's rate
            index = math.ceil(t_step * self.fps - 1e-9)
            t = index / self.fps if self.sync == "index" else t_step
            images: dict[str, np.ndarray | None] = {}
            detect: dict[str, np.ndarray | None] = {}
            frames: dict[str, int] = {}
            times: dict[str, float] = {}
            for s in _recordings(self.sources):
                item = self._take(s, index, t, half)
                images[s.name] = None if item is None else item[2]
                if item is not None and item[2] is not None:
                    frames[s.name] = item[0]
                    times[s.name] = item[1]
                sub = self.detect_sources.get(s.name)
                if sub is not None and not isinstance(sub, LiveStream):
                    got = self._take(sub, index, t, half)
                    detect[s.name] = None if got is None else got[2]
            if not frames and len(self._ended) == len(self.sources):
                return
            number = index if self.sync == "index" else round(t * self.fps)
            if self.wall_clock:  # when the frames were read, as a live camera's arrival
                t = last_read = max(self.clock.since(time.monotonic()), last_read + 1e-4)
            yield FrameSet(number, t, images, frames, times, detect)
            step += 1

    def _take(self, s: Recording, index: int, t: float, half: float) -> tuple | None:
        """A recorded camera's frame for this step, the frames before it passed over without
        decoding: by index, frame `index`; by time, the last one with time in
        [t - half, t + half). None where it has none (or has ended)."""
        if id(s) in self._ended_ids:
            return None
        item = None
        if self.sync == "index":
            while s.index < index:
                if not s.skip():
                    break
            if s.index == index:
                item = s.read()
        else:
            step_s = 1.0 / s.fps
            while (nt := s.next_time()) is not None and nt < t + half:
                if nt < t - half or nt + step_s < t + half:  # another frame is nearer: pass
                    if not s.skip():
                        break
                    continue
                item = s.read()
                break
        if (item is None and s.next_time() is None) or (item is None and self.sync == "index"):
            self._end(s)
        return item

    def _end(self, s: Recording) -> None:
        self._ended_ids.add(id(s))
        if s in self.sources:
            self._ended.add(s.name)
        logger.info("camera %s: end of %s after %d frames", s.name, s.path, s.stats.frames)

    # live

    def _live(self) -> Iterator[FrameSet]:
        step = 0
        last_t = -math.inf
        next_at = time.monotonic()
        while self.max_frames is None or step < self.max_frames:
            if self.detect_fps and self._closing.wait(max(0.0, next_at - time.monotonic())):
                return
            started = time.monotonic()
            for s in _streams(self.all_sources):
                s.request()
            got = self._gather()
            if got is None:
                return
            images: dict[str, np.ndarray | None] = {}
            detect: dict[str, np.ndarray | None] = {}
            frames: dict[str, int] = {}
            times: dict[str, float] = {}
            for s in self.sources:
                mine, sub = got.get(id(s)), got.get(id(self.detect_sources.get(s.name)))
                images[s.name] = None if mine is None else mine[2]
                if s.name in self.detect_sources:
                    detect[s.name] = None if sub is None else sub[2]
                    if _packets_only(s):  # the picture of a camera kept encoded
                        images[s.name] = detect[s.name]
                first = sub or mine  # the time of the frame detection uses
                if first is not None:
                    frames[s.name] = first[0]
                    times[s.name] = first[1]
            if not times:  # only a camera's full stream came, its substream did not
                continue
            # strictly increasing, also when a camera's frame arrived just before the last step's
            last_t = max(max(times.values()), last_t + 1e-4)
            yield FrameSet(step, last_t, images, frames, times, detect)
            step += 1
            if self.detect_fps:
                next_at = started + 1.0 / self.detect_fps

    def _gather(self) -> dict[int, tuple] | None:
        """The images asked for: every recently delivering camera's, or those that came
        within GATHER_S of the first; None when the set is closed."""
        got: dict[int, tuple] = {}
        deadline = None
        while not self._closing.is_set():
            self._fresh.clear()  # before reading, so that an image arriving after is waited for
            now = time.monotonic()
            waited = []
            for s in _streams(self.all_sources):
                if _packets_only(s):  # never gives an image
                    continue
                if id(s) not in got and (item := s.latest()) is not None:
                    got[id(s)] = item
                recent = s.last_frame_at is not None and now - s.last_frame_at < RECENT_S
                if recent and s.connected and id(s) not in got:
                    waited.append(s)
            if got and not waited:
                return got
            if got:
                deadline = deadline or now + GATHER_S
                if now >= deadline:
                    return got
            else:
                self._check_first_frame()
            self._fresh.wait(0.05 if got else 0.25)
        return None

    def _wait_first_frame(self) -> None:
        """Wait until a live camera delivers, or first_frame_timeout_s passes (VideoError)."""
        while not any(s.delivered for s in _streams(self.sources)):
            self._check_first_frame()
            self._fresh.wait(0.25)
        logger.info("cameras opened; first frame after %.1f s", time.monotonic() - self.clock.start)

    def _check_first_frame(self) -> None:
        """A VideoError naming every camera once first_frame_timeout_s has passed since the
        set was opened without any camera delivering a frame."""
        limit = self.first_frame_timeout_s
        streams = _streams(self.all_sources)
        if limit is None or any(s.delivered for s in streams):
            return
        if time.monotonic() - self.clock.start < limit:
            return
        why = "; ".join(f"{s.label}: {s.problem}" for s in streams)
        raise VideoError(
            f"no camera delivered a frame within {limit:g} s ({why}); "
            "a run's [input] first_frame_timeout_s sets how long to wait"
        )

    def end(self) -> None:
        """End the iteration: a step being waited for is not (a pipeline's thread stops);
        the readers stay open until close()."""
        self._closing.set()

    def stats(self) -> dict[str, SourceStats]:
        """Each camera's reader statistics (its own source; substreams: detect_stats)."""
        return {s.name: s.stats for s in self.sources}

    def delivering(self, name: str, within_s: float) -> bool:
        """Whether camera `name`'s reader has a frame to give: a live stream not known lost
        (its decoder process dead, say) whose newest frame came within `within_s` seconds; a
        recorded file has not ended. (A service whose steps are late while its readers
        deliver is itself late, not its cameras.)"""
        for s in self.sources:
            if s.name != name:
                continue
            if not s.live:
                return id(s) not in self._ended_ids
            if not isinstance(s, LiveStream) or not s.connected:
                return False
            last = s.last_frame_at
            return last is not None and time.monotonic() - last < within_s
        return False

    def lost(self, name: str) -> bool:
        """Whether camera `name` is known lost now: the live stream its steps are detected on
        (its substream where it has one, else its own) delivered, then was lost, and is not
        back. (A full stream kept for the clips, lost while its substream delivers, leaves
        the camera seen.)"""
        source = self.detect_sources.get(name)
        if source is None:
            source = next((s for s in self.sources if s.name == name), None)
        return isinstance(source, LiveStream) and source.lost

    def detect_stats(self) -> dict[str, SourceStats]:
        return {name: s.stats for name, s in self.detect_sources.items()}

    def close(self) -> None:
        """Close every camera; live ones are all stopped first, then waited for together, at
        most JOIN_S in all."""
        self._closing.set()
        if self._ahead is not None:  # no reader reads once the sources close
            self._ahead.close()
        every = self.all_sources
        live = _streams(every)
        for s in live:
            s.stop()
        deadline = time.monotonic() + (JOIN_S if live else 0.0)
        for s in every:
            if isinstance(s, LiveStream):
                s.close(max(0.0, deadline - time.monotonic()))
            else:
                s.close()

    def __enter__(self) -> CameraSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
