"""`stereopose run`: cameras -> detection -> 3D people -> tracks -> zone events -> one folder.

The output folder holds ``poses3d.jsonl``, ``events.jsonl`` and ``events.sqlite`` (with a site),
``trc/person_<id>.trc``, ``joints.csv``, ``tracks.json``, ``overlays/<camera>.mp4``,
``report.html``, ``summary.json`` (frames, time per stage, people, events, reprojection error per
camera) and what the report needs to be rebuilt: ``config.toml`` (the configuration used),
``calib.toml`` and ``site.toml``. The folder holds one run: a previous run's outputs there are
refused, or replaced with ``overwrite``; a user's file is never written over (pipeline.paths).

Recorded cameras are processed as fast as possible; live cameras in real time, each step taking
every camera's newest frame. Ctrl-C (SIGINT) ends the run after the current step: every output is
flushed and closed, and the summary and report are written.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from stereopose.calibration.formats import load_calibration
from stereopose.config import Config, DetectorConfig, load_config
from stereopose.config_refs import resolve, source_path
from stereopose.detection import make_detector
from stereopose.errors import ConfigError, StereoposeError
from stereopose.fence import Site, load_site
from stereopose.io.cameraset import CameraSet
from stereopose.io.summary import CAMERA_STAGES, CameraStats, RunSummary
from stereopose.io.video import ImageFolder, VideoFile, is_stream, open_source
from stereopose.pipeline.detect import READ_AHEAD
from stereopose.pipeline.loop import run_frames
from stereopose.pipeline.outputs import Outputs, check_outputs
from stereopose.pipeline.paths import (
    Place,
    check_places,
    in_run_folder,
    output_places,
    places,
    previous_outputs,
    remove_outputs,
    run_products,
)
from stereopose.pipeline.pipelined import PipelinedCameras
from stereopose.pipeline.reconstruct import save_inputs
from stereopose.pipeline.sources import Cameras, check_size, detecting_cameras
from stereopose.secrets import masked_toml
from stereopose.tickets.ticket import Ticket, check_ticket_site
from stereopose.types import Event, Rig
from stereopose.zones.state_log import StateLogFile

if TYPE_CHECKING:
    from stereopose.detection.base import PoseDetector

__all__ = ["STAGES", "CameraStats", "RunSummary", "check_run_config", "run"]

logger = logging.getLogger(__name__)

STAGES = CAMERA_STAGES


def check_run_config(cfg: Config, path: Path) -> None:
    """What `run` needs beyond the schema: a calibration and at least two named cameras."""
    if not cfg.calibration:
        raise ConfigError(f"{path}: 'calibration' (the calibration file) is required")
    if len(cfg.cameras) < 2:
        raise ConfigError(
            f"{path}: at least 2 [[cameras]] (name and source) are needed, got {len(cfg.cameras)}"
        )
    names = [c.name for c in cfg.cameras]
    for i, c in enumerate(cfg.cameras):
        if not c.name or not c.source:
            raise ConfigError(f"{path}: cameras[{i}] needs both 'name' and 'source'")
    if len(set(names)) != len(names):
        raise ConfigError(f"{path}: camera names must be unique, got {', '.join(names)}")


def _inputs(
    config_path: Path, calib: Path, site: Path | None, sources: list[str], model: Path | None
) -> list[Place]:
    """Every path a run reads, named by its configuration key."""
    found = places(
        ("configuration", config_path),
        ("calibration", calib),
        ("site", site),
        ("detector.model", model),
    )
    found += [
        Place(f"cameras[{i}].source", Path(s)) for i, s in enumerate(sources) if not is_stream(s)
    ]
    return found


def _outputs(outputs: Outputs, out_dir: Path, cameras: list[str], site: bool) -> list[Place]:
    """Every path a run writes in its folder: the outputs, each camera's overlay video, and
    the copies of the configuration, calibration and site used."""
    # the overlay folder as its files: the run's other outputs are never inside it
    found = [p for p in output_places(outputs, in_run_folder) if p.path != outputs.overlays_dir]
    if outputs.overlays_dir is not None:
        found += [
            Place(f"overlays/{n}.mp4 in the output folder", outputs.overlays_dir / f"{n}.mp4")
            for n in cameras
        ]
    copies = ("config.toml", "calib.toml", "site.toml") if site else ("config.toml", "calib.toml")
    return found + [
        Place(f"{n} in the output folder (a copy of the one used)", out_dir / n) for n in copies
    ]


def _camera_source(
    cams: CameraSet, rig: Rig, detector: PoseDetector, settings: DetectorConfig, site: Site | None
) -> Cameras | PipelinedCameras:
    """Live cameras: detection on its own thread, always on the newest frames. Recorded ones
    keep the plain source: every frame is detected in turn, and the outputs stay the same.
    settings: [detector] regions and its settings (detection.regional), night
    (detection.light); site: where workers matter, for the regions' scans (None: anywhere)."""
    cameras = detecting_cameras(cams, rig, detector, settings, site)
    return PipelinedCameras(cameras) if cams.live else cameras


def _holds_secrets(cfg: Config) -> bool:
    """Whether the configuration holds a password or a URL with credentials in it."""
    urls = [cfg.outputs.webhook or "", *(c.source for c in cfg.cameras)]
    urls += [c.detect for c in cfg.cameras if c.detect]
    return bool(cfg.mqtt.password) or any(_credentials(u) for u in urls if "://" in u)


def _credentials(url: str) -> bool:
    try:
        return urlsplit(url).username is not None
    except ValueError:  # not a URL one can parse: treat as holding a secret
        return True


