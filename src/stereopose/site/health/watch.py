"""Cameras watched: a camera that stops giving frames is itself an alarm.

    watch = CameraWatch(rig.names, timeout_s=config.serve.camera_timeout_s, start=t0)
    watch.frame(name, t_arrival)          # each frame a camera delivers
    events = watch.poll(t, frame)         # once per step, also when no camera gave a frame

`poll` gives `camera_down` once when a camera has had no frame for timeout_s (a camera that
never gave one counts from `start`), and `camera_up` when a frame comes again (duration_s: how
long it was down). Times are seconds on one clock, the frame loop's (injectable: tests step it).
The events (kind "camera", zone "", person -1, `camera` naming it) go through every event sink.

Every camera late at once is first a question for site.health.stall: `overdue(t)` names the
cameras that `poll` would take down at t, so the service can tell its own stall from its
cameras', and `shift(s)` gives the cameras still up the time of a stall back (a stall is not
their silence).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TypedDict, Unpack

from stereopose.types import Event

__all__ = ["CAMERA_KIND", "CameraState", "CameraWatch", "camera_event"]

logger = logging.getLogger(__name__)

CAMERA_KIND = "camera"
NO_PERSON = -1  # camera events concern no person


class CameraFields(TypedDict, total=False):
    """What a camera event may carry beyond its camera and times."""

    duration_s: float | None  # how long it was down (camera_up)
    reprojection_px: float | None  # its reprojection error now (calibration events)
    baseline_px: float | None  # against its baseline
    result: dict | None  # a placement's figures (calibration_corrected)


def camera_event(
    kind_of_event: str,
    camera: str,
    t: float,
    frame: int,
    onset_t: float,
    **fields: Unpack[CameraFields],
) -> Event:
    """An event about a camera (kind "camera", zone "", person -1)."""
    return Event(
        t=t,
        frame=frame,
        person=NO_PERSON,
        zone="",
        kind=CAMERA_KIND,
        type=kind_of_event,
        onset_t=onset_t,
        camera=camera,
        **fields,
    )


@dataclass
class CameraState:
    """One camera as the watch sees it: its last frame's time (None: none yet), down or up, and
    when it went down (its last frame, or the start)."""

    last_t: float | None = None
    down: bool = False
    quiet_since: float = 0.0
    frames: int = 0


class CameraWatch:
    """Per camera the time of its last frame; `poll` turns silences into events."""

    def __init__(self, names: Iterable[str], timeout_s: float, start: float = 0.0) -> None:
        """names: the cameras; timeout_s (> 0): silence that makes a camera down; start: the
        time the watch starts, on the clock of `frame` and `poll`."""
        if not (timeout_s > 0 and math.isfinite(timeout_s)):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s}")
        self.timeout_s, self.start = float(timeout_s), float(start)
        self.cameras = {n: CameraState(quiet_since=self.start) for n in names}
        self._came_back: dict[str, float] = {}  # camera -> arrival of its first frame back
        self._lost: set[str] = set()  # cameras whose stream is known lost (down at the next poll)

    def frame(self, name: str, t_arrival: float) -> None:
        """Camera `name` delivered a frame at t_arrival."""
        st = self.cameras.get(name)
        if st is None:
            raise KeyError(f"camera {name!r} is not watched (cameras: {', '.join(self.cameras)})")
        self._lost.discard(name)
        if st.down and name not in self._came_back:
            self._came_back[name] = float(t_arrival)
        if st.last_t is None or t_arrival > st.last_t:
            st.last_t = float(t_arrival)
        st.frames += 1

    def poll(self, t: float, frame: int = 0) -> list[Event]:
        """The camera events due at time t (the frame loop's step `frame`)."""
        out = []
        for name, st in self.cameras.items():
            if st.down and name in self._came_back:
                back = self._came_back.pop(name)
                st.down = False
                down_s = back - st.quiet_since
                out.append(camera_event("camera_up", name, t, frame, back, duration_s=down_s))
                logger.warning("camera %s is back after %.1f s", name, down_s)
            elif not st.down:
                since = st.quiet_since if st.last_t is None else st.last_t
                known = name in self._lost
                if t - since >= self.timeout_s or known:
                    st.down, st.quiet_since = True, since
                    self._came_back.pop(name, None)
                    self._lost.discard(name)
                    out.append(camera_event("camera_down", name, t, frame, since))
                    why = "its stream lost, " if known else ""
                    logger.error("camera %s: %sno frame for %.1f s", name, why, t - since)
        return out

    def lost(self, name: str) -> None:
        """Camera `name`'s stream is known lost (it ended, or its decoder died): down at the
        next poll, without waiting for timeout_s of silence; its next frame undoes it."""
        if name in self.cameras:
            self._lost.add(name)

    def overdue(self, t: float) -> list[str]:
        """The cameras not down whose silence has reached timeout_s at t (poll would take
        them down)."""
        out = []
        for name, st in self.cameras.items():
            since = st.quiet_since if st.last_t is None else st.last_t
            if not st.down and t - since >= self.timeout_s:
                out.append(name)
        return out

    def up(self) -> list[str]:
        """The cameras not down (up, or waiting for their first frame)."""
        return [name for name, st in self.cameras.items() if not st.down]

    def shift(self, seconds: float) -> None:
        """The cameras not down lose `seconds` of their silence (a stall of the service that
        ended: the time it lasted is not theirs)."""
        if not (seconds > 0 and math.isfinite(seconds)):
            return
        for st in self.cameras.values():
            if not st.down:
                st.quiet_since += seconds
                if st.last_t is not None:
                    st.last_t += seconds

    def state(self, name: str) -> str:
        """ "up", "down" or "waiting" (no frame yet, not yet timed out)."""
        st = self.cameras[name]
        if st.down:
            return "down"
        return "waiting" if st.last_t is None else "up"

    def age(self, name: str, t: float) -> float | None:
        """Seconds since the camera's last frame at time t (None: none yet)."""
        last = self.cameras[name].last_t
        return None if last is None else max(0.0, t - last)
