"""The one typed configuration schema; every default lives here.

A TOML file overrides any subset of it; unknown tables or keys are rejected with an error that
names the file and the key. Every numeric field carries its range beside its default
(`number(default, ge=..., le=...)`), checked whenever a section is built: from a file, in code,
or by `dataclasses.replace` / `with_overrides` for command-line options.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import types
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from stereopose.checks import DAY_S, FPS_MAX, FPS_MIN, Range, read_limited
from stereopose.errors import ConfigError
from stereopose.secrets import shown
from stereopose.skeleton import NUM_JOINTS

Mode = Literal["pair", "weighted", "robust"]
MODES: tuple[str, ...] = get_args(Mode)

_T = TypeVar("_T")
_LENGTH_M = 1000.0  # the largest distance a configuration may hold, metres


def number(default: Any, **bounds: Any) -> Any:
    """A numeric field with its range: ge/gt/le/lt bounds, integer, multiple_of (see Range)."""
    return field(default=default, metadata={"range": Range(**bounds)})


def _base(tp: Any) -> tuple[Any, bool]:
    """(type without None, whether None is allowed)."""
    if get_origin(tp) in (Union, types.UnionType):
        options = [a for a in get_args(tp) if a is not type(None)]
        return (options[0] if len(options) == 1 else tp), len(options) < len(get_args(tp))
    return tp, False


def _schema(section: str) -> Callable[[type[_T]], type[_T]]:
    """A frozen dataclass of the schema at key path `section`, checked on every construction;
    a numeric field without a range is refused when the class is defined."""

    def wrap(cls: type[_T]) -> type[_T]:
        cls.__post_init__ = _check_fields  # type: ignore[attr-defined]
        cls = dataclass(frozen=True)(cls)
        hints = get_type_hints(cls)
        ranges, choices = {}, {}
        for f in dataclasses.fields(cls):
            tp, optional = _base(hints[f.name])
            if tp in (int, float):
                if "range" not in f.metadata:
                    raise TypeError(f"{cls.__name__}.{f.name}: a number needs a range (number())")
                ranges[f.name] = (f.metadata["range"], optional, tp is float)
            elif get_origin(tp) is Literal:
                choices[f.name] = get_args(tp)
        cls._section, cls._ranges, cls._choices = section, ranges, choices  # type: ignore[attr-defined]
        return cls

    return wrap


def _check_fields(self: Any) -> None:
    cls = type(self)
    for name, allowed in cls._choices.items():
        value = getattr(self, name)
        if value not in allowed:
            raise ConfigError(f"{_key(cls, name)}: expected one of {list(allowed)}, got {value!r}")
    for name, (rng, optional, is_float) in cls._ranges.items():
        value = getattr(self, name)
        if value is None and optional:
            continue
        rng.check(value, _key(cls, name))
        if is_float:
            object.__setattr__(self, name, float(value))
    check = getattr(cls, "_check", None)
    if check is not None:  # what a range cannot say (an address, a list that may not be empty)
        check(self)


def _key(cls: Any, name: str) -> str:
    return f"{cls._section}.{name}" if cls._section else name


@_schema("reconstruction.association")
class AssociationConfig:
    """Cross-camera grouping of 2D people.

    Costs are epipolar distances divided by the person's size in the image (dimensionless), so
    near and far people are treated alike.
    """

    # joints below this confidence do not vote
    min_conf: float = number(0.3, ge=0.0, le=1.0)
    # a camera pair needs this many joints confident in both
    min_common_joints: int = number(3, integer=True, ge=1, le=NUM_JOINTS)
    # mean normalised epipolar distance accepted for a match
    max_cost: float = number(0.12, gt=0.0, le=100.0)
    reassign_leftovers: bool = True  # give unmatched detections to a reconstructed person
    # a tracked person's pose reprojected into a camera claims the detection within this mean
    # joint distance, divided by the detection's size
    track_max_cost: float = number(0.25, gt=0.0, le=100.0)
    # robust mode, frame-by-frame calls: the people of the previous frame (and of the few
    # frames before, for people missed since) seed the next frame as a tracked person's
    # predicted pose does, so their association and left/right labels carry over; 0: each
    # frame on its own
    continuity_frames: int = number(3, integer=True, ge=0, le=1000)


@_schema("reconstruction.triangulation")
class TriangulationConfig:
    """Triangulation of one person's joints from the views of its group."""

    mode: Mode = "robust"
    # joints below this confidence are not used
    min_conf: float = number(0.05, ge=0.0, le=1.0)
    # `pair` mode: weight per pixel of mean epipolar distance
    pair_a: float = number(0.01, ge=0.0, le=1e6)
    # `pair` mode: weight of the mean confidences of the two views
    pair_b: float = number(1.0, ge=0.0, le=1e6)
    # `robust`: reprojection error always accepted, pixels
    inlier_px: float = number(10.0, ge=0.0, le=1e5)
    # `robust`: ... or this fraction of the person's size in the view
    inlier_rel: float = number(0.03, ge=0.0, le=1.0)
    fix_swaps: bool = True  # `robust`: correct left/right labels swapped by the detector
    # `robust`: a joint seen in one view only is placed on that view's ray, at the point nearest
    # a reconstructed neighbouring joint (within one bone length of the truth); views = 1
    single_view: bool = True


