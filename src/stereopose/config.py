"""The one typed configuration schema; every default lives here.

A TOML file overrides any subset of it; unknown tables or keys are rejected with an error that
names the file and the key.
"""

from __future__ import annotations

import dataclasses
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from stereopose.errors import ConfigError

Mode = Literal["pair", "weighted", "robust"]
MODES: tuple[str, ...] = get_args(Mode)


@dataclass(frozen=True)
class AssociationConfig:
    """Cross-camera grouping of 2D people.

    Costs are epipolar distances divided by the person's size in the image (dimensionless), so
    near and far people are treated alike.
    """

    min_conf: float = 0.3  # joints below this confidence do not vote
    min_common_joints: int = 3  # a camera pair needs this many joints confident in both
    max_cost: float = 0.12  # mean normalised epipolar distance accepted for a match
    reassign_leftovers: bool = True  # give unmatched detections to a reconstructed person
    # a tracked person's pose reprojected into a camera claims the detection within this mean
    # joint distance, divided by the detection's size
    track_max_cost: float = 0.25
    # robust mode, frame-by-frame calls: the people of the previous frame (and of the few
    # frames before, for people missed since) seed the next frame as a tracked person's
    # predicted pose does, so their association and left/right labels carry over; 0: each
    # frame on its own
    continuity_frames: int = 3


@dataclass(frozen=True)
class TriangulationConfig:
    """Triangulation of one person's joints from the views of its group."""

    mode: Mode = "robust"
    min_conf: float = 0.05  # joints below this confidence are not used
    pair_a: float = 0.01  # `pair` mode: weight per pixel of mean epipolar distance
    pair_b: float = 1.0  # `pair` mode: weight of the mean confidences of the two views
    inlier_px: float = 10.0  # `robust`: reprojection error always accepted, pixels
    inlier_rel: float = 0.03  # `robust`: ... or this fraction of the person's size in the view
    fix_swaps: bool = True  # `robust`: correct left/right labels swapped by the detector
    # `robust`: a joint seen in one view only is placed on that view's ray, at the point nearest
    # a reconstructed neighbouring joint (within one bone length of the truth); views = 1
    single_view: bool = True


@dataclass(frozen=True)
class PlausibilityConfig:
    """Rejection of reconstructed people that cannot be real."""

    min_joints: int = 5  # fewer joints reconstructed from two views or more: not a person
    floor_tolerance_m: float = 0.4  # lowest joint may be this far below the floor
    max_height_m: float = 3.0  # vertical extent of a person's joints
    max_limb_m: float = 1.0  # a joint making a PCP limb longer than this is dropped
    # seen by fewer than this fraction of the cameras that should see them: a ghost
    min_view_fraction: float = 0.4


@dataclass(frozen=True)
class ReconstructionConfig:
    association: AssociationConfig = field(default_factory=AssociationConfig)
    triangulation: TriangulationConfig = field(default_factory=TriangulationConfig)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)


@dataclass(frozen=True)
class TrackingConfig:
    """Identities over time, online smoothing and positioning of reconstructed people."""

    enabled: bool = True  # false: per-frame people, ids 0..P-1 in each frame (memory "recent")
    # what the 3D stage remembers between frames (tracking.memory): "tracker" (Kalman tracks,
    # persistent ids), "recent" (the last continuity_frames frames seed the next, ids per
    # frame) or "none" (every frame on its own)
    memory: Literal["tracker", "recent", "none"] = "tracker"
    confirm_frames: int = 3  # a person gets an id after this many consecutive frames
    bridge_s: float = 0.2  # gaps up to this long are filled by prediction, flagged predicted
    seed_s: float = 0.4  # an unseen person's predicted pose is looked for in images this long
    max_lost_s: float = 3.0  # an unseen person keeps their id this long, then the track ends
    reid_radius_m: float = 1.0  # a returning person is this close to where they were last ...
    reid_speed_mps: float = 1.5  # ... plus walking at this speed for the time unseen
    duplicate_radius_m: float = 0.4  # a new person this close to a tracked one is the same
    smoothing: bool = True  # false: raw per-frame joints (the filter still predicts gaps)
    process_noise: float = 3.0  # constant-velocity model: acceleration density, m^2/s^3 ...
    limb_noise_factor: float = (
        2.5  # ... times this for elbows and knees, squared for wrists, ankles
    )
    measurement_noise_m: float = 0.03  # joint noise of a reconstruction from two views
    single_view_noise_m: float = 0.15  # ... of a joint seen in one view (depth from a neighbour)
    gate_m: float = 0.25  # a joint jumping farther than this from its prediction ...
    gate_sigmas: float = 4.0  # ... and this many standard deviations is not believed
    gate_reset_frames: int = 3  # ... unless it stays there this many frames in a row
    bone_lengths: bool = True  # keep each person's limb lengths at their running estimate

    @property
    def ids(self) -> bool:
        """Whether people keep ids over time: the tracker's memory (what zone events and
        two-way smoothing need)."""
        return self.enabled and self.memory == "tracker"


