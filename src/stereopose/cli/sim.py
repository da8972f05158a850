"""`simulate` and `demo --synthetic`."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from rich.table import Table

from stereopose.cli.common import _config, out
from stereopose.config import MODES, Config, with_overrides
from stereopose.errors import StereoposeError

if TYPE_CHECKING:
    from stereopose.fence import Site
    from stereopose.sim import Scene
    from stereopose.sim.metrics import Metrics, TrackingMetrics
    from stereopose.types import People3D

MAX_FRAMES = 100_000  # an hour at 25 frames/s


def _simulated(
    num_frames: int,
    seed: int,
    difficulty: str,
    num_cameras: int | None = None,
    num_people: int | None = None,
    fps: float = 25.0,
) -> Scene:
    from stereopose.sim import simulate

    if not 1 <= num_frames <= MAX_FRAMES:  # a scene is held in memory
        raise StereoposeError(f"--frames must be in 1..{MAX_FRAMES}, got {num_frames}")
    Config._ranges["fps"][0].check(fps, "--fps")  # the schema's range
    try:
        return simulate(
            num_cameras=num_cameras,
            num_people=num_people,
            num_frames=num_frames,
            seed=seed,
            difficulty=difficulty,
            fps=fps,
        )
    except ValueError as e:
        raise StereoposeError(f"cannot simulate this scene: {e}") from None


def _simulate(args: argparse.Namespace) -> int:
    from stereopose.sim.io import write_scene

    scene = _simulated(
        num_cameras=args.cameras,
        num_people=args.people,
        num_frames=args.frames,
        seed=args.seed,
        difficulty=args.difficulty,
        fps=args.fps,
    )
    write_scene(scene, args.out_dir)
    out.print(
        f"simulated {args.difficulty} scene: {len(scene.rig)} cameras, {scene.truth.shape[1]} "
        f"people, {scene.truth.shape[0]} frames -> {args.out_dir} "
        "(calib.toml, pose/, truth.jsonl)"
    )
    return 0


def _accuracy_row(label: str, m: Metrics, ids: TrackingMetrics | None, fps_3d: float) -> list[str]:
    """One row of the accuracy table: metrics (sim.Metrics), ids (sim.TrackingMetrics or
    None without tracking) and the 3D stage's frames/s."""
    return [
        label,
        f"{m.mpjpe_mm:.1f}",
        f"{100 * m.pcp:.1f}",
        f"{100 * m.pcp_seen:.1f}",
        f"{100 * m.person_recall:.1f}",
        f"{m.false_people_per_frame:.3f}",
        f"{ids.ids}/{ids.workers}" if ids else "-",
        str(ids.id_switches) if ids else "-",
        f"{fps_3d:.0f}",
    ]


def _print_events(
    scene: Scene, site: Site, events_path: Path, predictions: list[People3D], scene_dir: Path
) -> None:
    """The tracked run's zone events against those the ground truth raises."""
    from stereopose.io.sinks import read_events
    from stereopose.sim.events import evaluate_events, track_workers, truth_events

    events = read_events(events_path)
    truth = truth_events(scene, site)
    em = evaluate_events(events, truth, track_workers(predictions, scene))
    out.print(
        f"[bold]Zone events[/] ({len(site.zones)} zones in {scene_dir / 'site.toml'}): "
        f"{len(events)} raised -> {events_path}; enter/exit against the ground truth: precision "
        f"{em.precision:.2f}, recall {em.recall:.2f} ({em.matched} of {em.true}), raised "
        f"{em.latency_mean_s:.2f} s after the true onset on average (at most "
        f"{em.latency_max_s:.2f} s)."
    )


def _poses_name(mode: str, tracked: bool) -> str:
    return f"poses3d_{mode}{'_tracked' * tracked}.jsonl"


