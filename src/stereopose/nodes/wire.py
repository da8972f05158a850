"""What detection nodes and the fusion service say to each other over the site's broker.

Topics (prefix and site as in [mqtt]; names as one topic level, io.sinks.mqtt_settings):

- ``<prefix>/<site>/keypoints/<camera>``: one camera-frame's 2D people, QoS 0, not retained
  (a late frame is worth nothing): ``{"v": 1, "node", "camera", "frame", "t", "size",
  "people": [{"k": [x, y, c] * 17 flat, "b": [x1, y1, x2, y2], "s": score}]}``. ``t``: the
  frame's capture time, seconds since 1970 on the node's clock; ``size``: the camera's
  calibrated (width, height), the pixels of ``k`` and ``b``; a missing joint is ``0, 0, 0``.
  Pixels are rounded to 0.1, confidences to 0.01: about 350 bytes a person, 100 with nobody.
- ``<prefix>/<site>/pictures/<camera>``: the camera's picture now and then (JPEG, QoS 0), its
  capture time in the topic's message as the 8 bytes before the JPEG (big-endian double).
- ``<prefix>/<site>/nodes/<node>``: the node's health, QoS 1, retained, its last will
  ``{"v": 1, "node", "state": "offline"}``: ``{"v": 1, "node", "state": "online", "clock",
  "cameras": {name: {"fps", "detect_fps", "frames", "dropped", "up"}}, "detect_ms",
  "queue": {"queued", "dropped"}, "backend", "regions", "carry": {"cameras": {name:
  {"detected", "carried", "near_hazard"}}, "holds": {"taken", "malformed"}}}``; ``clock`` is
  the node's time when sent, from which the fusion service measures the node's offset.

- ``<prefix>/<site>/hold``: from the fusion service to the nodes, at each step, QoS 0, not
  retained: ``{"v": 1, "t", "valid_s", "all": bool, "held": [camera, ...]}``, the cameras
  that see someone near an energized zone and so are detected at every step, never carried
  (every camera: ``all``; nodes.hold), for ``valid_s`` after it comes.

`decode_people` is strict: anything not of this shape (a hostile or broken publisher) is a
WireError naming the problem, and the fusion service counts and skips it.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from stereopose.io.sinks.mqtt_settings import topic_name, topic_part
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import People2D

VERSION = 1
MAX_PEOPLE = 256  # more people in one camera-frame is not a real frame
MAX_PAYLOAD = 256 * 1024  # bytes of a keypoints message
MAX_PICTURE = 4 * 2**20  # bytes of a picture message
MAX_CAMERAS = 256  # cameras in one node's health
LIGHT_MODES = ("day", "night", "black", "blinded")  # a camera's light (detection.light.MODES)
_STAMP = struct.Struct(">d")


class WireError(ValueError):
    """A message that is not what nodes send."""


@dataclass(frozen=True)
class Topics:
    """The node topics of one site."""

    base: str  # "<prefix>/<site>"

    @classmethod
    def of(cls, prefix: str, site: str) -> Topics:
        return cls(f"{prefix.strip('/')}/{topic_part(site)}")

    def keypoints(self, camera: str) -> str:
        return f"{self.base}/keypoints/{topic_part(camera)}"

    def picture(self, camera: str) -> str:
        return f"{self.base}/pictures/{topic_part(camera)}"

    def node(self, name: str) -> str:
        return f"{self.base}/nodes/{topic_part(name)}"

    @property
    def hold(self) -> str:
        return f"{self.base}/hold"

    def parse(self, topic: str) -> tuple[str, str] | None:
        """(kind, name) of one of this site's node topics: kind keypoints, pictures or
        nodes; None for any other topic."""
        head = self.base + "/"
        if not topic.startswith(head):
            return None
        kind, _, part = topic[len(head) :].partition("/")
        if kind not in ("keypoints", "pictures", "nodes") or not part or "/" in part:
            return None
        try:
            return kind, topic_name(part)
        except (ValueError, UnicodeDecodeError):
            return None


def _r(x: float, nd: int) -> float:
    return round(float(x), nd) if math.isfinite(x) else 0.0


def encode_people(node: str, people: People2D, t: float, size: tuple[float, float]) -> bytes:
    """One camera-frame's people as a keypoints message."""
    kp = np.asarray(people.keypoints, float).reshape(-1, NUM_JOINTS, 3)
    boxes = None if people.boxes is None else np.asarray(people.boxes, float)
    scores = None if people.scores is None else np.asarray(people.scores, float)
    out = []
    for i, person in enumerate(kp):
        flat = []
        for x, y, c in person:
            if c > 0 and math.isfinite(x) and math.isfinite(y):
                flat += [_r(x, 1), _r(y, 1), _r(c, 2)]
            else:
                flat += [0, 0, 0]
        p: dict = {"k": flat}
        if boxes is not None and i < len(boxes):
            p["b"] = [_r(v, 1) for v in boxes[i]]
        if scores is not None and i < len(scores):
            p["s"] = _r(scores[i], 3)
        out.append(p)
    doc = {
        "v": VERSION,
        "node": node,
        "camera": people.camera,
        "frame": int(people.frame),
        "t": round(float(t), 6),
        "size": [_r(size[0], 1), _r(size[1], 1)],
        "people": out,
    }
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


