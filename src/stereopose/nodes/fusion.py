"""The fusion side: `serve` with ``[input] detection = "nodes"`` takes every camera's 2D people
from the detection nodes (nodes.node) over the site's broker and gives the frame loop time
steps of them, as its own cameras and detector would.

`NodeInput` subscribes to the site's keypoints, pictures and node topics (nodes.wire) and
groups the camera-frames into steps by capture time:

- a step begins with the earliest capture time t0 waiting, and takes each camera's earliest
  frame within t0 + window (node_window_s; default half a step period, so the frames of one
  grid time on every node are one step);
- it is given to the loop as soon as every active camera (one heard from within ACTIVE_S or
  ACTIVE_STEPS step periods, whichever is longer, its node not offline) has
  a frame in it or a newer one waiting (its node passed this time over), or once node_wait_s
  has gone by since its first frame arrived: a slow or dead node delays the others by at most
  that much;
- a frame that arrives after its step was given (capture time at or before that step's end),
  or from before the service started, is late: dropped and counted per camera; each camera's
  frames waiting are at most PENDING (the oldest dropped and counted).

A step's t is its capture time on the service's clock (seconds since `clock.start_epoch`), so
latency is measured from capture; the service's empty steps (no frame for a while) are stamped
`lag_s` before now, the longest way of a frame to its step, so a real step never has to be
moved later than its capture time. Each camera of a step carries the newest picture its node
sent (or a grey one until the first; every picture of a camera at the size of
node_picture_scale), the one the console shows and the clips are made of.
Each node's health (retained, with its last will) is followed: its clock's offset measured
from its health messages (the largest of the last CLOCK_KEPT: the least delayed), and a node
off by more than node_clock_tolerance_s is refused: its frames are dropped (counted) until its
clock is right, and its cameras go down. A frame from the future is refused: captured after
now by more than FUTURE_S once its node's measured clock offset is taken off
(node_clock_tolerance_s while the offset is not known yet), and a node whose frames keep
coming from the future (even the least early of its last LEADS_KEPT, at least FUTURE_RUN) is
refused whole until one is on time. A slow service delays frames and health alike, so it never
makes a node look early. One node cannot push another's frames late: a camera's frames are
taken from one node at a time (another node takes it over only once the first fell silent for
ACTIVE_S), and at most one per half step period (the rest dropped and counted), so no camera
makes more steps than the cameras' rate.
Malformed messages are counted and logged once a minute per kind.
A camera whose node stops sending is down after camera_timeout_s, through the camera watch as
a local camera is. The broker away is retried for ever; its restart is survived (subscribed
again on every connection).
"""

from __future__ import annotations

import logging
import math
import threading
import time
import uuid
from collections import deque
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

import cv2
import numpy as np

from stereopose.io.sinks.mqtt_settings import MqttSettings, loop_alive, make_client, restart_loop
from stereopose.io.source import Clock
from stereopose.io.summary import CAMERA_STAGES, RunSummary
from stereopose.nodes.hold import HoldTeller
from stereopose.nodes.node_state import (
    CameraFigures,
    NodeState,
    camera_rates,
    from_future,
    judge_clock,
)
from stereopose.nodes.wire import (
    Keypoints,
    Topics,
    WireError,
    decode_health,
    decode_people,
    decode_picture,
    jpeg_size,
    picture_size,
)
from stereopose.pipeline.loop import SourceStep
from stereopose.types import People2D, People3D, Rig
from stereopose.zones.hazard import Hazards

if TYPE_CHECKING:
    import paho.mqtt.client as paho
    from paho.mqtt.reasoncodes import ReasonCode

logger = logging.getLogger(__name__)

PENDING = 32  # camera-frames waiting per camera
ACTIVE_S = 1.0  # a camera heard from within this long (or ACTIVE_STEPS step periods) is
ACTIVE_STEPS = 4  # waited for, unless its node is known to be offline
WARN_S = 60.0  # the same kind of bad message logged at most this often
MAX_NODES = 256  # nodes followed at most (names come from whoever publishes)
MIN_PICTURE_PX = 2_000_000  # a picture may have 4x its camera's picture pixels, or this
DETECT_ALLOWANCE_S = 1.0  # a node's detection of one step, at most, for the empty steps' time