def _remove_other_modes(out_dir: Path, runs: set[tuple[str, bool]]) -> None:
    """A previous demo's poses of the modes this one does not run: they would be mixed with
    this demo's results (only the demo writes these names)."""
    from stereopose.pipeline.paths import remove_outputs

    stale = [
        out_dir / _poses_name(m, t) for m in MODES for t in (False, True) if (m, t) not in runs
    ]
    remove_outputs([p for p in stale if p.is_file()])


def _demo_synthetic(args: argparse.Namespace) -> int:
    import numpy as np

    from stereopose.fence import save_site
    from stereopose.io.results import load_people3d
    from stereopose.pipeline import reconstruct_files
    from stereopose.sim import evaluate, evaluate_tracking
    from stereopose.sim.events import make_zones
    from stereopose.sim.io import write_scene

    out_dir = Path(args.out)
    scene_dir = out_dir / "scene"
    scene = _simulated(num_frames=args.frames, seed=args.seed, difficulty=args.difficulty)
    write_scene(scene, scene_dir)
    out.print(
        f"[bold]Simulated substation[/]: {args.difficulty}, {len(scene.rig)} cameras, "
        f"{scene.truth.shape[1]} workers, {scene.truth.shape[0]} frames at {scene.fps:g} fps "
        f"-> {scene_dir}"
    )
    table = Table(title="Accuracy against the simulator's ground truth")
    for col in ("method", "MPJPE mm", "PCP %", "seen %", "recall %", "false", "ids", "IDSW", "fps"):
        table.add_column(col, justify="right", no_wrap=col == "method")
    modes = (args.mode,) if args.mode else MODES
    cfg0 = dataclasses.replace(_config(args), fps=scene.fps)
    runs = [(m, m, False) for m in modes]
    runs.append((f"{modes[-1]} + tracking", modes[-1], True))
    _remove_other_modes(out_dir, {(mode, tracked) for _, mode, tracked in runs})
    site = make_zones(scene, np.random.default_rng([args.seed, 7]))
    save_site(scene_dir / "site.toml", site)
    events_path = out_dir / "events.jsonl"
    last = None  # the last run's poses, summary and people (the tracked one's)
    for label, mode, tracked in runs:
        cfg = with_overrides(cfg0, triangulation={"mode": mode}, tracking={"enabled": tracked})
        poses = out_dir / _poses_name(mode, tracked)
        summary = reconstruct_files(
            scene_dir / "calib.toml",
            scene_dir / "pose",
            poses,
            cfg,
            site=site if tracked else None,
            events_path=events_path if tracked else None,
            config_path=args.config,
        )
        predictions = load_people3d(poses, len(scene.rig))
        m = evaluate(predictions, scene)
        ids = evaluate_tracking(predictions, scene) if tracked else None
        table.add_row(*_accuracy_row(label, m, ids, summary.fps_3d))
        last = poses, summary, predictions
    assert last is not None  # the tracked run at least
    poses, summary, predictions = last
    out.print(table)
    _print_events(scene, site, events_path, predictions, scene_dir)
    out.print(
        "Per frame: pair is the reference two-camera method; weighted uses every view, weighted "
        "by confidence; robust (default) the views that agree, left/right swaps corrected. "
        "+ tracking (default): persistent ids, online smoothing, short gaps bridged. "
        "seen %: PCP of the limbs the detector reported in two cameras or more; recall: people "
        "found; false: people per frame where there is nobody (with tracking, including people "
        "still predicted for a moment after they left); ids: ids given / workers; IDSW: id "
        "switches; fps: 3D back end, frames/s."
    )
    from stereopose.pipeline.reconstruct import write_reconstruction_report

    report = write_reconstruction_report(
        out_dir, summary, scene_dir / "calib.toml", site, poses, events_path
    )
    out.print(
        f"3D poses: {out_dir}/poses3d_*.jsonl; ground truth: {scene_dir}/truth.jsonl; "
        f"report: {report}",
        highlight=False,
        soft_wrap=True,
    )
    return 0