def copy_config(source: Path, target: Path, secret: bool) -> None:
    """The configuration copied into the run folder (for `report`), its secrets masked (a
    password's value hidden, URLs without their password: secrets.masked_toml); readable by
    its owner only when the original held a secret."""
    text = masked_toml(source.read_text(encoding="utf-8"))
    target.unlink(missing_ok=True)  # a new file, so the mode below is the one it gets
    fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if secret else 0o644)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)


def check_recorded_sizes(rig: Rig, names: list[str], sources: list[str]) -> None:
    """Each recorded camera's first frame has its calibration's size (pipeline.sources.
    check_size); live cameras are checked at their first frame, as they come."""
    for name, spec in zip(names, sources, strict=True):
        if is_stream(spec):
            continue
        source = open_source(spec, name)
        assert isinstance(source, (VideoFile, ImageFolder))  # a recording
        try:
            first = source.read()
        finally:
            source.close()
        if first is not None and first[2] is not None:
            check_size(rig[name], first[2])


def run_rig(config_path: Path, calib_path: Path, cfg: Config) -> Rig:
    """The calibration's cameras that the configuration names, in its order; a camera the
    calibration lacks is a ConfigError naming both files."""
    rig = load_calibration(calib_path)
    names = [c.name for c in cfg.cameras]
    unknown = [n for n in names if n not in rig.names]
    if unknown:
        raise ConfigError(
            f"{config_path}: camera(s) {', '.join(unknown)} not in the calibration {calib_path} "
            f"(which has {', '.join(rig.names)})"
        )
    return rig.subset(names)


def run(
    config_path: str | Path,
    on_step: Callable[[int, int | None, float], None] | None = None,
    on_events: Callable[[list[Event]], None] | None = None,
    stop: threading.Event | None = None,
    overwrite: bool = False,
    ticket: Ticket | None = None,
    zone_states: str | Path | None = None,
) -> RunSummary:
    """Run the configuration at ``config_path`` end to end; returns what it did.

    zone_states: a switching log (zones.state_log) the recording's energized zones are judged
    with (None: every zone live); it needs the configuration's site.

    on_step(done, total, fps) after each time step; on_events(events) for each step's zone
    events; ``stop`` (or SIGINT) ends the run after the current step. No output may be an
    input or lie inside an input folder (pipeline.paths); an output folder holding a previous
    run's outputs is refused unless ``overwrite``, which removes them (and only them) first.
    """
    config_path = Path(config_path)
    cfg = load_config(config_path)
    check_run_config(cfg, config_path)
    base = config_path.resolve().parent
    calib_path = resolve(base, cfg.calibration or "")  # given: check_run_config
    rig = run_rig(config_path, calib_path, cfg)
    names = [c.name for c in cfg.cameras]
    site_path = resolve(base, cfg.site) if cfg.site else None
    site = load_site(site_path) if site_path is not None else None
    sources = [source_path(base, c.source) for c in cfg.cameras]
    substreams = [source_path(base, c.detect) for c in cfg.cameras]
    det = cfg.detector
    model = resolve(base, det.model) if det.model else None
    out_dir = resolve(base, cfg.output)
    outputs = Outputs.run_folder(out_dir, cfg.outputs, site)
    check_outputs(cfg, site, outputs)
    check_ticket_site(ticket, site)
    states = None
    if zone_states is not None:
        if site is None:
            raise ConfigError(f"{config_path}: --zone-states needs a site (`site` in the file)")
        states = StateLogFile.read(zone_states, site.zones)
    inputs = _inputs(config_path, calib_path, site_path, sources, model)
    inputs += [
        Place(f"cameras[{i}].detect", Path(d))
        for i, d in enumerate(substreams)
        if d and not is_stream(d)
    ]
    hint = f'set `output` in {config_path} to a folder of its own (such as "out/run")'
    check_places(inputs, _outputs(outputs, out_dir, names, site is not None), hint)
    folder = Place(f"{config_path}: the output folder", out_dir)
    previous = previous_outputs(folder, run_products, overwrite, inputs)
    detector = make_detector(
        det.backend, model, det.imgsz, det.conf, det.iou, det.device, det.threads, det.precision
    )
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise StereoposeError(f"{out_dir}: cannot create the output folder: {e.strerror}") from None
    check_recorded_sizes(rig, names, sources)  # before any output: a wrong file writes nothing
    with CameraSet(
        sources,
        names,
        cfg.input.sync,
        cfg.input.fps,
        cfg.input.max_frames,
        open_timeout_s=cfg.input.open_timeout_s,
        first_frame_timeout_s=cfg.input.first_frame_timeout_s,
        loop=[c.loop for c in cfg.cameras],
        detect=[d or None for d in substreams],
        detect_fps=cfg.input.detect_fps,
        read_ahead=READ_AHEAD,
        decoders=cfg.input.decoders,
    ) as cams:
        cfg = dataclasses.replace(cfg, fps=cams.fps)
        remove_outputs(previous)  # every check passed and every camera opened: now replace
        copy_config(config_path, out_dir / "config.toml", secret=_holds_secrets(cfg))
        save_inputs(out_dir, rig, site, ticket)
        return run_frames(
            rig,
            cfg,
            _camera_source(cams, rig, detector, det, site),
            outputs,
            site,
            calib_path=cfg.calibration or "",
            label=", ".join(cams.names),
            on_events=on_events,
            stop=stop,
            on_step=on_step,
            out_dir=out_dir,
            config_path=config_path,
            ticket=ticket,
            zone_states=states,
        )