@_schema("reconstruction.plausibility")
class PlausibilityConfig:
    """Rejection of reconstructed people that cannot be real."""

    # fewer joints reconstructed from two views or more: not a person
    min_joints: int = number(5, integer=True, ge=0, le=NUM_JOINTS)
    # lowest joint may be this far below the floor
    floor_tolerance_m: float = number(0.4, ge=0.0, le=_LENGTH_M)
    # vertical extent of a person's joints
    max_height_m: float = number(3.0, gt=0.0, le=_LENGTH_M)
    # a joint making a PCP limb longer than this is dropped
    max_limb_m: float = number(1.0, gt=0.0, le=_LENGTH_M)
    # seen by fewer than this fraction of the cameras that should see them: a ghost
    min_view_fraction: float = number(0.4, ge=0.0, le=1.0)


@_schema("reconstruction")
class ReconstructionConfig:
    association: AssociationConfig = field(default_factory=AssociationConfig)
    triangulation: TriangulationConfig = field(default_factory=TriangulationConfig)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)


@_schema("tracking")
class TrackingConfig:
    """Identities over time, online smoothing and positioning of reconstructed people."""

    enabled: bool = True  # false: per-frame people, ids 0..P-1 in each frame (memory "recent")
    # what the 3D stage remembers between frames (tracking.memory): "tracker" (Kalman tracks,
    # persistent ids), "recent" (the last continuity_frames frames seed the next, ids per
    # frame) or "none" (every frame on its own)
    memory: Literal["tracker", "recent", "none"] = "tracker"
    # a person gets an id after this many consecutive frames
    confirm_frames: int = number(3, integer=True, ge=1, le=100_000)
    # gaps up to this long are filled by prediction, flagged predicted
    bridge_s: float = number(0.2, ge=0.0, le=DAY_S)
    # an unseen person's predicted pose is looked for in images this long
    seed_s: float = number(0.4, ge=0.0, le=DAY_S)
    # an unseen person keeps their id this long, then the track ends
    max_lost_s: float = number(3.0, ge=0.0, le=DAY_S)
    # a returning person is this close to where they were last ...
    reid_radius_m: float = number(1.0, ge=0.0, le=_LENGTH_M)
    # ... plus walking at this speed for the time unseen
    reid_speed_mps: float = number(1.5, ge=0.0, le=100.0)
    # a new person this close to a tracked one is the same
    duplicate_radius_m: float = number(0.4, ge=0.0, le=_LENGTH_M)
    smoothing: bool = True  # false: raw per-frame joints (the filter still predicts gaps)
    # constant-velocity model: acceleration density, m^2/s^3 ...
    process_noise: float = number(3.0, gt=0.0, le=1e6)
    # ... times this for elbows and knees, squared for wrists, ankles
    limb_noise_factor: float = number(2.5, gt=0.0, le=1e3)
    # joint noise of a reconstruction from two views
    measurement_noise_m: float = number(0.03, gt=0.0, le=_LENGTH_M)
    # ... of a joint seen in one view (depth from a neighbour)
    single_view_noise_m: float = number(0.15, gt=0.0, le=_LENGTH_M)
    # a joint jumping farther than this from its prediction ...
    gate_m: float = number(0.25, gt=0.0, le=_LENGTH_M)
    # ... and this many standard deviations is not believed
    gate_sigmas: float = number(4.0, gt=0.0, le=1e3)
    # ... unless it stays there this many frames in a row
    gate_reset_frames: int = number(3, integer=True, ge=1, le=100_000)
    bone_lengths: bool = True  # keep each person's limb lengths at their running estimate

    @property
    def ids(self) -> bool:
        """Whether people keep ids over time: the tracker's memory (what zone events and
        two-way smoothing need)."""
        return self.enabled and self.memory == "tracker"