@dataclass(frozen=True)
class Keypoints:
    """A keypoints message read back: its node, camera, frame, capture time and people."""

    node: str
    camera: str
    frame: int
    t: float
    size: tuple[float, float]
    people: People2D


def _number(v: object, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise WireError(f"{what}: expected a finite number, got {v!r}")
    return float(v)


def decode_people(payload: bytes, camera: str) -> Keypoints:
    """A keypoints message of the topic of `camera`; a WireError naming the problem."""
    if len(payload) > MAX_PAYLOAD:
        raise WireError(f"{len(payload)} bytes, more than the {MAX_PAYLOAD} a frame may have")
    try:
        doc = json.loads(payload)
    except (ValueError, RecursionError):
        raise WireError("not JSON") from None
    if not isinstance(doc, dict):
        raise WireError("not a JSON object")
    if doc.get("v") != VERSION:
        raise WireError(f"version {doc.get('v')!r}, expected {VERSION}")
    node, cam = doc.get("node"), doc.get("camera")
    if not isinstance(node, str) or not node:
        raise WireError("no node name")
    if cam != camera:
        raise WireError(f"camera {cam!r} on the topic of camera {camera!r}")
    frame = doc.get("frame")
    if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
        raise WireError(f"frame: expected an integer >= 0, got {frame!r}")
    t = _number(doc.get("t"), "t")
    size = doc.get("size")
    if not isinstance(size, list) or len(size) != 2:
        raise WireError(f"size: expected [width, height], got {size!r}")
    w, h = (_number(v, "size") for v in size)
    people = doc.get("people")
    if not isinstance(people, list) or len(people) > MAX_PEOPLE:
        raise WireError(f"people: expected a list of at most {MAX_PEOPLE}")
    n = len(people)
    kp = np.zeros((n, NUM_JOINTS, 3))
    boxes = np.zeros((n, 4))
    scores = np.ones(n)
    has_boxes = n > 0
    for i, p in enumerate(people):
        if not isinstance(p, dict):
            raise WireError(f"people[{i}]: expected an object")
        k = p.get("k")
        if not isinstance(k, list) or len(k) != NUM_JOINTS * 3:
            raise WireError(f"people[{i}].k: expected {NUM_JOINTS * 3} numbers")
        kp[i] = np.array([_number(v, f"people[{i}].k") for v in k]).reshape(NUM_JOINTS, 3)
        b = p.get("b")
        if b is None:
            has_boxes = False
        elif not isinstance(b, list) or len(b) != 4:
            raise WireError(f"people[{i}].b: expected [x1, y1, x2, y2]")
        else:
            boxes[i] = [_number(v, f"people[{i}].b") for v in b]
        if "s" in p:
            scores[i] = _number(p["s"], f"people[{i}].s")
    if n and not ((kp[..., 2] >= 0) & (kp[..., 2] <= 1)).all():
        raise WireError("a joint's confidence outside [0, 1]")
    # a joint of confidence 0 (sent as 0, 0, 0) is made missing by People2D itself
    found = People2D(camera, frame, kp, boxes if has_boxes else None, scores)
    return Keypoints(node, camera, frame, t, (w, h), found)


def encode_picture(t: float, jpeg: bytes) -> bytes:
    return _STAMP.pack(float(t)) + jpeg


def decode_picture(payload: bytes) -> tuple[float, bytes]:
    """(capture time, JPEG bytes) of a picture message; a WireError when it is none."""
    if len(payload) > MAX_PICTURE:
        raise WireError(f"{len(payload)} bytes, more than the {MAX_PICTURE} a picture may have")
    if len(payload) < _STAMP.size + 4 or payload[_STAMP.size : _STAMP.size + 2] != b"\xff\xd8":
        raise WireError("not a time-stamped JPEG")
    (t,) = _STAMP.unpack_from(payload)
    if not math.isfinite(t):
        raise WireError("its time is not a finite number")
    return t, payload[_STAMP.size :]


def jpeg_size(jpeg: bytes) -> tuple[int, int]:
    """(width, height) of a JPEG from its frame header, without decoding it; a WireError when
    none is found (a picture is checked for its size before any pixel is decoded)."""
    i, n = 2, len(jpeg)
    while i + 4 <= n:
        if jpeg[i] != 0xFF:
            raise WireError("its JPEG is malformed")
        marker = jpeg[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # no length
            i += 2
            continue
        length = int.from_bytes(jpeg[i + 2 : i + 4], "big")
        if length < 2:
            raise WireError("its JPEG is malformed")
        # a start of frame: SOF0..SOF15 but DHT (C4), JPG (C8) and DAC (CC)
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            if i + 9 > n:
                break
            h = int.from_bytes(jpeg[i + 5 : i + 7], "big")
            w = int.from_bytes(jpeg[i + 7 : i + 9], "big")
            return w, h
        i += 2 + length
    raise WireError("its JPEG has no frame header")


def _camera_health(name: object, value: object) -> None:
    if not isinstance(name, str) or not isinstance(value, dict):
        raise WireError("cameras: each camera's health must be an object")
    for key in ("fps", "detect_fps", "detect_ms"):
        v = value.get(key)
        if v is not None:
            _number(v, f"cameras.{key}")
    if "up" in value and not isinstance(value["up"], bool):
        raise WireError("cameras.up: expected true or false")
    if value.get("light") is not None and value["light"] not in LIGHT_MODES:
        raise WireError(f"cameras.light: expected one of {', '.join(LIGHT_MODES)}")


def health_message(node: str, state: str, **fields: object) -> bytes:
    return json.dumps(
        {"v": VERSION, "node": node, "state": state, **fields},
        separators=(",", ":"),
        allow_nan=False,
    ).encode()


def decode_health(payload: bytes) -> Mapping[str, object]:
    """A node's health message; a WireError when it is none."""
    if len(payload) > MAX_PAYLOAD:
        raise WireError("too large")
    try:
        doc = json.loads(payload)
    except (ValueError, RecursionError):
        raise WireError("not JSON") from None
    if not isinstance(doc, dict) or doc.get("v") != VERSION:
        raise WireError("not a node's health message")
    if doc.get("state") not in ("online", "offline") or not isinstance(doc.get("node"), str):
        raise WireError("no node or state")
    if doc["state"] == "online":
        _number(doc.get("clock"), "clock")
        cameras = doc.get("cameras", {})
        if not isinstance(cameras, dict) or len(cameras) > MAX_CAMERAS:
            raise WireError(f"cameras: expected an object of at most {MAX_CAMERAS} cameras")
        for name, value in cameras.items():
            _camera_health(name, value)
        for key in ("detect_ms",):
            if doc.get(key) is not None:
                _number(doc[key], key)
        for key in ("queue", "regions", "carry"):
            if doc.get(key) is not None and not isinstance(doc[key], dict):
                raise WireError(f"{key}: expected an object")
    return doc


def picture_size(size: tuple[float, float], scale: float) -> tuple[int, int]:
    """(width, height) of a camera's pictures sent by its node: its size at `scale`
    (node_picture_scale), at least 16 px each way."""
    return max(16, round(size[0] * scale)), max(16, round(size[1] * scale))
