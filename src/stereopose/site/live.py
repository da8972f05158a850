"""The console's live side: the latest people with their trails, the zones' state, the
cameras' pictures and health, new events from the log, and the push channel to the pages.

The frame loop only calls `LiveHub.on_frame` (through site.serve's ConsoleSink): it keeps
a reference to the frame's people with their floor points and headings (computed with NumPy,
no JSON), extends each person's trail, follows the zones' occupancy from the enter and exit
events, and, a few times a second, hands the camera images to the snapshot encoder through a
queue of SNAPSHOT_QUEUE frames (full: the frame is dropped and counted). Nothing it does waits
for the web side.

- The snapshot encoder (a thread) draws each camera's image with its skeletons and ids
  (viz.overlay) and keeps its newest JPEG; at `snapshot_hz` while someone looks at the
  pictures, at IDLE_SNAPSHOT_HZ otherwise.
- The live thread tails the event log (new rows every TAIL_S) and pushes to every subscriber
  (at most max_clients): `people` (at most people_hz), `event` (each new row), `zones` (on a
  change and every ZONES_S), `cameras` (every CAMERAS_S), `ack` (when one is made).
  Each subscriber has a queue of client_queue messages; a slow one loses its oldest (counted).
- The subscribers' places are shared fairly (site.http.places): at most per_user streams of one
  user (a newer one ends their own oldest), and max_clients // RESERVED_SHARE kept for
  operators and admins, whose alarm channel is always served: when every place is held, the
  oldest viewer's stream ends for them.
- Bounded: trails (trail_points per person, TRAIL_S long, MAX_TRAILS people), subscribers,
  their queues, the snapshot queue.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from urllib.parse import quote

import cv2
import numpy as np

from stereopose.fence import Site, ZoneGeometry
from stereopose.io.sinks.base import FrameResult
from stereopose.site.eventlog import EventLog, LogError
from stereopose.site.health.state import ServiceState
from stereopose.site.http.places import FairPlaces, Place
from stereopose.skeleton import floor_position, heading_deg
from stereopose.types import Camera, Rig

logger = logging.getLogger(__name__)

TRAIL_S = 5.0
TRAIL_POINTS = 50
MAX_TRAILS = 256
SNAPSHOT_QUEUE = 2
IDLE_SNAPSHOT_HZ = 0.5
# a picture's longest side at least this many pixels (up to the frame's own size), so that the
# ids drawn on a small detection substream can still be read when the picture is enlarged
SNAPSHOT_MIN_SIDE = 640
WATCHED_S = 10.0  # a snapshot asked for within this long: someone is looking
TAIL_S = 0.1
ZONES_S = 2.0
CAMERAS_S = 1.0
FOV_RANGE_M = 15.0
ALARM_HOLD_S = 3.0  # an approach keeps its zone in alarm this long
STREAMS_PER_USER = 4
RESERVED_SHARE = 4  # max_clients // RESERVED_SHARE places kept for operators and admins


def _num(x: float, nd: int = 3) -> float | None:
    return round(float(x), nd) if math.isfinite(x) else None


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
    border = np.concatenate([
        np.stack([np.linspace(0, w, n), np.zeros(n)], 1),
        np.stack([np.full(n, w), np.linspace(0, h, n)], 1),
        np.stack([np.linspace(w, 0, n), np.full(n, h)], 1),
        np.stack([np.zeros(n), np.linspace(h, 0, n)], 1),
    ])  # fmt: skip
    if cam.fisheye:
        rays = cv2.fisheye.undistortPoints(border[None].astype(np.float64), cam.matrix,
                                           cam.distortions[:4])[0]  # fmt: skip
    else:
        rays = cv2.undistortPoints(border[None].astype(np.float64), cam.matrix,
                                   cam.distortions)[:, 0]  # fmt: skip
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


@dataclass
class _Latest:
    frame: int
    t: float
    wall_t: float
    ids: np.ndarray
    joints: np.ndarray
    positions: np.ndarray
    headings: np.ndarray
    postures: Mapping[int, object] | None = None  # id -> behaviour.posture.Posture


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


def picture_scale(shape: tuple[int, ...], scale: float) -> float:
    """The scale of a frame of `shape` (height, width, ...) in its picture: `scale`, or more
    (never above the frame's own size) so the longest side has SNAPSHOT_MIN_SIDE pixels."""
    longest = max(int(shape[0]), int(shape[1]), 1)
    return max(float(scale), min(1.0, SNAPSHOT_MIN_SIDE / longest))


class LiveHub:
    """See the module. rig: the cameras; site: the zones (None: none); state: the health
    state (cameras' health; the hub's queues registered on it); log: the event log to tail
    (None: no events pushed); draw: (camera, image, people2d, people3d, scale, label) -> the
    picture (default viz.overlay over the rig)."""

    def __init__(
        self,
        rig: Rig,
        site: Site | None,
        state: ServiceState,
        log: EventLog | None = None,
        *,
        snapshot_hz: float = 3.0,
        snapshot_scale: float = 0.5,
        jpeg_quality: int = 75,
        people_hz: float = 5.0,
        max_clients: int = 32,
        per_user: int = STREAMS_PER_USER,
        client_queue: int = 256,
        draw: Callable | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.rig, self.site, self.state, self.log = rig, site, state, log
        self.snapshot_hz, self.snapshot_scale = snapshot_hz, snapshot_scale
        self.jpeg_quality, self.people_hz = jpeg_quality, people_hz
        self._places = FairPlaces(max_clients, per_user=per_user)
        self.max_clients, self.client_queue = max_clients, client_queue
        self.clock = clock
        if draw is None:
            from stereopose.viz.overlay import draw_overlay

            def draw(camera, image, p2, p3, scale, label):
                return draw_overlay(image, rig[camera], p2, p3, scale, label)

        self.draw = draw
        self._views = {c.name: camera_view(c) for c in rig}
        self._lock = threading.Lock()
        self._latest: _Latest | None = None
        self._trails: dict[int, deque[tuple[float, float, float]]] = {}
        self._trail_seen: dict[int, float] = {}
        zones = site.zones if site is not None else ()
        self._zones = {z.name: z for z in zones}
        self._inside: dict[str, set[int]] = {z.name: set() for z in zones}
        # energized zones, tested each frame: whoever has a triggering joint inside one now
        # is its occupant at once (the enter event waits for its debounce)
        self._energized = tuple(z for z in zones if z.kind == "energized")
        self._geometry = ZoneGeometry(self._energized) if self._energized else None
        self._touching: dict[str, frozenset[int]] = {}
        self._approach: dict[str, float] = {}  # zone -> service time of its last approach
        self._zones_version = 0
        self._snapshots: dict[str, tuple[bytes, float]] = {}
        self._regions_view: Callable[[str], dict | None] | None = None
        self._snap_q: queue.Queue = queue.Queue(SNAPSHOT_QUEUE)
        self._snap_at = -math.inf
        self._watched_at = -math.inf
        self.snapshots_dropped = self.snapshots_made = self.snapshot_errors = 0
        self._subs: set[Subscriber] = set()
        self.messages_dropped_gone = 0  # by subscribers that have left
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.closed = False
        state.register_queue("console_snapshots", self._snap_q.qsize,
                             lambda: self.snapshots_dropped)  # fmt: skip
        state.register_queue("console_clients", self._queued, None)

    # -- the frame loop's side -------------------------------------------------------------

    def on_frame(self, frame: FrameResult, wall_start: float) -> None:
        """One frame (see the module); quick, never blocks."""
        p = frame.people3d
        joints = np.asarray(p.joints, float)
        ids = np.asarray(p.ids)
        if len(ids):
            positions, headings = floor_position(joints), heading_deg(joints)
        else:
            positions, headings = np.zeros((0, 2)), np.zeros(0)
        t = float(frame.t)
        latest = _Latest(int(frame.frame), t, wall_start + t, ids, joints, positions, headings,
                         getattr(frame, "postures", None))  # fmt: skip
        touching = self._touching_now(joints, ids)
        with self._lock:
            self._latest = latest
            self._trail(t, ids, positions)
            if touching != self._touching:
                self._touching = touching
                self._zones_version += 1
            if frame.events:
                self._occupancy(frame.events, t)
        if frame.images and any(im is not None for im in frame.images.values()):
            self._offer_snapshot(frame, wall_start)

    def _touching_now(self, joints: np.ndarray, ids: np.ndarray) -> dict[str, frozenset[int]]:
        """Energized zone -> the ids with one of its triggering joints inside it (joints
        (P, 17, 3) metres)."""
        if self._geometry is None or not len(ids) or joints.ndim != 3:
            return {}
        P, J = joints.shape[:2]
        inside = self._geometry.inside(joints.reshape(-1, 3)).reshape(P, J, -1)
        out = {}
        for k, z in enumerate(self._energized):
            rows = np.flatnonzero(inside[:, list(z.joints), k].any(axis=1))
            if len(rows):
                out[z.name] = frozenset(int(i) for i in ids[rows])
        return out

    def _trail(self, t: float, ids: np.ndarray, positions: np.ndarray) -> None:
        step = TRAIL_S / TRAIL_POINTS
        for pid, (x, y) in zip(ids.tolist(), positions.tolist(), strict=True):
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            trail = self._trails.get(pid)
            if trail is None:
                if len(self._trails) >= MAX_TRAILS:
                    continue
                trail = self._trails[pid] = deque(maxlen=TRAIL_POINTS)
            if not trail or t - trail[-1][0] >= step - 1e-6:
                trail.append((t, x, y))
            while trail[0][0] < t - TRAIL_S - 1e-6:
                trail.popleft()
            self._trail_seen[pid] = t
        for pid in [k for k, seen in self._trail_seen.items() if t - seen > TRAIL_S]:
            self._trails.pop(pid, None)
            self._trail_seen.pop(pid, None)

    def _occupancy(self, events, t: float) -> None:
        for e in events:
            inside = self._inside.get(e.zone)
            if inside is None:
                continue
            if e.type == "enter":
                inside.add(e.person)
            elif e.type == "exit":
                inside.discard(e.person)
            elif e.type == "approach":
                self._approach[e.zone] = t
            else:
                continue
            self._zones_version += 1

    def _offer_snapshot(self, frame: FrameResult, wall_start: float) -> None:
        now = self.clock()
        watched = now - self._watched_at <= WATCHED_S
        hz = self.snapshot_hz if watched else IDLE_SNAPSHOT_HZ
        if hz <= 0 or now - self._snap_at < 1.0 / hz:
            return
        self._snap_at = now
        item = (wall_start + float(frame.t), dict(frame.images), dict(frame.people2d),
                frame.people3d)  # fmt: skip
        try:
            self._snap_q.put_nowait(item)
        except queue.Full:
            self.snapshots_dropped += 1

    # -- threads ---------------------------------------------------------------------------

    def start(self) -> None:
        for name, target in (("console-snapshots", self._encode_loop),
                             ("console-live", self._live_loop)):  # fmt: skip
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the threads; every push stream ends."""
        self.closed = True
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self._snap_q.put_nowait(None)
        deadline = time.monotonic() + timeout_s
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        for sub in list(self._subs):
            with contextlib.suppress(RuntimeError):
                sub.loop.call_soon_threadsafe(sub.wake.set)

    def _encode_loop(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._snap_q.get(timeout=0.5)
            except queue.Empty:
                continue
            if item is None:
                return
            wall_t, images, people2d, people3d = item
            stamp = datetime.fromtimestamp(wall_t, timezone.utc).strftime("%H:%M:%S")
            for camera, image in images.items():
                if image is None or camera not in self._views:
                    continue
                try:
                    scale = picture_scale(image.shape, self.snapshot_scale)
                    picture = self.draw(camera, image, people2d.get(camera), people3d, scale,
                                        f"{camera} {stamp}")  # fmt: skip
                    quality = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality]
                    ok, buf = cv2.imencode(".jpg", picture, quality)
                except Exception:  # a bad frame must not stop the pictures
                    ok, buf = False, None
                    logger.debug("console: camera %s: snapshot not drawn", camera, exc_info=True)
                if not ok:
                    self.snapshot_errors += 1
                    continue
                with self._lock:
                    self._snapshots[camera] = (buf.tobytes(), wall_t)
                self.snapshots_made += 1

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
                latest = self._latest
                if (self.people_hz > 0 and latest is not None and latest.frame != people_frame
                        and now - people_at >= 1.0 / self.people_hz):  # fmt: skip
                    people_frame, people_at = latest.frame, now
                    self._broadcast(_sse("people", self.people()))
                if self._zones_version != zones_version or now - zones_at >= ZONES_S:
                    zones_version, zones_at = self._zones_version, now
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

    def subscribe(self, loop: asyncio.AbstractEventLoop, user: str = "",
                  privileged: bool = False) -> Subscriber | None:  # fmt: skip
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
        for kind, body in (("people", self.people()), ("zones", self.zones()),
                           ("cameras", self.cameras())):  # fmt: skip
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
        """The /api/people body of the latest frame."""
        with self._lock:
            latest = self._latest
            trails = {pid: list(tr) for pid, tr in self._trails.items()}
            inside = self._occupants()
        if latest is None:
            return {"frame": None, "t": None, "wall_t": None, "people": []}
        people = []
        postures = latest.postures or {}
        for row, pid in enumerate(latest.ids.tolist()):
            posture = postures.get(pid)
            x, y = latest.positions[row].tolist()
            joints = [[round(a, 3), round(b, 3), round(c, 3)]
                      if math.isfinite(a) and math.isfinite(b) and math.isfinite(c) else None
                      for a, b, c in latest.joints[row].tolist()]  # fmt: skip
            people.append({
                "id": int(pid),
                "position": [_num(x), _num(y), 0.0] if math.isfinite(x + y) else None,
                "heading_deg": _num(float(latest.headings[row]), 1),
                "joints": joints,
                "zones": sorted(z for z, ids in inside.items() if pid in ids),
                "trail": [[round(px, 3), round(py, 3)] for _, px, py in trails.get(pid, [])],
                "posture": getattr(posture, "posture", None),
                "flags": [str(f) for f in getattr(posture, "flags", ())],
            })  # fmt: skip
        return {"frame": latest.frame, "t": round(latest.t, 3),
                "wall_t": round(latest.wall_t, 3), "people": people}  # fmt: skip

    def _occupants(self) -> dict[str, set[int]]:
        """Zone -> who is inside: by its enter and exit events, and for an energized zone
        also whoever has a triggering joint in it now (under the lock)."""
        return {z: ids | self._touching.get(z, frozenset()) for z, ids in self._inside.items()}

    def zones(self) -> dict:
        """The /api/zones body: each zone with its state and who is inside."""
        with self._lock:
            inside = {z: sorted(ids) for z, ids in self._occupants().items()}
            approach = dict(self._approach)
            now_t = self._latest.t if self._latest is not None else 0.0
        out = []
        for name, z in self._zones.items():
            occupants = inside.get(name, [])
            recent = now_t - approach.get(name, -math.inf) <= ALARM_HOLD_S
            if z.kind == "energized" and (occupants or recent):
                state = "alarm"
            else:
                state = "occupied" if occupants else "free"
            out.append({
                "name": name, "kind": z.kind,
                "polygon": [[round(float(x), 3), round(float(y), 3)] for x, y in z.polygon],
                "z": [float(z.z[0]), float(z.z[1])], "margin_m": float(z.margin_m),
                "state": state, "occupants": occupants,
            })  # fmt: skip
        return {"zones": out}

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
                "last_frame_age_s": (round(c.last_frame_age_s, 3)
                                     if c and c.last_frame_age_s is not None else None),
                "state": c.state if c else "down",
                "reconnects": c.reconnects if c else 0,
                "frames": c.frames if c else 0,
                "dropped_frames": c.dropped_frames if c else 0,
            }  # fmt: skip
            if self._regions_view is not None:
                item["regions"] = self._regions_view(name)
            out.append(item)
        return {"cameras": out}

    def show_regions(self, view: Callable[[str], dict | None]) -> None:
        """view(camera): what detection in regions looked at in the camera's last step
        (detection.regional.RegionDetector.view), given with each camera in /api/cameras and
        the live channel, for the console's Regions toggle."""
        self._regions_view = view

    def has_camera(self, name: str) -> bool:
        return name in self._views

    def snapshot(self, camera: str) -> tuple[bytes, float] | None:
        """The camera's newest picture (JPEG, its wall time); None before one."""
        self._watched_at = self.clock()
        with self._lock:
            return self._snapshots.get(camera)

    def figures(self) -> Mapping[str, int]:
        return {"clients": self.clients, "messages_dropped": self.messages_dropped,
                "clients_replaced": self._places.replaced,
                "clients_bumped": self._places.bumped, "clients_refused": self._places.refused,
                "snapshots_made": self.snapshots_made,
                "snapshots_dropped": self.snapshots_dropped,
                "snapshot_errors": self.snapshot_errors}  # fmt: skip


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