@_schema("cameras[]")
class CameraSource:
    """One camera of a run: its calibration name and where its frames come from."""

    name: str = ""
    source: str = ""  # a video file, a folder of images, or an rtsp:// / http:// URL
    # a recorded file played forward then backward for ever, time stamps increasing (serve)
    loop: bool = False
    # optional low-resolution substream (URL or file) used for detection; `source` is used for
    # clips; empty: `source` for both
    detect: str = ""


@_schema("nodes[]")
class NodeConfig:
    """One detection node (`stereopose detect-node CONFIG --node NAME`): its cameras."""

    name: str = ""
    cameras: tuple[str, ...] = ()


@_schema("detector")
class DetectorConfig:
    backend: Literal["onnx", "openvino", "ultralytics"] = "onnx"
    model: str | None = None  # a local .onnx or .pt file; default: yolo11n-pose from the cache
    # model input, long side
    imgsz: int = number(640, multiple_of=32, ge=32, le=8192)
    conf: float = number(0.25, ge=0.0, le=1.0)  # person score threshold
    iou: float = number(0.7, ge=0.0, le=1.0)  # NMS overlap threshold
    # cpu, cuda, cuda:N, tensorrt, tensorrt:N or auto; openvino: cpu, gpu, gpu.N or auto
    device: str = "cpu"
    # inference threads (default: all cores)
    threads: int | None = number(None, integer=True, ge=1, le=1024)
    # "fp32", "int8" (the INT8-quantised model; onnx only), "bf16" (openvino on a
    # CPU with bfloat16 instructions) or "fp16" (onnx on device tensorrt)
    precision: Literal["fp32", "bf16", "int8", "fp16"] = "fp32"
    # detect where the people are (their tracks, each camera's own people, motion, periodic
    # full scans), at the camera's own resolution (detection.regional); false: every camera's
    # whole frame at imgsz, every step
    regions: bool = True
    # each region's model input side (a multiple of 32): smaller regions are enlarged to it,
    # larger ones shrunk
    region_imgsz: int = number(320, multiple_of=32, ge=64, le=4096)
    # each camera's whole frame scanned this often (staggered across cameras), seconds: someone
    # who walked in unseen and stands still is found within this and one step
    full_scan_s: float = number(3.0, gt=0.0, le=3600.0)
    # grey levels of change that count as motion (lower: more sensitive)
    motion_threshold: int = number(25, integer=True, ge=1, le=255)
    # a region's people seen at least this many times as finely as in the whole frame at
    # imgsz (a person too large for a region at that detail is detected in the whole frame);
    # below 1: large people cost less, their joints a little less exact
    region_detail: float = number(1.0, gt=0.0, le=4.0)


