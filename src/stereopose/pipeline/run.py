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
import json
import logging
import shutil
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.config import Config, load_config
from stereopose.detection import make_detector
from stereopose.errors import ConfigError, StereoposeError
from stereopose.fence import Site, load_site, save_site
from stereopose.geometry.camera import project
from stereopose.io.video import CameraSet, is_stream
from stereopose.pipeline.detect import detect_step
from stereopose.pipeline.stages import Back3D, ReconstructionSummary
from stereopose.skeleton import SWAP
from stereopose.types import Event, People2D, People3D, Rig
from stereopose.viz.overlay import OverlayVideo

logger = logging.getLogger(__name__)

STAGES = ("decode", "detect", "3d", "fences", "write", "overlays")


@dataclass
class CameraStats:
    frames: int = 0
    detections: int = 0
    reprojection_px: list[float] = field(default_factory=list, repr=False)

    def as_dict(self) -> dict:
        e = self.reprojection_px
        return {
            "frames": self.frames,
            "detections_per_frame": self.detections / self.frames if self.frames else 0.0,
            "reprojection_median_px": float(np.median(e)) if e else None,
            "reprojection_mean_px": float(np.mean(e)) if e else None,
            "joints_compared": len(e),
        }


@dataclass
class RunSummary:
    """What a run did; written to summary.json."""

    out_dir: Path
    config_path: Path | None  # None: a reconstruction from keypoint files
    cameras: tuple[str, ...]
    live: bool = False
    fps_input: float = 0.0
    steps: int = 0
    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(STAGES, 0.0))
    wall_s: float = 0.0
    camera_stats: dict[str, CameraStats] = field(default_factory=dict)
    sources: dict[str, dict] = field(default_factory=dict)
    events: dict[str, int] = field(default_factory=dict)
    people: list[dict] = field(default_factory=list)
    people_per_frame: float = 0.0
    reprojection_median_px: float | None = None
    outputs: list[Path] = field(default_factory=list)
    interrupted: bool = False

    @property
    def fps(self) -> float:
        return self.steps / self.wall_s if self.wall_s > 0 else 0.0

    def stage_fps(self) -> dict[str, float | None]:
        return {k: (self.steps / v if v > 0 else None) for k, v in self.seconds.items()}

    def as_dict(self) -> dict:
        return {
            "config": str(self.config_path) if self.config_path else None,
            "cameras": list(self.cameras),
            "live": self.live,
            "fps_input": self.fps_input,
            "frames": self.steps,
            "wall_s": self.wall_s,
            "fps": self.fps,
            "seconds_per_stage": self.seconds,
            "fps_per_stage": self.stage_fps(),
            "people_per_frame": self.people_per_frame,
            "people": self.people,
            "events": self.events,
            "reprojection_median_px": self.reprojection_median_px,
            "per_camera": {k: v.as_dict() for k, v in self.camera_stats.items()},
            "sources": self.sources,
            "interrupted": self.interrupted,
            "outputs": [str(p) for p in self.outputs],
        }


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


def _reprojection(
    rig: Rig, people3d: People3D, people2d: dict[str, People2D], stats: dict[str, CameraStats]
) -> None:
    """Distances between each person's 3D joints projected into each camera and the detection
    they were reconstructed from (joints with conf > 0.5 in both). A detection whose left/right
    labels the reconstruction found swapped is compared swapped back."""
    if not len(people3d):
        return
    for ci, cam in enumerate(rig):
        p2 = people2d.get(cam.name)
        if p2 is None:
            continue
        for p in np.flatnonzero(people3d.detections[:, ci] >= 0):
            px = project(people3d.joints[p], cam)
            best = None
            for order in (slice(None), SWAP):
                kp = p2.keypoints[people3d.detections[p, ci]][order]
                ok = (kp[:, 2] > 0.5) & (people3d.conf[p] > 0.5) & np.isfinite(px[:, 0])
                d = np.linalg.norm(px[ok] - kp[ok, :2], axis=1)
                if len(d) and (best is None or np.median(d) < np.median(best)):
                    best = d
            if best is not None:
                stats[cam.name].reprojection_px.extend(best.tolist())


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
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise StereoposeError(f"{out_dir}: cannot create the output folder: {e.strerror}") from None
    with CameraSet(sources, names, cfg.input.sync, cfg.input.fps, cfg.input.max_frames) as cams:
        cfg = dataclasses.replace(cfg, fps=cams.fps)
        summary = RunSummary(out_dir, config_path, tuple(names), cams.live, cams.fps)
        summary.camera_stats = {n: CameraStats() for n in names}
        (out_dir / "config.toml").write_text(config_path.read_text(encoding="utf-8"))
        _save_inputs(out_dir, rig, site)
        _process(cams, cfg, rig, site, detector, out_dir, summary, on_step, on_events, stop)
        summary.sources = {k: dataclasses.asdict(v) for k, v in cams.stats().items()}
    return _finish(out_dir, summary, cfg.outputs.report)


def _save_inputs(out_dir: Path, rig: Rig, site: Site | None) -> None:
    """The calibration and site a run used, which the report is rebuilt from."""
    save_calibration(out_dir / "calib.toml", rig)
    if site is not None:
        save_site(out_dir / "site.toml", site)


