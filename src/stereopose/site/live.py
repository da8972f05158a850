"""The console's live side, by job: the scene (site.scene: the latest people with their
trails, the zones' state), the cameras' pictures (site.pictures: drawn and encoded on a thread
of their own) and, here, the push channel to the pages; `LiveHub` holds the three, and the
console's API reads them through it.

The frame loop only calls `LiveHub.on_frame` (through site.serve's ConsoleSink): the scene
takes the step, the pictures are offered the frame's images. Nothing it does waits for the web
side.

- The live thread tails the event log (new rows every TAIL_S) and pushes to every subscriber
  (at most max_clients): `people` (at most people_hz), `event` (each new row), `zones` (on a
  change and every ZONES_S), `cameras` (every CAMERAS_S), `ack` and `incident` (when one is
  made). Each subscriber has a queue of client_queue messages; a slow one loses its oldest
  (counted).
- The subscribers' places are shared fairly (site.http.places): at most per_user streams of one
  user (a newer one ends their own oldest), and max_clients // RESERVED_SHARE kept for
  operators and admins, whose alarm channel is always served: when every place is held, the
  oldest viewer's stream ends for them.
- Bounded: the scene's trails, subscribers, their queues, the pictures' queue.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING
from urllib.parse import quote

import cv2
import numpy as np

from stereopose.fence import Site
from stereopose.io.sinks.base import FrameResult
from stereopose.site.eventlog import EventLog, LogError
from stereopose.site.health.state import ServiceState
from stereopose.site.http.places import FairPlaces, Place
from stereopose.site.pictures import PictureEncoder
from stereopose.site.scene import SceneState
from stereopose.types import Camera, Rig

if TYPE_CHECKING:
    from stereopose.alarms import Change
    from stereopose.types import People2D, People3D

logger = logging.getLogger(__name__)

TAIL_S = 0.1
ZONES_S = 2.0
CAMERAS_S = 1.0
FOV_RANGE_M = 15.0
STREAMS_PER_USER = 4
RESERVED_SHARE = 4  # max_clients // RESERVED_SHARE places kept for operators and admins


def _sse(kind: str, body: object) -> bytes:
    data = json.dumps(body, separators=(",", ":"), allow_nan=False)
    return f"event: {kind}\ndata: {data}\n\n".encode()


def camera_view(cam: Camera, range_m: float = FOV_RANGE_M) -> dict:
    """A camera's place on the floor plan: position, yaw (degrees from +x, counter-clockwise,
    of its optical axis on the floor), horizontal field of view, and the floor it sees (the
    image border's rays met with z = 0, each at most range_m away on the floor)."""
    w, h = cam.size
    centre = np.asarray(cam.center, float)
    axis = cam.R[2]  # the optical axis in the world
    yaw = math.degrees(math.atan2(axis[1], axis[0]))
    hfov = math.degrees(2 * math.atan2(w / 2, cam.matrix[0, 0]))
    n = 12
    border = np.concatenate(
        [
            np.stack([np.linspace(0, w, n), np.zeros(n)], 1),
            np.stack([np.full(n, w), np.linspace(0, h, n)], 1),
            np.stack([np.linspace(w, 0, n), np.full(n, h)], 1),
            np.stack([np.zeros(n), np.linspace(h, 0, n)], 1),
        ]
    )
    if cam.fisheye:
        rays = cv2.fisheye.undistortPoints(
            border[None].astype(np.float64), cam.matrix, cam.distortions[:4]
        )[0]
    else:
        rays = cv2.undistortPoints(border[None].astype(np.float64), cam.matrix, cam.distortions)[
            :, 0
        ]
    dirs = np.c_[rays, np.ones(len(rays))] @ cam.R  # camera -> world: R.T @ d
    poly = []
    for d in dirs:
        flat = d[:2]
        reach = np.hypot(*flat)
        if d[2] < -1e-9 and centre[2] > 0:
            s = -centre[2] / d[2]
            p = centre[:2] + s * flat
            if np.hypot(*(p - centre[:2])) <= range_m:
                poly.append(p)
                continue
        if reach > 1e-9:
            poly.append(centre[:2] + flat / reach * range_m)
    return {
        "name": cam.name,
        "position": [round(float(v), 3) for v in centre],
        "yaw_deg": round(yaw, 1),
        "hfov_deg": round(hfov, 1),
        "floor_fov": [[round(float(x), 3), round(float(y), 3)] for x, y in poly],
        "image_size": [int(w), int(h)],
        "snapshot": f"/api/cameras/{quote(cam.name, safe='')}/snapshot.jpg",  # any name
    }


class Subscriber:
    """One page on the push channel: a bounded queue of encoded messages, woken on its event
    loop; `dropped` counts what it lost for being slow; `ended`: why the hub ended it to make
    room for another (its stream then closes), None while it stands."""

    def __init__(self, loop: asyncio.AbstractEventLoop, maxlen: int) -> None:
        self.loop, self.maxlen = loop, maxlen
        self.wake = asyncio.Event()
        self.dropped = 0
        self.ended: str | None = None
        self.place: Place | None = None
        self._queue: deque[bytes] = deque()
        self._lock = threading.Lock()

    def put(self, message: bytes) -> None:
        with self._lock:
            if len(self._queue) >= self.maxlen:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(message)
        with contextlib.suppress(RuntimeError):  # its loop has closed: the stream is over
            self.loop.call_soon_threadsafe(self.wake.set)

    def take(self) -> list[bytes]:
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        return out

    def __len__(self) -> int:
        return len(self._queue)


@dataclass(frozen=True)
class HubSettings:
    """The live side's pace and limits: camera pictures snapshot_hz a second, scaled by
    snapshot_scale, JPEG quality jpeg_quality; people pushed people_hz a second; at most
    max_clients push channels, per_user of them a user's, each with client_queue messages
    waiting at most."""

    snapshot_hz: float = 3.0
    snapshot_scale: float = 0.5
    jpeg_quality: int = 75
    people_hz: float = 5.0
    max_clients: int = 32
    per_user: int = STREAMS_PER_USER
    client_queue: int = 256


class LiveHub:
    """See the module. rig: the cameras; site: the zones (None: none); state: the health
    state (cameras' health; the hub's queues registered on it); log: the event log to tail
    (None: no events pushed); settings: its pace and limits; draw: (camera, image, people2d,
    people3d, scale, label) -> the picture (default viz.overlay over the rig); power(): the
    energized zones' states now (site.scene)."""

    def __init__(
        self,
        rig: Rig,
        site: Site | None,
        state: ServiceState,
        log: EventLog | None = None,
        settings: HubSettings = HubSettings(),
        *,
        draw: Callable | None = None,
        clock: Callable[[], float] = time.monotonic,
        power: Callable[[], dict] | None = None,
    ) -> None:
        self.rig, self.site, self.state, self.log = rig, site, state, log
        self.people_hz = settings.people_hz
        self._places = FairPlaces(settings.max_clients, per_user=settings.per_user)
        self.max_clients, self.client_queue = settings.max_clients, settings.client_queue
        self.clock = clock
        if draw is None:
            from stereopose.viz.overlay import draw_overlay

            def overlay(
                camera: str,
                image: np.ndarray,
                p2: People2D | None,
                p3: People3D,
                scale: float,
                label: str,
            ) -> np.ndarray:
                return draw_overlay(image, self.rig[camera], p2, p3, scale, label)

            draw = overlay

        self._views = {c.name: camera_view(c) for c in rig}
        self.scene = SceneState(site, power)
        self.pictures = PictureEncoder(
            self._views,
            draw,
            snapshot_hz=settings.snapshot_hz,
            snapshot_scale=settings.snapshot_scale,
            jpeg_quality=settings.jpeg_quality,
            clock=clock,
        )
        self._lock = threading.Lock()
        self._regions_view: Callable[[str], dict | None] | None = None
        self._subs: set[Subscriber] = set()
        self.messages_dropped_gone = 0  # by subscribers that have left
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.closed = False
        state.register_queue(
            "console_snapshots", self.pictures.queue.qsize, lambda: self.pictures.snapshots_dropped
        )
        state.register_queue("console_clients", self._queued, None)

    # -- the frame loop's side -------------------------------------------------------------

    def on_frame(self, frame: FrameResult, wall_start: float) -> None:
        """One frame (see the module); quick, never blocks."""
        self.scene.update(frame, wall_start)
        if frame.images and any(im is not None for im in frame.images.values()):
            self.pictures.offer(frame, wall_start)

    # -- threads ---------------------------------------------------------------------------

    def start(self) -> None:
        self.pictures.start()
        thread = threading.Thread(target=self._live_loop, name="console-live", daemon=True)
        thread.start()
        self._threads.append(thread)

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the threads; every push stream ends."""
        self.closed = True
        self._stop.set()
        deadline = time.monotonic() + timeout_s
        self.pictures.close(timeout_s)
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        for sub in list(self._subs):
            with contextlib.suppress(RuntimeError):
                sub.loop.call_soon_threadsafe(sub.wake.set)

    def _live_loop(self) -> None:
        last_id = self._last_id()
        people_at = zones_at = cameras_at = -math.inf
        people_frame, zones_version = None, -1
        while not self._stop.wait(TAIL_S):
            try:
                last_id = self._tail(last_id)
                if not self._subs:
                    continue
                now = self.clock()
                latest = self.scene.latest
                if (
                    self.people_hz > 0
                    and latest is not None
                    and latest.frame != people_frame
                    and now - people_at >= 1.0 / self.people_hz
                ):
                    people_frame, people_at = latest.frame, now
                    self._broadcast(_sse("people", self.people()))
                if self.scene.version != zones_version or now - zones_at >= ZONES_S:
                    zones_version, zones_at = self.scene.version, now
                    self._broadcast(_sse("zones", self.zones()))
                if now - cameras_at >= CAMERAS_S:
                    cameras_at = now
                    self._broadcast(_sse("cameras", self.cameras()))
            except Exception:  # the push channel must outlive a bug in one message
                logger.exception("console: the live channel failed to send; going on")

    def _last_id(self) -> int | None:
        if self.log is None:
            return None
        try:
            return self.log.last_id() if self.log.path.is_file() else 0
        except LogError:  # not known now (0 would push every stored event again): next tick
            return None

    def _tail(self, last_id: int | None) -> int | None:
        if self.log is None:
            return last_id
        if last_id is None:  # the log was not readable at the start: where it ends now
            return self._last_id()
        try:
            new = self.log.after(last_id)
        except LogError as e:
            logger.debug("console: event log not readable now: %s", e)
            return last_id
        for item in new:
            last_id = max(last_id, int(item["id"]))
            self._broadcast(_sse("event", item))
        return last_id

    # -- subscribers -----------------------------------------------------------------------

    @property
    def max_clients(self) -> int:
        return self._places.total

    @max_clients.setter
    def max_clients(self, n: int) -> None:
        self._places.total, self._places.reserved = n, n // RESERVED_SHARE

    def subscribe(
        self, loop: asyncio.AbstractEventLoop, user: str = "", privileged: bool = False
    ) -> Subscriber | None:
        """A new subscriber of `user` with the current people, zones and cameras queued; None
        when no place is free for them (see the module; privileged: an operator or admin).
        A stream ended to make room for this one has its `ended` set and is woken."""
        if self.closed:
            return None
        sub = Subscriber(loop, self.client_queue)
        sub.place = self._places.take(user, privileged, lambda why: self._ended(sub, why))
        if sub.place is None:
            return None
        with self._lock:
            self._subs.add(sub)
        for kind, body in (
            ("people", self.people()),
            ("zones", self.zones()),
            ("cameras", self.cameras()),
        ):
            sub.put(_sse(kind, body))
        return sub

    def _ended(self, sub: Subscriber, why: str) -> None:
        sub.ended = why
        self.unsubscribe(sub)
        with contextlib.suppress(RuntimeError):  # its loop has closed: the stream is over
            sub.loop.call_soon_threadsafe(sub.wake.set)

    def unsubscribe(self, sub: Subscriber) -> None:
        if sub.place is not None:
            self._places.give_back(sub.place)
        with self._lock:
            if sub in self._subs:
                self._subs.discard(sub)
                self.messages_dropped_gone += sub.dropped

    def publish(self, kind: str, body: object) -> None:
        """A message to every subscriber (e.g. an acknowledgement)."""
        self._broadcast(_sse(kind, body))

    def incident_changes(self, changes: Sequence[Change]) -> None:
        """An incident output (pipeline.incidents): each change as an `incident` message."""
        for c in changes:
            self.publish("incident", c.to_dict())

    def _broadcast(self, message: bytes) -> None:
        with self._lock:
            subs = list(self._subs)
        for sub in subs:
            sub.put(message)

    def _queued(self) -> int:
        with self._lock:
            return sum(len(s) for s in self._subs)

    @property
    def clients(self) -> int:
        return len(self._subs)

    @property
    def messages_dropped(self) -> int:
        with self._lock:
            return self.messages_dropped_gone + sum(s.dropped for s in self._subs)

    # -- the web side's reads --------------------------------------------------------------

    def people(self) -> dict:
        """The /api/people body of the latest frame (site.scene)."""
        return self.scene.people()

    def zones(self) -> dict:
        """The /api/zones body: each zone with its state and who is inside (site.scene)."""
        return self.scene.zones()

    def cameras(self) -> dict:
        """The /api/cameras body: each camera's place and view, with its health now."""
        snap = self.state.snapshot()
        health = {c.name: c for c in snap.cameras}
        out = []
        for name, view in self._views.items():
            c = health.get(name)
            item = dict(view)
            item["health"] = {
                "fps": round(c.fps, 2) if c else 0.0,
                "last_frame_age_s": (
                    round(c.last_frame_age_s, 3) if c and c.last_frame_age_s is not None else None
                ),
                "state": c.state if c else "down",
                "reconnects": c.reconnects if c else 0,
                "frames": c.frames if c else 0,
                "dropped_frames": c.dropped_frames if c else 0,
            }
            if self._regions_view is not None:
                item["regions"] = self._regions_view(name)
            light = snap.light.get(name)
            if light:  # its light (detection.light): the mode and what it rests on
                item["light"] = {k: light.get(k) for k in ("mode", "brightness", "noise")}
            out.append(item)
        return {"cameras": out}

    def set_rig(self, rig: Rig) -> None:
        """The cameras placed again (the calibration keeper, the surveyed points): their views
        on the plan and their pictures' overlays from now on."""
        self.rig = rig
        self._views.update({c.name: camera_view(c) for c in rig if c.name in self._views})

    def show_regions(self, view: Callable[[str], dict | None]) -> None:
        """view(camera): what detection in regions looked at in the camera's last step
        (detection.regional.RegionDetector.view), given with each camera in /api/cameras and
        the live channel, for the console's Regions toggle."""
        self._regions_view = view

    def has_camera(self, name: str) -> bool:
        return name in self._views

    def snapshot(self, camera: str) -> tuple[bytes, float] | None:
        """The camera's newest picture (JPEG, its wall time); None before one."""
        return self.pictures.snapshot(camera)

    def figures(self) -> Mapping[str, int]:
        return {
            "clients": self.clients,
            "messages_dropped": self.messages_dropped,
            "clients_replaced": self._places.replaced,
            "clients_bumped": self._places.bumped,
            "clients_refused": self._places.refused,
            **self.pictures.figures(),
        }


class ConsoleSink:
    """The frame loop's sink feeding `hub` (wall_start: the Unix time of t = 0). A failure in
    the hub is logged once and counted, never raised: the console must not stop the loop."""

    stage = "write"

    def __init__(self, hub: LiveHub, wall_start: float) -> None:
        self.hub, self.wall_start = hub, float(wall_start)
        self.errors = 0
        self._closed = False

    def write(self, frame: FrameResult) -> None:
        if self._closed:
            return
        try:
            self.hub.on_frame(frame, self.wall_start)
        except Exception:
            self.errors += 1
            if self.errors == 1:
                logger.exception("console: a frame could not be shown (later ones are tried)")

    def close(self) -> list:
        self._closed = True
        return []