@_schema("input")
class InputConfig:
    sync: Literal["index", "time"] = "index"  # recorded cameras aligned by frame index or time
    # time steps per second (default: the first camera's frame rate)
    fps: float | None = number(None, ge=FPS_MIN, le=FPS_MAX)
    # stop after this many time steps
    max_frames: int | None = number(None, integer=True, ge=1)
    # live cameras: how long one try to open a stream, or one read, may take, seconds
    open_timeout_s: float = number(5.0, gt=0.0, le=600.0)
    # live cameras: end the run (exit 2) if no camera delivers a frame within this (none: wait)
    first_frame_timeout_s: float | None = number(30.0, gt=0.0, le=DAY_S)
    # cap on detection steps per second (default: as fast as the detector allows)
    detect_fps: float | None = number(None, ge=FPS_MIN, le=FPS_MAX)
    # serve: a live camera with a detection substream keeps its full stream encoded, for the
    # clips' full-stream copies ("copy"; nothing decoded), or decodes it for the drawn clips
    full_streams: Literal["copy", "decode"] = "copy"
    # serve: where the cameras' 2D people come from: "local" (serve opens the cameras and
    # detects), or "nodes" (`stereopose detect-node` processes publish them on the site's
    # broker, [mqtt]; serve groups them into time steps by capture time)
    detection: Literal["local", "nodes"] = "local"
    # nodes: the cameras' frames within this many seconds of a step's first are one step
    # (default: half the step period, of detect_fps or else of the cameras' fps)
    node_window_s: float | None = number(None, gt=0.0, le=10.0)
    # nodes: the longest a step waits for its missing cameras, seconds after its first arrived
    node_wait_s: float = number(0.5, gt=0.0, le=10.0)
    # nodes: a node whose clock is off the service's by more than this is refused, seconds
    node_clock_tolerance_s: float = number(0.25, gt=0.0, le=3600.0)
    # nodes: each camera's picture (for the console and clips) sent this often, per second
    node_picture_hz: float = number(1.0, ge=0.0, le=30.0)
    # nodes: the pictures' scale of the calibration's size
    node_picture_scale: float = number(0.25, gt=0.0, le=1.0)


@_schema("outputs")
class OutputConfig:
    """What a run writes into its output folder."""

    poses: bool = True  # poses3d.jsonl
    events: bool = True  # events.jsonl and events.sqlite (with a site)
    trc: bool = True  # trc/person_<id>.trc
    csv: bool = True  # joints.csv
    two_way: bool = False  # trc/ and joints.csv smoothed both ways over each track, at the end
    overlays: bool = True  # overlays/<camera>.mp4: 2D skeletons, ids, reprojected 3D joints
    # overlay video size relative to the camera's frames
    overlay_scale: float = number(0.5, gt=0.0, le=1.0)
    report: bool = True  # report.html
    webhook: str | None = None  # POST each zone event to this URL


@_schema("serve")
class ServeConfig:
    """`stereopose serve`: its HTTP server and its health watch."""

    # address of the health/metrics server; anything but loopback is reachable from the network
    host: str = "127.0.0.1"
    port: int = number(8787, integer=True, ge=0, le=65535)  # 0: any free port
    # the console's address as others reach it (https://...): a control room links to it
    public_url: str = ""
    # a camera with no frame for this long raises camera_down
    camera_timeout_s: float = number(5.0, gt=0.0, le=DAY_S)
    # a camera's reprojection error above this many times its baseline: calibration_drift
    calib_warn_factor: float = number(2.0, gt=1.0, le=1000.0)
    # how often status.json (the health snapshot) is rewritten
    status_interval_s: float = number(10.0, gt=0.0, le=DAY_S)
    # HTTPS: a PEM certificate (chain) and its private key (relative to the config file; both
    # or neither; the key readable by its owner only)
    certificate: str | None = None
    key: str | None = None
    # Host names (and addresses) the service answers to besides the bound address, the
    # loopback names and, bound to 0.0.0.0, the machine's names and addresses; another Host
    # header is refused (421, against DNS rebinding). "*": any; "*.example.org": a domain.
    allowed_hosts: tuple[str, ...] = ()
    # reverse proxies in front of the service (addresses or networks, "10.0.0.0/24"): their
    # connections are not capped per address (every client behind one shares it), and the
    # client address they forward (X-Forwarded-For) counts for the login limits instead of
    # theirs; anyone else's X-Forwarded-For is ignored
    trusted_proxies: tuple[str, ...] = ()


