"""What the fusion knows of each node and camera: a camera's figures as received, a node's
state and clock (its offset from its health messages, the largest of the last CLOCK_KEPT: the
least delayed), and the judgements that refuse a node's frames: its clock off, or its frames
coming from the future."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from stereopose.nodes.wire import Keypoints

logger = logging.getLogger("stereopose.nodes.fusion")

CLOCK_KEPT = 5
FUTURE_S = 0.1  # a frame captured this long after now (its node's clock offset taken off)
FUTURE_RUN = 5  # frames at least before a node is refused as from the future
LEADS_KEPT = 25  # a node's last frames whose least lead over this clock is judged


@dataclass
class CameraFigures:
    """One camera as the fusion service receives it."""

    frames: int = 0  # camera-frames received
    used: int = 0  # in a step given to the loop
    late: int = 0
    dropped: int = 0  # waiting frames over PENDING
    refused: int = 0  # from a node with its clock off, from the future, or not its node
    flood: int = 0  # closer than half a step period to the camera's previous frame
    bytes: int = 0
    pictures: int = 0
    node: str | None = None
    last_mono: float | None = None
    reconnects: int = 0  # the readers' figure, for the health state (a node's link: none)

    def report(self, waiting: int) -> dict:
        """status.json's `nodes.cameras` entry of this camera, `waiting` frames waiting."""
        return {
            "node": self.node,
            "frames": self.frames,
            "used": self.used,
            "late": self.late,
            "dropped": self.dropped,
            "refused": self.refused,
            "flood": self.flood,
            "bytes": self.bytes,
            "pictures": self.pictures,
            "waiting": waiting,
        }


@dataclass
class NodeState:
    name: str
    state: str = "online"
    offsets: deque = field(default_factory=lambda: deque(maxlen=CLOCK_KEPT))
    refused: bool = False
    last_mono: float | None = None
    health: dict = field(default_factory=dict)
    future: bool = False  # refused: its frames keep coming from the future
    # its last frames' lead over this clock (capture time - arrival)
    leads: deque = field(default_factory=lambda: deque(maxlen=LEADS_KEPT))

    @property
    def offset(self) -> float | None:
        """Its clock minus ours: the largest of the last offsets measured, the least delayed
        (a message's way here only ever makes a node's clock look behind)."""
        return max(self.offsets) if self.offsets else None

    def report(self, now: float) -> dict:
        """status.json's entry of this node (now: time.monotonic())."""
        return {
            "state": self.state,
            "clock_offset_s": rounded(self.offset),
            "clock_refused": self.refused,
            "future_refused": self.future,
            "seen_s_ago": None if self.last_mono is None else round(now - self.last_mono, 1),
            **self.health,
        }


def judge_clock(node: NodeState, tolerance_s: float) -> None:
    """A node refused while its clock is off the service's by more than `tolerance_s`
    (logged when that changes)."""
    off = node.offset
    if off is None:
        return
    bad = abs(off) > tolerance_s
    if bad and not node.refused:
        logger.error(
            "node %s: its clock is off the service's by %+.3f s (more than "
            "input.node_clock_tolerance_s = %g s): its frames are refused until "
            "its clock is set right",
            node.name,
            off,
            tolerance_s,
        )
    elif node.refused and not bad:
        logger.warning(
            "node %s: its clock is right again (%+.3f s): its frames are taken", node.name, off
        )
    node.refused = bad


def from_future(
    kp: Keypoints,
    node: NodeState | None,
    name: str,
    wall: float,
    tolerance_s: float,
    warn: Callable[[str, str], None],
) -> bool:
    """Whether the frame is refused as from the future (under the fusion's lock): its lead
    over this clock (capture time - now) beyond `tolerance_s`, or beyond FUTURE_S
    past its node's clock offset (the largest of its health's last: the least delayed);
    and the whole node while even its frames' least lead of late is (a node whose frames
    keep coming from the future). A slow service delays the frames as much as the health
    messages, so their way here never makes a node look early."""
    lead = kp.t - wall
    offset = node.offset if node is not None else None
    if node is not None:
        node.leads.append(lead)
    ahead = lead - (offset or 0.0)
    future = ahead > (FUTURE_S if offset is not None else tolerance_s)
    if future:
        warn(
            f"future:{kp.node}",
            f"nodes: node {kp.node}: a frame of camera "
            f"{name} captured {ahead:+.3f} s from now (its clock offset taken "
            "off)",
        )
    if node is None or offset is None:
        return future
    early = min(node.leads) - offset  # its frames' least lead of late, past its offset
    if not node.future and len(node.leads) >= FUTURE_RUN and early > FUTURE_S:
        node.future = True
        logger.error(
            "nodes: node %s: its frames keep coming from the future (%+.3f s "
            "past its clock): refused until its frames are on time",
            node.name,
            early,
        )
    elif node.future and early <= FUTURE_S:
        node.future = False
        logger.warning("nodes: node %s: its frames are on time again: taken", node.name)
    return future or node.future


def positive_rate(v: object) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) and v > 0 else None


def rounded(v: float | None) -> float | None:
    return None if v is None else round(v, 4)


def nodes_light(report: Mapping) -> dict[str, dict[str, str]]:
    """Each camera's light (detection.light's mode) as its node's last health says it, from
    NodeInput.report(): {camera: {"mode"}}, the cameras whose mode is known."""
    out = {}
    for name, cam in (report.get("cameras") or {}).items():
        node = (report.get("nodes") or {}).get(cam.get("node") or "") or {}
        mode = ((node.get("cameras") or {}).get(name) or {}).get("light")
        if isinstance(mode, str):
            out[name] = {"mode": mode}
    return out


def camera_rates(node: NodeState | None, camera: str) -> tuple[float | None, float | None]:
    """A camera's (rate it should be processed at, its own rate) from its node's health; None
    while not known."""
    cam = ((node.health.get("cameras") or {}).get(camera) if node else None) or {}
    own, det = positive_rate(cam.get("fps")), positive_rate(cam.get("detect_fps"))
    return (min(own, det) if own and det else own or det, own)