@dataclass(frozen=True)
class CameraSource:
    """One camera of a run: its calibration name and where its frames come from."""

    name: str = ""
    source: str = ""  # a video file, a folder of images, or an rtsp:// / http:// URL


@dataclass(frozen=True)
class DetectorConfig:
    backend: Literal["onnx", "ultralytics"] = "onnx"
    model: str | None = None  # a local .onnx or .pt file; default: yolo11n-pose from the cache
    imgsz: int = 640  # model input, long side (a multiple of 32)
    conf: float = 0.25  # person score threshold
    iou: float = 0.7  # NMS overlap threshold
    device: str = "cpu"  # cpu, cuda, cuda:N or auto
    threads: int | None = None  # inference threads (default: all cores)


@dataclass(frozen=True)
class InputConfig:
    sync: Literal["index", "time"] = "index"  # recorded cameras aligned by frame index or time
    fps: float | None = None  # time steps per second (default: the first camera's frame rate)
    max_frames: int | None = None  # stop after this many time steps


@dataclass(frozen=True)
class OutputConfig:
    """What a run writes into its output folder."""

    poses: bool = True  # poses3d.jsonl
    events: bool = True  # events.jsonl and events.sqlite (with a site)
    trc: bool = True  # trc/person_<id>.trc
    csv: bool = True  # joints.csv
    two_way: bool = False  # trc/ and joints.csv smoothed both ways over each track, at the end
    overlays: bool = True  # overlays/<camera>.mp4: 2D skeletons, ids, reprojected 3D joints
    overlay_scale: float = 0.5  # overlay video size relative to the camera's frames
    report: bool = True  # report.html
    webhook: str | None = None  # POST each zone event to this URL


@dataclass(frozen=True)
class Config:
    fps: float = 25.0  # time base when the input has none
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    # what `stereopose run` reads and writes; paths are relative to the config file
    calibration: str | None = None
    site: str | None = None
    output: str = "out/run"
    cameras: tuple[CameraSource, ...] = ()
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    input: InputConfig = field(default_factory=InputConfig)
    outputs: OutputConfig = field(default_factory=OutputConfig)


def _check_value(value: Any, tp: Any, where: str) -> Any:
    origin = get_origin(tp)
    if origin in (Union, types.UnionType):
        options = [a for a in get_args(tp) if a is not type(None)]
        return _check_value(value, options[0], where) if len(options) == 1 else value
    if origin is tuple:
        item = get_args(tp)[0]
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if dataclasses.is_dataclass(item):
            return tuple(from_dict(item, v, f"{where}[{i}]") for i, v in enumerate(value))
        return tuple(_check_value(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is Literal:
        if value not in get_args(tp):
            raise ConfigError(f"{where}: expected one of {list(get_args(tp))}, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type, data: dict[str, Any], where: str) -> Any:
    """Build dataclass `cls` from a (possibly partial) dict, rejecting unknown keys."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {data!r}")
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
    """A TOML file's tables; a missing, unreadable or invalid file is a ConfigError naming it
    (`what`: what the file is, for the message)."""
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: {what} not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read {what}: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from None


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


def with_overrides(config: Config, **sections: dict[str, Any]) -> Config:
    """A copy of `config` with fields of its sections replaced: `tracking`, or one of the
    reconstruction sections.

    Example: with_overrides(cfg, triangulation={"mode": "pair"}, tracking={"enabled": False}).
    """
    if "tracking" in sections:
        tracking = dataclasses.replace(config.tracking, **sections.pop("tracking"))
        config = dataclasses.replace(config, tracking=tracking)
    rec = config.reconstruction
    for name, values in sections.items():
        current = getattr(rec, name)
        rec = dataclasses.replace(rec, **{name: dataclasses.replace(current, **values)})
    return dataclasses.replace(config, reconstruction=rec)