@_schema("mqtt")
class MqttConfig:
    """Events, zone occupancy and people out over MQTT (serve); host empty: MQTT off."""

    host: str = ""
    port: int = number(1883, integer=True, ge=1, le=65535)
    site: str = "site"  # this installation's name, a topic level
    topic_prefix: str = "stereopose"
    username: str | None = None
    password: str | None = field(default=None, repr=False)  # never shown
    # or a file holding the password (its first line; relative to the config file), so the
    # configuration itself holds no secret and the file can be readable by the service only
    password_file: str | None = None
    tls: bool = False
    ca_file: str | None = None  # relative to the config file
    # people updates per second (0: none)
    people_hz: float = number(5.0, ge=0.0, le=1000.0)
    # messages held at most while the broker is away (then counted as dropped)
    queue_size: int = number(10_000, integer=True, ge=1, le=10_000_000)
    # the event log as an outbox: every stored event on <prefix>/<site>/log/events with its
    # id, sent again until a receiver confirms it (site.outbox, docs/mqtt.md)
    outbox: bool = True
    # the receiver's confirmed mark behind what was sent for this long: sent again (0: only on
    # a new connection)
    outbox_resend_s: float = number(30.0, ge=0.0, le=DAY_S)


@_schema("control_room")
class ControlRoomConfig:
    """`stereopose control-room` (stereopose.controlroom, docs/control-room.md)."""

    # the store: an SQLite file (relative to `output`; empty: <output>/control.sqlite), or
    # PostgreSQL: "postgresql://USER@HOST:PORT/DATABASE" (needs the `postgresql` extra)
    database: str = ""
    # the PostgreSQL password: a file readable by its owner only (relative to the config
    # file), so none is in the configuration; or in the URL
    database_password_file: str | None = None
    # a site with no message for this long is shown offline
    offline_after_s: float = number(90.0, gt=0.0, le=DAY_S)
    # a site whose clock is further than this from the control room's raises an incident
    clock_tolerance_s: float = number(5.0, gt=0.0, le=DAY_S)
    # this control room's name: a site's console shows an acknowledgement made here as
    # "USER via NAME"
    name: str = "control-room"
    # how often an acknowledgement not yet answered by its site is asked again
    command_resend_s: float = number(5.0, gt=0.0, le=3600.0)
    # several control-room workers on one PostgreSQL store: the MQTT shared subscription's
    # group they share the sites' messages in ("": one worker takes every message)
    shared_group: str = ""
    # the store keeps events (and closed incidents, answered acknowledgements) this long
    retention_days: float = number(365.0, gt=0.0, le=36500.0)
    # the sites that may report here (empty: any name, up to max_sites); a message from
    # another is refused, counted, and raises one control-room incident
    sites: tuple[str, ...] = ()
    max_sites: int = number(1000, integer=True, ge=1, le=100_000)
    # a site's outbox message (an event, an incident's change) larger than this is refused
    max_event_bytes: int = number(65_536, integer=True, ge=1024, le=16 << 20)
    # a heartbeat larger than this is refused (its summary: a few numbers and a status)
    max_heartbeat_bytes: int = number(8192, integer=True, ge=512, le=1 << 20)
    # an event id more than this beyond the last id its site announced is not taken as the
    # site's new mark: refused, counted, and a control-room incident
    ids_ahead: int = number(100_000, integer=True, ge=100, le=2**40)

    def _check(self) -> None:
        for s in self.sites:
            if not (0 < len(s) <= 200 and s.isprintable()):
                raise ConfigError(f"control_room.sites: {s[:40]!r}: 1 to 200 printable characters")
        if not (0 < len(self.name) <= 64 and self.name.isprintable()):
            raise ConfigError("control_room.name: 1 to 64 printable characters")
        g = self.shared_group
        if g and not (len(g) <= 64 and g.isprintable() and not set(g) & set("/+#")):
            raise ConfigError("control_room.shared_group: up to 64 printable characters, no / + #")