class NodeInput:
    """The frame-loop source of a service fed by nodes (see the module); a context manager:
    connected on enter, disconnected on exit."""

    stages = CAMERA_STAGES
    live = True
    total = None

    def __init__(
        self,
        settings: MqttSettings,
        rig: Rig,
        *,
        fps: float,
        window_s: float | None = None,
        wait_s: float = 0.5,
        clock_tolerance_s: float = 0.25,
        picture_scale: float = 0.25,
        clock: Clock | None = None,
    ) -> None:
        self.settings, self.rig = settings, rig
        self.cameras = tuple(rig.names)
        self.names = list(rig.names)
        self.fps = float(fps)
        self.window_s = float(window_s) if window_s else 0.5 / self.fps
        self.wait_s, self.tolerance_s = float(wait_s), float(clock_tolerance_s)
        self.clock = clock or Clock.now()
        # the longest a camera-frame takes from capture to its step here (detection at the
        # node, the window, the wait): an empty step's time is this much before now, so that
        # a step with the frames of that time can still follow it
        self.lag_s = self.wait_s + self.window_s + DETECT_ALLOWANCE_S
        # a camera heard from within this long is waited for: a few step periods
        self.active_s = max(ACTIVE_S, ACTIVE_STEPS / self.fps)
        self.wall_clock = True
        self.topics = Topics.of(settings.topic_prefix, settings.site)
        self.figures = {n: CameraFigures() for n in self.cameras}
        self.nodes: dict[str, NodeState] = {}
        self.malformed = 0
        self.unknown = 0  # messages for cameras not in the calibration
        self.steps = 0
        self.partial = 0  # steps given without every active camera (node_wait_s ran out)
        self.connected = False
        self._pending: dict[str, deque[tuple[Keypoints, float]]] = {
            n: deque() for n in self.cameras
        }
        self._pictures: dict[str, np.ndarray] = {}
        # every picture of a camera has one size (a clip's frames must): the nodes' pictures'
        self._sizes = {n: picture_size(rig[n].size, picture_scale) for n in self.cameras}
        self._placeholders = {
            n: np.full((h, w, 3), 96, np.uint8) for n, (w, h) in self._sizes.items()
        }
        self._given_end = -math.inf  # the capture time up to which steps were given
        self._owner: dict[str, tuple[str, float]] = {}  # camera -> (its node, last frame)
        self._last_t: dict[str, float] = {}  # camera -> capture time of its last frame taken
        self.min_gap_s = 0.5 / self.fps  # a camera's frames at most twice the step rate
        self._cond = threading.Condition()
        self._closed = False
        self._warned: dict[str, float] = {}
        self._problem: str | None = None
        self.client = None
        self.restarts = 0  # paho's thread started again by ensure_running
        self.hold = HoldTeller(self._publish, self.topics.hold, rig, self.fps)

    # -- the broker ---------------------------------------------------------------------------

    def __enter__(self) -> NodeInput:
        s = self.settings
        c = make_client(s, f"stereopose-fusion-{uuid.uuid4().hex[:8]}")
        c.on_connect, c.on_disconnect = self._on_connect, self._on_disconnect
        c.on_connect_fail, c.on_message = self._on_connect_fail, self._on_message
        self.client = c
        c.connect_async(s.host, s.port, keepalive=s.keepalive_s)
        c.loop_start()
        logger.info(
            "detection from nodes: %s under %s/ on %s:%d",
            ", ".join(self.cameras),
            self.topics.base,
            s.host,
            s.port,
        )
        return self

    def _publish(self, topic: str, payload: bytes) -> None:
        if self.client is not None:
            self.client.publish(topic, payload, qos=0)

    def __exit__(self, *exc: object) -> None:
        self.end()
        if self.client is not None:
            self.client.disconnect()
            self.client.loop_stop()

    def end(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def _on_connect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        if reason.is_failure:
            self._say(logging.ERROR, f"the broker refused the connection: {reason}; retrying")
            return
        base = self.topics.base
        client.subscribe(
            [(f"{base}/keypoints/+", 0), (f"{base}/pictures/+", 0), (f"{base}/nodes/+", 1)]
        )
        self.connected = True
        if self._problem is not None:
            logger.info("MQTT %s:%d: connected", self.settings.host, self.settings.port)
        self._problem = None

    def _on_disconnect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        was, self.connected = self.connected, False
        if was and not self._closed:
            self._say(
                logging.WARNING,
                "connection lost: no camera-frames from the nodes meanwhile; retrying",
            )

    def _on_connect_fail(self, client: paho.Client, userdata: object) -> None:
        self._say(logging.WARNING, "broker unreachable; retrying")

    def _say(self, level: int, text: str) -> None:
        if text != self._problem:
            self._problem = text
            logger.log(level, "MQTT %s:%d: %s", self.settings.host, self.settings.port, text)

    def _warn(self, kind: str, text: str) -> None:
        now = time.monotonic()
        if len(self._warned) >= MAX_NODES:  # kinds named by what a publisher sent: bounded
            self._warned.clear()
        if now - self._warned.get(kind, -math.inf) >= WARN_S:
            self._warned[kind] = now
            logger.warning("%s (such messages skipped and counted)", text)

    # -- messages (paho's thread) ---------------------------------------------------------------

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        try:
            self._message(msg.topic, bytes(msg.payload), bool(msg.retain))
        except Exception as e:  # nothing a message holds may end paho's thread
            self.malformed += 1
            self._warn("error", f"nodes: a message on {msg.topic} could not be read: {e}")

    def _message(self, topic: str, payload: bytes, retained: bool) -> None:
        parsed = self.topics.parse(topic)
        if parsed is None:
            return
        kind, name = parsed
        if kind == "nodes":
            self._health(name, payload, retained)
            return
        fig = self.figures.get(name)
        if fig is None:
            self.unknown += 1
            self._warn(
                f"unknown:{name}",
                f"nodes: camera {name!r} is not one of the "
                f"service's cameras ({', '.join(self.cameras)})",
            )
            return
        try:
            if kind == "pictures":
                self._picture(name, payload)
            else:
                self._keypoints(name, payload)
        except WireError as e:
            self.malformed += 1
            self._warn(f"{kind}:{name}", f"nodes: {topic}: {e}")

    def _health(self, name: str, payload: bytes, retained: bool) -> None:
        if not payload:  # a retained message cleared
            return
        try:
            doc = decode_health(payload)
        except WireError as e:
            self.malformed += 1
            self._warn(f"health:{name}", f"nodes: {self.topics.node(name)}: {e}")
            return
        with self._cond:
            if name not in self.nodes and len(self.nodes) >= MAX_NODES:
                self.unknown += 1
                self._warn("nodes", f"nodes: more than {MAX_NODES} nodes; {name!r} is ignored")
                return
            node = self.nodes.setdefault(name, NodeState(name))
            was = node.state
            node.state = str(doc["state"])
            node.last_mono = time.monotonic()
            if node.state == "online":
                node.health = {k: doc.get(k) for k in ("cameras", "detect_ms", "queue", "backend")}
                if not retained:  # a retained one is old: its clock says nothing of now
                    clock = doc["clock"]
                    assert isinstance(clock, (int, float))  # decode_health checked it
                    node.offsets.append(float(clock) - time.time())
                    judge_clock(node, self.tolerance_s)
        if was != node.state:
            log = logger.warning if node.state == "offline" else logger.info
            log("node %s is %s", name, node.state)

    def _picture(self, name: str, payload: bytes) -> None:
        _, jpeg = decode_picture(payload)
        w, h = self._sizes[name]
        pw, ph = jpeg_size(jpeg)  # from its header: a picture bomb is never decoded
        if pw * ph > max(4 * w * h, MIN_PICTURE_PX) or not (pw and ph):
            raise WireError(
                f"a {pw}x{ph} picture: more pixels than a {w}x{h} camera picture may have"
            )
        image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise WireError("its JPEG cannot be decoded")
        if image.shape[:2] != (h, w):  # a node of another picture scale
            image = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
        with self._cond:
            self._pictures[name] = image
            self.figures[name].pictures += 1

    def _keypoints(self, name: str, payload: bytes) -> None:
        kp = decode_people(payload, name)
        now, wall = time.monotonic(), time.time()
        with self._cond:
            fig = self.figures[name]
            fig.frames += 1
            fig.bytes += len(payload)
            owner = self._owner.get(name)
            if owner is not None and owner[0] != kp.node and now - owner[1] <= self.active_s:
                fig.refused += 1  # another node's camera, while that node sends it
                self._warn(
                    f"owner:{kp.node}:{name}",
                    f"nodes: node {kp.node} sent camera "
                    f"{name}, which node {owner[0]} sends: refused",
                )
                return
            node = self.nodes.get(kp.node)
            if from_future(kp, node, name, wall, self.tolerance_s, self._warn) or (
                node is not None and node.refused
            ):
                fig.refused += 1  # a node's clock off, a frame from the future
                return
            if owner is not None and owner[0] != kp.node:
                logger.warning(
                    "nodes: camera %s now comes from node %s (node %s fell silent)",
                    name,
                    kp.node,
                    owner[0],
                )
                self._last_t.pop(name, None)
            self._owner[name] = (kp.node, now)
            fig.node = kp.node
            fig.last_mono = now
            last = self._last_t.get(name)
            if last is not None and last <= kp.t < last + self.min_gap_s:
                fig.flood += 1  # faster than the steps: one step's worth taken
                self._warn(
                    f"flood:{name}",
                    f"nodes: camera {name} from node {kp.node}: "
                    f"frames closer than {self.min_gap_s:.3f} s dropped",
                )
                return
            if (
                kp.t <= self._given_end
                or kp.t < self.clock.start_epoch
                or (last is not None and kp.t < last)
            ):
                fig.late += 1  # its step given, or behind its camera's newer frame
                return
            self._last_t[name] = kp.t
            q = self._pending[name]
            if len(q) >= PENDING:
                q.popleft()
                fig.dropped += 1
            q.append((kp, now))
            self._cond.notify_all()

    # -- steps (the frame loop's side) -------------------------------------------------------

    def _ready(self, now: float) -> tuple[float, dict[str, Keypoints]] | None:
        """The step that can be given now (under the lock), taken off the waiting frames."""
        firsts = {n: q[0] for n, q in self._pending.items() if q}
        if not firsts:
            return None
        t0 = min(kp.t for kp, _ in firsts.values())
        end = t0 + self.window_s
        group = {n: item for n, item in firsts.items() if item[0].t <= end}
        arrived = min(at for _, at in group.values())
        active = {
            n
            for n, f in self.figures.items()
            if f.last_mono is not None
            and now - f.last_mono <= self.active_s
            and self._online(f.node)
        }
        settled = set(firsts)  # in the step, or a newer frame waiting: nothing more to come
        if not active <= settled and now - arrived < self.wait_s:
            return None
        if not active <= set(group):
            self.partial += 1
        for n in group:
            self._pending[n].popleft()
        self._given_end = end
        return t0, {n: kp for n, (kp, _) in group.items()}

    def _online(self, node: str | None) -> bool:
        """Whether a node is not known to be offline (its will or its goodbye)."""
        state = self.nodes.get(node or "")
        return state is None or state.state != "offline"

    def __iter__(self) -> Iterator[SourceStep]:
        while True:
            with self._cond:
                while True:
                    if self._closed:
                        return
                    got = self._ready(time.monotonic())
                    if got is not None:
                        break
                    self._cond.wait(0.02)
                t0, group = got
                step = self.steps
                self.steps += 1
                images = {}
                for n in group:
                    self.figures[n].used += 1
                    images[n] = self._pictures.get(n, self._placeholders[n])
            people = {
                n: People2D(n, step, kp.people.keypoints, kp.people.boxes, kp.people.scores)
                for n, kp in group.items()
            }
            yield SourceStep(step, t0 - self.clock.start_epoch, people, images)

    def detect(self, step: SourceStep) -> Mapping[str, People2D]:
        raise TypeError("the nodes' steps carry their people")

    def tracked(self, people: People3D) -> None:
        """The frame loop's people of its last step: the cameras that see someone near an
        energized zone told to the nodes, which never carry their steps (nodes.hold)."""
        self.hold.tell(people, self.clock.start_epoch)

    def set_hazards(self, hazards: Hazards | None) -> None:
        """The hazards from the next step on (a new site while serving)."""
        self.hold.set_hazards(hazards)

    # -- health ----------------------------------------------------------------------------------

    def delivering(self, name: str, within_s: float) -> bool:
        """Whether camera `name` has had a frame from its node within `within_s`."""
        last = self.figures[name].last_mono
        return last is not None and time.monotonic() - last <= within_s

    def stats(self) -> dict[str, CameraFigures]:
        return dict(self.figures)

    def rates(self) -> dict[str, tuple[float | None, float | None]]:
        """Per camera (the rate it should be processed at, its own rate), from its node's
        health; None while not known."""
        with self._cond:
            return {
                name: camera_rates(self.nodes.get(fig.node or ""), name)
                for name, fig in self.figures.items()
            }

    def report(self) -> dict:
        """status.json's `nodes`: the link, each node, each camera's figures."""
        now = time.monotonic()
        with self._cond:
            nodes = {n.name: n.report(now) for n in self.nodes.values()}
            cams = {n: f.report(len(self._pending[n])) for n, f in self.figures.items()}
        return {
            "connected": self.connected,
            "window_s": self.window_s,
            "steps": self.steps,
            "partial_steps": self.partial,
            "malformed": self.malformed,
            "unknown_cameras": self.unknown,
            "restarts": self.restarts,
            "running": loop_alive(self.client),
            "nodes": nodes,
            "cameras": cams,
        }

    def waiting(self) -> int:
        return sum(len(q) for q in self._pending.values())

    def ensure_running(self) -> None:
        """paho's thread started again where it died (counted in `restarts`, logged); the
        service's watchdog calls this every half second. Meanwhile no frame comes, and the
        cameras' health says so."""
        if not self._closed and restart_loop(self.client):
            self.restarts += 1
            logger.error("detection from nodes: the MQTT client's thread ended; started again")

    def lost(self) -> int:
        return sum(f.late + f.dropped + f.refused + f.flood for f in self.figures.values())

    def finish(self, summary: RunSummary) -> None:
        summary.sources = {
            n: {"frames": f.frames, "dropped": f.dropped + f.late + f.flood, "reconnects": 0}
            for n, f in self.figures.items()
        }
        summary.clock_start_epoch = self.clock.start_epoch
