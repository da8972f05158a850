"""`stereopose detect-node`: some of a site's cameras detected on this machine, their 2D
people published on the site's broker for the fusion service (`serve`, [input] detection =
"nodes"; nodes.fusion).

The node reads the site's own configuration (its cameras, calibration, [detector], [input]
and [mqtt]) and opens only its cameras: those of ``--cameras``, or of its ``[[nodes]]`` entry
(``--node NAME``). Live cameras are read as `serve` reads them (newest frames, detect_fps,
reconnects; a camera with a `detect` substream from that substream alone, its full stream
never opened at the node); recorded files are played on the wall clock (nodes.paced), so that
nodes on several machines show the same moment at the same time. Each step's frames go
through the detector in one call; each camera's people, in the calibration's pixels, go out
on ``keypoints/<camera>`` with their capture time (nodes.wire), QoS 0. A picture of each
camera goes out `node_picture_hz` times a second (``pictures/<camera>``, JPEG at
`node_picture_scale`), for the console's pictures and the alarm clips: the pictures are small
and rare next to a camera's stream, and the fusion service needs no decoder and no link to
the cameras. The node's health (its cameras, detection time, queue, clock) goes out every
HEALTH_S on ``nodes/<node>``, retained, with a last will saying offline.

Messages wait for the broker in one queue of `queue_size` (the oldest dropped when full, and
counted); a keypoints message older than STALE_S when its turn comes is dropped too (the
fusion service would take it as late). The broker away is retried for ever.
"""

from __future__ import annotations

import dataclasses
import logging
import socket
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2

from stereopose.config import Config, load_config
from stereopose.config_refs import (
    mqtt_settings,
    resolve,
    source_path,
)
from stereopose.detection import make_detector
from stereopose.detection.carry import carrier
from stereopose.detection.light import LightWatch
from stereopose.detection.regional import region_detector
from stereopose.errors import ConfigError
from stereopose.io.cameraset import CameraSet
from stereopose.io.sinks.mqtt_settings import MqttSettings
from stereopose.io.video import FrameSet, is_stream
from stereopose.nodes.hold import HoldWatch
from stereopose.nodes.link import QUEUE_SIZE, Publisher
from stereopose.nodes.paced import PacedFiles
from stereopose.nodes.wire import (
    Topics,
    encode_people,
    encode_picture,
    health_message,
    picture_size,
)
from stereopose.pipeline.detect import detect_step
from stereopose.pipeline.run import check_run_config, run_rig
from stereopose.pipeline.sources import check_size, scale_people
from stereopose.types import Rig

if TYPE_CHECKING:
    import numpy as np


logger = logging.getLogger(__name__)

HEALTH_S = 1.0
JPEG_QUALITY = 70


@dataclass(frozen=True)
class NodePlan:
    """A node's part of the site's configuration, checked."""

    config_path: Path
    config: Config
    name: str
    rig: Rig  # its cameras only
    sources: tuple[str, ...]
    detect_sources: tuple[str, ...]
    loop: tuple[bool, ...]
    mqtt: MqttSettings
    model: Path | None


def plan_node(
    config_path: str | Path,
    cameras: Sequence[str] | None = None,
    node: str | None = None,
    name: str | None = None,
) -> NodePlan:
    """The node of `config_path` with `cameras` (or those of its [[nodes]] entry `node`); a
    ConfigError naming the file and the problem."""
    path = Path(config_path)
    cfg = load_config(path)
    check_run_config(cfg, path)
    if cfg.mqtt.host == "":
        raise ConfigError(
            f"{path}: mqtt.host: a detection node publishes on the site's broker; set [mqtt] host"
        )
    if node is not None:
        entry = next((n for n in cfg.nodes if n.name == node), None)
        if entry is None:
            known = ", ".join(n.name for n in cfg.nodes) or "none"
            raise ConfigError(f"{path}: no [[nodes]] entry named {node!r} (known: {known})")
        if cameras:
            raise ConfigError(f"{path}: give the node's --cameras or --node, not both")
        cameras, name = entry.cameras, name or entry.name
    if not cameras:
        raise ConfigError(
            f"{path}: a detection node needs its cameras (--cameras A,B or "
            "--node NAME of a [[nodes]] entry)"
        )
    by_name = {c.name: (i, c) for i, c in enumerate(cfg.cameras)}
    unknown = [c for c in cameras if c not in by_name]
    if unknown:
        raise ConfigError(
            f"{path}: camera(s) {', '.join(unknown)} not among its [[cameras]] "
            f"({', '.join(by_name)})"
        )
    if len(set(cameras)) != len(cameras):
        raise ConfigError(f"{path}: a camera named twice in the node's cameras")
    base = path.resolve().parent
    rig = run_rig(path, resolve(base, cfg.calibration or ""), cfg).subset(list(cameras))
    picked = [by_name[c][1] for c in cameras]
    sources = tuple(source_path(base, c.source) for c in picked)
    kinds = {is_stream(s) for s in sources}
    if len(kinds) > 1:
        raise ConfigError(
            f"{path}: a node's cameras are all live streams or all recorded "
            f"files; {', '.join(cameras)} mix them: give them two nodes"
        )
    for s, c in zip(sources, picked, strict=True):
        if not is_stream(s) and not Path(s).is_file():
            raise ConfigError(f"{path}: camera {c.name}: no such video file {s}")
    settings = mqtt_settings(path, base, cfg)
    assert settings is not None
    node_name = name or f"{socket.gethostname()}-{'-'.join(cameras)}"
    return NodePlan(
        config_path=path,
        config=cfg,
        name=node_name,
        rig=rig,
        sources=sources,
        detect_sources=tuple(source_path(base, c.detect) for c in picked),
        loop=tuple(c.loop for c in picked),
        mqtt=settings,
        model=resolve(base, cfg.detector.model) if cfg.detector.model else None,
    )