@_schema("iec104")
class Iec104Config:
    """serve's IEC 60870-5-104 outstation (stereopose.scada.iec104, docs/scada.md); needs the
    `scada` extra. Off unless enabled; `stereopose points CONFIG.toml` prints its points."""

    enabled: bool = False
    # the address it listens on (IPv4); anything but loopback is reachable from the network
    host: str = "127.0.0.1"
    port: int = number(2404, integer=True, ge=1, le=65535)
    common_address: int = number(1, integer=True, ge=1, le=65534)  # the station's ASDU address
    # the masters that may connect: IPv4 addresses or networks ("10.0.0.0/24"); others are
    # refused at connect
    allowed_clients: tuple[str, ...] = ("127.0.0.1",)
    # open connections at most (a master and its redundant twin); more are refused
    max_connections: int = number(2, integer=True, ge=1, le=64)
    # single commands that acknowledge a zone's or a priority's incidents (off: no command
    # point exists, a command is answered unknown)
    commands: bool = False
    # the time tags' clock: "utc", or "local" (the machine's time zone, as dispatch centres on
    # local time expect)
    time_tags: Literal["utc", "local"] = "utc"
    # point changes held at most for the outstation's thread (then counted as dropped)
    queue_size: int = number(10_000, integer=True, ge=1, le=10_000_000)
    # IEC 104's t3: a link silent this long is tested (TESTFR), and t1: a test or an I-frame
    # unanswered this long closes it (a master's t2, its acknowledgement delay, must stay
    # below t1: the standard's 10 s). A socket that does not speak IEC 104 holds a place for
    # their sum at most (the standard's t3 of 20 s let idle sockets hold the places for 35 s)
    test_after_s: int = number(3, integer=True, ge=1, le=255)
    answer_within_s: int = number(15, integer=True, ge=2, le=255)
    # a connection that has not started data transfer (STARTDT) this long after it opened is
    # closed; and when every place is taken, a new master takes the place of the oldest
    # connection not transferring data
    start_within_s: float = number(5.0, gt=0, le=255)

    def _check(self) -> None:
        import ipaddress

        try:
            ipaddress.IPv4Address(self.host)
        except ValueError:
            raise ConfigError(
                f"iec104.host: expected an IPv4 address to listen on, got {self.host!r}"
            ) from None
        if not self.allowed_clients:
            raise ConfigError("iec104.allowed_clients: empty, so no master could connect")
        for i, a in enumerate(self.allowed_clients):
            try:
                ipaddress.IPv4Network(a, strict=False)
            except ValueError:
                raise ConfigError(
                    f"iec104.allowed_clients[{i}]: expected an IPv4 address or "
                    f'network ("10.0.0.0/24"), got {a!r}'
                ) from None


OpcuaPolicy = Literal[
    "Basic256Sha256_SignAndEncrypt",
    "Basic256Sha256_Sign",
    "Aes128Sha256RsaOaep_SignAndEncrypt",
    "Aes128Sha256RsaOaep_Sign",
    "Aes256Sha256RsaPss_SignAndEncrypt",
    "Aes256Sha256RsaPss_Sign",
]


