"""`stereopose run`: cameras -> detection -> 3D people -> tracks -> zone events -> one folder.

The output folder holds ``poses3d.jsonl``, ``events.jsonl`` and ``events.sqlite`` (with a site),
``trc/person_<id>.trc``, ``joints.csv``, ``tracks.json``, ``overlays/<camera>.mp4``,
``report.html``, ``summary.json`` (frames, time per stage, people, events, reprojection error per
camera) and what the report needs to be rebuilt: ``config.toml`` (the configuration used),
``calib.toml`` and ``site.toml``.

Recorded cameras are processed as fast as possible; live cameras in real time, each step taking
every camera's newest frame. Ctrl-C (SIGINT) ends the run after the current step: every output is
flushed and closed, and the summary and report are written.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable
from pathlib import Path

from stereopose.calibration.formats import load_calibration
from stereopose.config import Config, load_config
from stereopose.detection import make_detector
from stereopose.errors import ConfigError, StereoposeError
from stereopose.fence import load_site
from stereopose.io.summary import CAMERA_STAGES, CameraStats, RunSummary
from stereopose.io.video import CameraSet, is_stream
from stereopose.pipeline.loop import run_frames
from stereopose.pipeline.outputs import Outputs, check_outputs
from stereopose.pipeline.reconstruct import save_inputs
from stereopose.pipeline.sources import Cameras
from stereopose.types import Event

__all__ = ["STAGES", "CameraStats", "RunSummary", "check_run_config", "run"]

logger = logging.getLogger(__name__)

STAGES = CAMERA_STAGES


def _resolve(base: Path, value: str) -> Path:
    p = Path(value).expanduser()
    return p if p.is_absolute() else base / p


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


def run(
    config_path: str | Path,
    on_step: Callable[[int, int | None, float], None] | None = None,
    on_events: Callable[[list[Event]], None] | None = None,
    stop: threading.Event | None = None,
) -> RunSummary:
    """Run the configuration at ``config_path`` end to end; returns what it did.

    on_step(done, total, fps) after each time step; on_events(events) for each step's zone
    events; ``stop`` (or SIGINT) ends the run after the current step.
    """
    config_path = Path(config_path)
    cfg = load_config(config_path)
    check_run_config(cfg, config_path)
    base = config_path.resolve().parent
    calib_path = _resolve(base, cfg.calibration)
    rig = load_calibration(calib_path)
    names = [c.name for c in cfg.cameras]
    unknown = [n for n in names if n not in rig.names]
    if unknown:
        raise ConfigError(
            f"{config_path}: camera(s) {', '.join(unknown)} not in the calibration {calib_path} "
            f"(which has {', '.join(rig.names)})"
        )
    rig = rig.subset(names)
    site = load_site(_resolve(base, cfg.site)) if cfg.site else None
    sources = [c.source if is_stream(c.source) else str(_resolve(base, c.source)) for c in
               cfg.cameras]  # fmt: skip
    det = cfg.detector
    model = _resolve(base, det.model) if det.model else None
    detector = make_detector(
        det.backend, model, det.imgsz, det.conf, det.iou, det.device, det.threads
    )
    out_dir = _resolve(base, cfg.output)
    outputs = Outputs.run_folder(out_dir, cfg.outputs, site)
    check_outputs(cfg, site, outputs)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise StereoposeError(f"{out_dir}: cannot create the output folder: {e.strerror}") from None
    with CameraSet(sources, names, cfg.input.sync, cfg.input.fps, cfg.input.max_frames) as cams:
        cfg = dataclasses.replace(cfg, fps=cams.fps)
        (out_dir / "config.toml").write_text(config_path.read_text(encoding="utf-8"))
        save_inputs(out_dir, rig, site)
        return run_frames(
            rig, cfg, Cameras(cams, rig, detector), outputs, site,
            calib_path=cfg.calibration or "", label=", ".join(cams.names), on_events=on_events,
            stop=stop, on_step=on_step, out_dir=out_dir, config_path=config_path,
        )  # fmt: skip