@dataclass
class NodeFigures:
    steps: int = 0
    detect_s: float = 0.0
    last_detect_ms: float | None = None
    frames: dict[str, int] = field(default_factory=dict)


class DetectNode:
    """One node's run (see the module): `run(stop)` until `stop` is set."""

    def __init__(self, plan: NodePlan) -> None:
        self.plan = plan
        cfg = plan.config
        d = cfg.detector
        self.detector = make_detector(
            d.backend, plan.model, d.imgsz, d.conf, d.iou, d.device, d.threads, d.precision
        )
        # regions from each camera's own people, motion and full scans (a node has no 3D)
        self.regions = region_detector(self.detector, d)
        self.light = LightWatch(enhance=d.night)  # a night camera's pictures prepared, as serve's
        # carried steps as serve's, never for a camera the fusion service holds (nodes.hold)
        self.carry = carrier(d)
        self.holds = HoldWatch()
        self._step_index = 0
        self.topics = Topics.of(plan.mqtt.topic_prefix, plan.mqtt.site)
        self.figures = NodeFigures()
        self.picture_hz = cfg.input.node_picture_hz
        self.picture_scale = cfg.input.node_picture_scale
        self._pictured: dict[str, float] = {}
        self._checked: set[str] = set()
        self._subs: set[str] = set()  # cameras read from their detection substream
        self.publisher: Publisher | None = None
        self._source: Any = None

    # -- the cameras --------------------------------------------------------------------------

    def _open(self) -> PacedFiles | CameraSet:
        p, cfg = self.plan, self.plan.config
        # a camera with a detection substream is read from it alone: its people are found on
        # it and its picture made of it; the full stream is never opened here
        self._subs = {n for n, d in zip(p.rig.names, p.detect_sources, strict=True) if d}
        sources = [d or s for s, d in zip(p.sources, p.detect_sources, strict=True)]
        if not is_stream(p.sources[0]):
            spec = {n: (s, loop) for n, s, loop in zip(p.rig.names, sources, p.loop, strict=True)}
            return PacedFiles(spec, cfg.input.detect_fps)
        return CameraSet(
            sources,
            list(p.rig.names),
            cfg.input.sync,
            cfg.input.fps,
            None,
            open_timeout_s=cfg.input.open_timeout_s,
            first_frame_timeout_s=None,
            detect_fps=cfg.input.detect_fps,
            wait_first_frame=False,
            wall_clock=True,
            decoders=cfg.input.decoders,
        )

    def _steps(self, source: PacedFiles | CameraSet) -> Iterator[tuple[float, FrameSet]]:
        """(capture time, seconds since 1970; the FrameSet) per step with a frame."""
        if isinstance(source, PacedFiles):
            for fs in source:
                yield fs.t, fs
            return
        for fs in source:
            if fs.times:
                yield source.clock.start_epoch + min(fs.times.values()), fs

    def camera_figures(self) -> dict[str, dict]:
        src, out = self._source, {}
        timeout_s = self.plan.config.serve.camera_timeout_s
        for name in self.plan.rig.names:
            entry: dict = {"frames": self.figures.frames.get(name, 0)}
            if isinstance(src, PacedFiles):
                cam = src.cameras[name]
                entry |= {
                    "fps": cam.fps,
                    "detect_fps": src.rate,
                    "dropped": src.stats[name].skipped,
                    "up": True,
                }
            elif isinstance(src, CameraSet):
                st = src.stats().get(name)
                s = next((s for s in src.sources if s.name == name), None)
                entry |= {
                    "fps": float(s.fps) if s is not None and s.fps else None,
                    "detect_fps": src.detect_fps,
                    "dropped": 0 if st is None else st.dropped,
                    "up": src.delivering(name, timeout_s),
                }
            entry["light"] = self.light.mode(name)  # day, night, black, blinded (None: unseen)
            out[name] = entry
        return out

    # -- the run ------------------------------------------------------------------------------

    def run(self, stop: threading.Event) -> NodeFigures:
        p = self.plan
        self.publisher = pub = Publisher(
            p.mqtt,
            self.topics,
            p.name,
            max(QUEUE_SIZE, 8 * len(p.rig.names)),
            on_hold=self.holds.take if self.carry is not None else None,
        )
        pub.on_connect = lambda: pub.health(self._health())
        try:
            self._source = source = self._open()
            logger.info(
                "node %s: detecting %s; publishing on %s:%d under %s/",
                p.name,
                ", ".join(p.rig.names),
                p.mqtt.host,
                p.mqtt.port,
                self.topics.base,
            )
            threading.Thread(
                target=self._beats, args=(stop, source), name="node-health", daemon=True
            ).start()
            try:
                for t, frames in self._steps(source):
                    if stop.is_set():
                        break
                    self._step(t, frames)
            finally:
                stop.set()
                if isinstance(source, CameraSet):
                    source.close()
        finally:
            pub.close()
        return self.figures

    def _step(self, t: float, frames: FrameSet) -> None:
        t0 = time.perf_counter()
        images = frames.images
        for name, image in images.items():
            if image is not None and name not in self._checked and name not in self._subs:
                self._checked.add(name)
                check_size(self.plan.rig[name], image)
        # its people named and numbered, at the capture time t; cameras carried left out (the
        # carried steps counted on the node's own steps: one after another, whatever the
        # frames' numbers skip)
        step = self._step_index
        self._step_index += 1
        order = [n for n, im in images.items() if im is not None]
        carried: set[str] = set()
        if self.carry is not None:
            carried = self.carry.plan(order, step, t, self.holds.held)
        detected = {n: im for n, im in images.items() if n not in carried}
        people = detect_step(
            self.detector,
            dataclasses.replace(frames, t=t, images=detected),
            self.regions,
            light=self.light,
        )
        if self.carry is not None:
            for name, found in people.items():
                self.carry.seen(name, found, step, t)
            for name in carried:  # numbered as the frames they stand for
                people[name] = dataclasses.replace(
                    self.carry.carried(name, step), frame=frames.index
                )
        spent = time.perf_counter() - t0
        self.figures.steps += 1
        self.figures.detect_s += spent
        self.figures.last_detect_ms = spent * 1000
        pub = self.publisher
        assert pub is not None
        for name, found in people.items():
            cam = self.plan.rig[name]
            image = images[name]
            if image is not None and (image.shape[1], image.shape[0]) != (
                round(cam.size[0]),
                round(cam.size[1]),
            ):
                found = scale_people(found, cam.size, image.shape)
            pub.put(self.topics.keypoints(name), encode_people(self.plan.name, found, t, cam.size))
            self.figures.frames[name] = self.figures.frames.get(name, 0) + 1
            self._picture(name, t, image)

    def _picture(self, name: str, t: float, image: np.ndarray | None) -> None:
        if image is None or self.picture_hz <= 0:
            return
        now = time.monotonic()
        if now - self._pictured.get(name, -1e9) < 1.0 / self.picture_hz:
            return
        self._pictured[name] = now
        cam = self.plan.rig[name]
        w, h = picture_size(cam.size, self.picture_scale)
        small = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
        ok, jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if ok and self.publisher is not None:
            self.publisher.put(self.topics.picture(name), encode_picture(t, jpeg.tobytes()))
            self.publisher.counts.pictures += 1

    def _health(self) -> bytes:
        pub = self.publisher
        return health_message(
            self.plan.name,
            "online",
            clock=time.time(),
            cameras=self.camera_figures(),
            detect_ms=None
            if self.figures.last_detect_ms is None
            else round(self.figures.last_detect_ms, 1),
            queue={
                "queued": pub.queued() if pub else 0,
                "dropped": pub.counts.dropped if pub else 0,
            },
            backend=self.detector.name,
            regions=self._region_figures(),
            # per camera the steps detected, carried and held near a hazard; the holds taken
            carry=None
            if self.carry is None
            else {"cameras": self.carry.report(), "holds": self.holds.figures()},
        )

    def _region_figures(self) -> dict[str, dict[str, float]] | None:
        """Each camera's detection in regions, in brief: regions and full scans so far, the
        share of whole frames' model input used (None: whole frames)."""
        if self.regions is None:
            return None
        return {
            cam: {
                "regions": c["regions"],
                "full_scans": c["full_scans"],
                "input_share": round(float(c["input_share"]), 3),
            }
            for cam, c in self.regions.report().items()
        }

    def _beats(self, stop: threading.Event, source: PacedFiles | CameraSet) -> None:
        """The health every HEALTH_S whatever the cameras do; the source ended at the stop."""
        while not stop.wait(HEALTH_S):
            if self.publisher is not None:
                try:
                    self.publisher.health(self._health())
                except Exception as e:  # a figure missing must not end the health
                    logger.warning("node health not sent: %s", e)
        source.end()