@_schema("opcua")
class OpcuaConfig:
    """serve's OPC UA server (stereopose.scada.opcua, docs/scada.md): the site, its zones,
    cameras and counts, and each incident as an Alarms and Conditions alarm; needs the `scada`
    extra. Off unless enabled. Clients log in as the console's users (operator or admin to
    acknowledge)."""

    enabled: bool = False
    # the address it listens on; anything but loopback is reachable from the network
    host: str = "127.0.0.1"
    port: int = number(4840, integer=True, ge=1, le=65535)
    path: str = "/stereopose"  # the endpoint: opc.tcp://host:port/path
    site: str = "site"  # this installation's name: the site object's name in the address space
    # the server's application instance certificate (DER or PEM) and its private key (PEM),
    # relative to the config file, both or neither (the key readable by its owner only);
    # neither: a self-signed pair made once in <output>/opcua/, its thumbprint logged
    certificate: str | None = None
    key: str | None = None
    # a folder of the client certificates that may connect (relative to the config file);
    # unset: any client certificate, the user login decides
    trusted_clients: str | None = None
    # the security policies offered, all signed; no unsecured endpoint is ever offered
    security: tuple[OpcuaPolicy, ...] = ("Basic256Sha256_SignAndEncrypt",)
    # clients without a login may browse and subscribe (never acknowledge)
    allow_anonymous: bool = False
    # client connections at most (more are refused at connect)
    max_connections: int = number(16, integer=True, ge=1, le=1000)
    # incident changes held at most for the server's thread (then counted as dropped)
    queue_size: int = number(10_000, integer=True, ge=1, le=10_000_000)

    def _check(self) -> None:
        import ipaddress
        import re

        try:
            ipaddress.ip_address(self.host)
        except ValueError:
            raise ConfigError(
                f"opcua.host: expected an IP address to listen on, got {self.host!r}"
            ) from None
        if not re.fullmatch(r"(/[A-Za-z0-9._~-]+)*/?", self.path) or len(self.path) > 200:
            raise ConfigError(
                f'opcua.path: expected a URL path such as "/stereopose", got {self.path!r}'
            )
        if not self.site or len(self.site) > 64 or not self.site.isprintable():
            raise ConfigError(f"opcua.site: 1 to 64 printable characters, got {self.site!r}")
        if bool(self.certificate) != bool(self.key):
            raise ConfigError("opcua.certificate and opcua.key: give both or neither")
        if not self.security:
            raise ConfigError("opcua.security: empty, so no client could connect")
        for i, name in enumerate(self.security):
            if name not in get_args(OpcuaPolicy):
                raise ConfigError(
                    f"opcua.security[{i}]: expected one of "
                    f"{list(get_args(OpcuaPolicy))}, got {name!r}"
                )


@_schema("storage")
class StorageConfig:
    """What serve keeps in its output folder, and for how long."""

    # seconds of poses per segment file
    segment_s: float = number(3600.0, ge=1.0, le=DAY_S)
    # pose segments are deleted after this many days
    retention_days: float = number(7.0, gt=0.0, le=36500.0)
    # pose segments and clips together at most this many GB (0: no cap)
    max_gb: float = number(20.0, ge=0.0, le=1e6)
    clip_retention_days: float = number(30.0, gt=0.0, le=36500.0)
    event_retention_days: float = number(365.0, gt=0.0, le=36500.0)
    clips: bool = True  # an MP4 per camera for each alarm
    # seconds of clip before and after an alarm
    clip_pre_s: float = number(5.0, ge=0.0, le=60.0)
    clip_post_s: float = number(5.0, ge=0.0, le=600.0)
    # seconds between retention passes
    maintenance_interval_s: float = number(60.0, gt=0.0, le=DAY_S)


@_schema("")
class Config:
    # time base when the input has none
    fps: float = number(25.0, ge=FPS_MIN, le=FPS_MAX)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    # what `stereopose run` reads and writes; paths are relative to the config file
    calibration: str | None = None
    site: str | None = None
    output: str = "out/run"
    cameras: tuple[CameraSource, ...] = ()
    nodes: tuple[NodeConfig, ...] = ()
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    input: InputConfig = field(default_factory=InputConfig)
    outputs: OutputConfig = field(default_factory=OutputConfig)
    serve: ServeConfig = field(default_factory=ServeConfig)
    mqtt: MqttConfig = field(default_factory=MqttConfig)
    iec104: Iec104Config = field(default_factory=Iec104Config)
    opcua: OpcuaConfig = field(default_factory=OpcuaConfig)
    storage: StorageConfig = field(default_factory=StorageConfig)
    control_room: ControlRoomConfig = field(default_factory=ControlRoomConfig)