def _finish(out_dir: Path, summary: RunSummary, report: bool) -> RunSummary:
    """Write summary.json and, if asked, the report."""
    path = out_dir / "summary.json"
    path.write_text(json.dumps(summary.as_dict(), indent=1) + "\n", encoding="utf-8")
    summary.outputs.append(path)
    if report:
        from stereopose.viz.report import write_report

        summary.outputs.append(write_report(out_dir))
    return summary


def _process(cams, cfg, rig, site, detector, out_dir, summary, on_step, on_events, stop) -> None:
    o = cfg.outputs
    back = Back3D(
        rig,
        cfg,
        out_dir / "poses3d.jsonl" if o.poses else None,
        calib_path=cfg.calibration or "",
        source=", ".join(cams.names),
        trc_dir=out_dir / "trc" if o.trc else None,
        csv_path=out_dir / "joints.csv" if o.csv else None,
        two_way=o.two_way,
        tracks_path=out_dir / "tracks.json",
        site=site,
        events_path=out_dir / "events.jsonl" if site is not None and o.events else None,
        events_db=out_dir / "events.sqlite" if site is not None and o.events else None,
        webhook=o.webhook,
        on_events=on_events,
    )
    overlays = {
        c.name: OverlayVideo(out_dir / "overlays" / f"{c.name}.mp4", c, cams.fps, o.overlay_scale)
        for c in rig
    } if o.overlays else {}  # fmt: skip
    stop = stop or threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():

        def interrupt(signum, frame) -> None:
            if stop.is_set():  # a second Ctrl-C: stop now
                raise KeyboardInterrupt
            logger.warning("interrupted: finishing the current frame and closing the outputs")
            stop.set()

        previous = signal.signal(signal.SIGINT, interrupt)
    sec = summary.seconds
    checked: set[str] = set()
    start = time.perf_counter()
    try:
        it = iter(cams)
        while not stop.is_set():
            t0 = time.perf_counter()
            step = next(it, None)
            t1 = time.perf_counter()
            sec["decode"] += t1 - t0
            if step is None:
                break
            people2d = detect_step(detector, step)
            for name in people2d.keys() - checked:
                checked.add(name)
                _check_size(rig[name], step.images[name], name)
            sec["detect"] += time.perf_counter() - t1
            people3d, _ = back.step(step.index, people2d)
            for name, p2 in people2d.items():
                st = summary.camera_stats[name]
                st.frames += 1
                st.detections += len(p2)
            _reprojection(rig, people3d, people2d, summary.camera_stats)
            t3 = time.perf_counter()
            label = f"{step.index}  t={step.t:.2f}s"
            for name, p2 in people2d.items():
                if name in overlays:
                    overlays[name].write(step.images[name], p2, people3d, label)
            sec["overlays"] += time.perf_counter() - t3
            summary.steps += 1
            if on_step is not None:
                elapsed = time.perf_counter() - start
                on_step(summary.steps, cams.count, summary.steps / elapsed if elapsed else 0.0)
        summary.interrupted = stop.is_set()
    except KeyboardInterrupt:
        summary.interrupted = True
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        summary.wall_s = time.perf_counter() - start
        back.close()
        for ov in overlays.values():
            path = ov.close()
            if path is not None:
                summary.outputs.append(path)
        b = back.summary
        sec["3d"], sec["fences"], sec["write"] = b.seconds_3d, b.seconds_fences, b.seconds_write
        summary.outputs[:0] = b.outputs
        summary.events = dict(b.events)
        summary.people = [t.as_dict() for t in b.trajectories]
        summary.people_per_frame = b.mean_people
        errors = [e for s in summary.camera_stats.values() for e in s.reprojection_px]
        summary.reprojection_median_px = float(np.median(errors)) if errors else None
    if summary.interrupted:
        logger.warning("run interrupted after %d frames; outputs closed", summary.steps)


def _check_size(camera, image: np.ndarray, name: str) -> None:
    w, h = camera.size
    if (image.shape[1], image.shape[0]) != (round(w), round(h)):
        raise StereoposeError(
            f"camera {name}: frames are {image.shape[1]}x{image.shape[0]} pixels but its "
            f"calibration is for {round(w)}x{round(h)}"
        )


def write_reconstruction_report(
    out_dir: Path,
    summary: ReconstructionSummary,
    calib_path: Path,
    site: Site | None,
    poses_path: Path,
    events_path: Path | None = None,
) -> Path:
    """A run folder and its report for a reconstruction from keypoint files (no cameras)."""
    out_dir = Path(out_dir)
    for src, name in ((poses_path, "poses3d.jsonl"), (events_path, "events.jsonl")):
        if src is not None and Path(src).resolve() != (out_dir / name).resolve():
            shutil.copyfile(src, out_dir / name)
    _save_inputs(out_dir, load_calibration(calib_path), site)
    run = RunSummary(out_dir, None, summary.cameras, steps=summary.frames)
    run.seconds = {"3d": summary.seconds_3d, "fences": summary.seconds_fences,
                   "write": summary.seconds_write}  # fmt: skip
    run.events = dict(summary.events)
    run.people = [t.as_dict() for t in summary.trajectories]
    run.people_per_frame = summary.mean_people
    run.reprojection_median_px = summary.median_confident_reprojection_px
    _finish(out_dir, run, report=True)
    return out_dir / "report.html"