def _check_value(value: Any, tp: Any, where: str) -> Any:
    origin = get_origin(tp)
    if origin in (Union, types.UnionType):
        options = [a for a in get_args(tp) if a is not type(None)]
        return _check_value(value, options[0], where) if len(options) == 1 else value
    if origin is tuple:
        item = get_args(tp)[0]
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {shown(where, value)}")
        if dataclasses.is_dataclass(item):
            return tuple(from_dict(item, v, f"{where}[{i}]") for i, v in enumerate(value))
        return tuple(_check_value(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is Literal:
        if value not in get_args(tp):
            raise ConfigError(
                f"{where}: expected one of {list(get_args(tp))}, got {shown(where, value)}"
            )
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {shown(where, value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {shown(where, value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {shown(where, value)}")
        try:
            return float(value)
        except OverflowError:  # an integer beyond any float: its range check names it
            return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {shown(where, value)}")
        return value
    return value


def from_dict(cls: type, data: dict[str, Any], where: str) -> Any:
    """Build dataclass `cls` from a (possibly partial) dict, rejecting unknown keys and values
    out of range."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {shown(where, data)}")
    hints = get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}"
        )
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        tp = hints[key]
        sub = f"{where}.{key}" if where else key
        if dataclasses.is_dataclass(tp):
            kwargs[key] = from_dict(tp, value, sub)
        else:
            kwargs[key] = _check_value(value, tp, sub)
    return cls(**kwargs)


def read_toml(path: Path, what: str) -> dict[str, Any]:
    """A TOML file's tables; a missing, unreadable, oversized or invalid file is a ConfigError
    naming it (`what`: what the file is, for the message)."""
    raw = read_limited(path, what, ConfigError)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: cannot read {what}: {e}") from None
    return parse_toml(text, path)


def parse_toml(text: str, path: Path | str) -> dict[str, Any]:
    """TOML text -> tables; any parse failure is a ConfigError naming `path`."""
    try:
        return tomllib.loads(text)
    except ValueError as e:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    except RecursionError:  # tomllib recurses once per level of nested arrays or tables
        raise ConfigError(f"{path}: invalid TOML: arrays or tables nested too deeply") from None


def load_config(path: str | Path | None = None) -> Config:
    """Defaults, overridden by the TOML file at `path` when given."""
    if path is None:
        return Config()
    path = Path(path)
    data = read_toml(path, "configuration file")
    try:
        return from_dict(Config, data, "")
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}".replace(": : ", ": ")) from None


def _replace(obj: _T, values: dict[str, Any], where: str) -> _T:
    try:
        return dataclasses.replace(obj, **values)
    except TypeError as e:  # an unknown field
        raise ConfigError(f"{where}: {e}") from None


def with_overrides(config: Config, **sections: dict[str, Any]) -> Config:
    """A copy of `config` with fields of its sections replaced: `tracking`, or one of the
    reconstruction sections; the new values are checked as a file's would be.

    Example: with_overrides(cfg, triangulation={"mode": "pair"}, tracking={"enabled": False}).
    """
    if "tracking" in sections:
        tracking = _replace(config.tracking, sections.pop("tracking"), "tracking")
        config = dataclasses.replace(config, tracking=tracking)
    rec = config.reconstruction
    for name, values in sections.items():
        current = getattr(rec, name, None)
        if not dataclasses.is_dataclass(current):
            raise ConfigError(f"reconstruction: no section {name!r}")
        rec = dataclasses.replace(
            rec, **{name: _replace(current, values, f"reconstruction.{name}")}
        )
    return dataclasses.replace(config, reconstruction=rec)


def check_options(args: argparse.Namespace, *sections: type) -> None:
    """Check command-line options against the ranges of the schema fields of the same name in
    `sections` (e.g. InputConfig: --fps, --max-frames); an error names the option."""
    for cls in sections:
        for name, (rng, _, _) in cls._ranges.items():
            value = getattr(args, name, None)
            if value is not None:
                rng.check(value, f"--{name.replace('_', '-')}")
