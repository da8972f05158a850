"""Command line: parse, load configuration, call the pipeline, report."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console
from rich.logging import RichHandler
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from stereopose import __version__
from stereopose.config import MODES, Config, load_config, with_overrides
from stereopose.errors import StereoposeError

if TYPE_CHECKING:
    from stereopose.sim import Scene

console = Console(stderr=True)
out = Console()


def _progress() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    )


def _config(args: argparse.Namespace) -> Config:
    cfg = load_config(args.config)
    if getattr(args, "mode", None):
        cfg = with_overrides(cfg, triangulation={"mode": args.mode})
    if getattr(args, "no_tracking", False):
        cfg = with_overrides(cfg, tracking={"enabled": False})
    if getattr(args, "fps", None) is not None:
        if not args.fps > 0:
            raise StereoposeError(f"--fps must be positive, got {args.fps}")
        cfg = dataclasses.replace(cfg, fps=args.fps)
    return cfg


def _px(value: float) -> str:
    return f"{value:.2f} px" if value == value else "n/a (no joint reconstructed)"


def _reconstruct(args: argparse.Namespace) -> int:
    from stereopose.fence import load_site
    from stereopose.fence.sinks import describe
    from stereopose.pipeline import reconstruct_files

    cfg = _config(args)
    site = load_site(args.site) if args.site else None
    if site is None and (args.events or args.events_db or args.webhook):
        raise StereoposeError("--events, --events-db and --webhook need a site file (--site)")
    if site is not None and site.fps and args.fps is None:
        cfg = dataclasses.replace(cfg, fps=site.fps)
    with _progress() as progress:

        def show(events) -> None:
            for e in events:
                progress.console.print(describe(e), markup=False, highlight=False)

        task = progress.add_task("reconstructing", total=None)
        summary = reconstruct_files(
            args.calib,
            args.pose,
            args.out,
            cfg,
            on_frame=lambda done, total: progress.update(task, completed=done, total=total),
            trc_dir=args.trc,
            csv_path=args.csv,
            tracks_path=args.tracks,
            site=site,
            events_path=args.events,
            events_db=args.events_db,
            webhook=args.webhook,
            on_events=show if site is not None else None,
        )
    table = Table(title=f"3D poses written to {args.out}", show_header=False)
    table.add_row("cameras", ", ".join(summary.cameras))
    table.add_row("mode", summary.mode)
    table.add_row(
        "tracking",
        f"on: {len(summary.trajectories)} people, {summary.predicted} bridged person-frames"
        if summary.tracking
        else "off (ids are per frame)",
    )
    table.add_row("frames", str(summary.frames))
    hist = ", ".join(
        f"{v} frame{'s' * (v != 1)} with {k}" for k, v in sorted(summary.people_histogram.items())
    )
    table.add_row("people per frame", f"{summary.mean_people:.2f} on average ({hist})")
    table.add_row("joints reconstructed", str(summary.joints_reconstructed))
    table.add_row("mean reprojection error", _px(summary.mean_reprojection_px))
    table.add_row(
        "median reprojection error, conf > 0.5", _px(summary.median_confident_reprojection_px)
    )
    table.add_row("3D back end speed", f"{summary.fps_3d:.0f} frames/s")
    if site is not None:
        counts = ", ".join(f"{v} {k}" for k, v in sorted(summary.events.items())) or "none"
        table.add_row("zone events", f"{counts} ({len(site.zones)} zones)")
    if summary.skipped_files:
        table.add_row("skipped files", f"{len(summary.skipped_files)} (listed below)")
    out.print(table)
    if summary.trajectories:
        out.print(_trajectory_table(summary.trajectories))
    for path in summary.outputs[1:]:
        out.print(f"wrote {path}", markup=False, highlight=False, soft_wrap=True)
    for path, why in summary.skipped_files:
        out.print(f"skipped {path}: {why}", markup=False, highlight=False, soft_wrap=True)
    return 0


def _events(args: argparse.Namespace) -> int:
    import csv

    from stereopose.fence.sinks import COLUMNS, query_events

    rows = query_events(
        args.db, person=args.person, zone=args.zone, event_type=args.type, since=args.since
    )
    if args.csv:
        w = csv.writer(sys.stdout, lineterminator="\n")
        w.writerow(COLUMNS)
        w.writerows([r[c] for c in COLUMNS] for r in rows)
        return 0
    table = Table(title=f"{len(rows)} event(s) in {args.db}")
    cols = ("run", "t", "frame", "person", "zone", "kind", "type", "joint", "distance_m", "x", "y")
    for c in cols:
        table.add_column(c, justify="left" if c in ("zone", "kind", "type", "joint") else "right")
    for r in rows:
        table.add_row(
            *(
                "" if r[c] is None else f"{r[c]:.2f}" if isinstance(r[c], float) else str(r[c])
                for c in cols
            )
        )
    out.print(table)
    return 0


def _board(args: argparse.Namespace):
    from stereopose.calibration.board import Board

    return Board.parse(args.board, args.square)


def _calibrate_intrinsics(args: argparse.Namespace) -> int:
    from stereopose.pipeline import calibrate_intrinsics_dir

    board = _board(args)
    with console.status("detecting the board") as status:
        run = calibrate_intrinsics_dir(
            args.images,
            board,
            args.out,
            k3=args.k3,
            report_dir=args.report,
            on_camera=lambda name: status.update(f"camera {name}: detecting the board"),
        )
    table = Table(title=f"Intrinsics written to {args.out}")
    for col in ("camera", "photos used", "not used", "fx", "fy", "cx", "cy", "RMS px", "coverage"):
        table.add_column(col, justify="right")
    for name, r in run.results.items():
        K = r.camera.matrix
        table.add_row(
            name,
            f"{len(r.used)}/{len(run.detections[name])}",
            str(len(r.rejected)),
            f"{K[0, 0]:.1f}",
            f"{K[1, 1]:.1f}",
            f"{K[0, 2]:.1f}",
            f"{K[1, 2]:.1f}",
            f"{r.rms_px:.3f}",
            f"{100 * r.coverage:.0f}%",
        )
    out.print(table)
    for name, r in run.results.items():
        for photo, why in r.rejected.items():
            out.print(f"{name}: {photo} not used: {why}", markup=False, highlight=False)
        for view, e in sorted(r.view_rms_px.items()):
            out.print(f"{name}: {view}: {e:.3f} px", markup=False, highlight=False)
        for w in r.warnings:
            console.print(f"[yellow]warning:[/] {escape(w)}")
    for p in run.outputs[1:]:
        out.print(f"wrote {p}", markup=False, highlight=False)
    return 0


def _calibrate_extrinsics(args: argparse.Namespace) -> int:
    from stereopose.pipeline import calibrate_extrinsics_dir

    board = _board(args)
    with console.status("detecting the board") as status:
        run = calibrate_extrinsics_dir(
            args.images,
            args.intrinsics,
            board,
            args.out,
            floor=args.floor,
            origin_m=tuple(args.origin),
            yaw_deg=args.yaw,
            refine_intrinsics=args.refine_intrinsics,
            report_dir=args.report,
            on_camera=lambda name: status.update(f"camera {name}: detecting the board"),
            intrinsics_images=args.intrinsics_images,
        )
    r = run.result
    table = Table(title=f"Rig written to {args.out}: RMS {r.rms_px:.3f} px")
    for col in ("camera", "board positions seen", "RMS px", "x m", "y m", "z m"):
        table.add_column(col, justify="right")
    for cam in r.rig:
        seen = sum(run.found[cam.name].values())
        x, y, z = cam.center
        table.add_row(
            cam.name,
            f"{seen}/{len(run.found[cam.name])}",
            f"{r.camera_rms_px[cam.name]:.3f}",
            f"{x:.3f}",
            f"{y:.3f}",
            f"{z:.3f}",
        )
    out.print(table)
    for view, e in sorted(r.view_rms_px.items()):
        out.print(f"position {view}: {e:.3f} px", markup=False, highlight=False)
    for w in r.warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")
    out.print(f"bundle adjustment and pose graph: {r.seconds:.2f} s")
    for p in run.outputs[1:]:
        out.print(f"wrote {p}", markup=False, highlight=False)
    return 0


def _trajectory_table(trajectories) -> Table:
    table = Table(title="People tracked")
    for col in ("id", "first frame", "last frame", "time in view s", "frames seen", "path m"):
        table.add_column(col, justify="right")
    for t in trajectories:
        table.add_row(
            str(t.id),
            str(t.first_frame),
            str(t.last_frame),
            f"{t.duration_s:.1f}",
            str(t.frames_seen),
            f"{t.path_m:.1f}",
        )
    return table


def _simulated(**kwargs: object) -> Scene:
    from stereopose.sim import simulate

    if kwargs["num_frames"] < 1:
        raise StereoposeError(f"--frames must be at least 1, got {kwargs['num_frames']}")
    if kwargs.get("fps", 25.0) <= 0:
        raise StereoposeError(f"--fps must be positive, got {kwargs['fps']}")
    try:
        return simulate(**kwargs)
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


def _demo(args: argparse.Namespace) -> int:
    if args.synthetic:
        return _demo_synthetic(args)
    from stereopose.pipeline.demo import write_demo_config

    config = write_demo_config(args.out)
    out.print(
        "[bold]Real demo[/]: Pose2Sim's multi-person recording, 4 cameras (1088x1920, 60 fps), "
        f"its Qualisys calibration and a demo site -> {config}"
    )
    rc = _run_config(config, "Real demo: detection, 3D reconstruction, tracking, zone events")
    out.print(f"open {Path(args.out) / 'report.html'} in a browser; overlay videos in "
              f"{Path(args.out) / 'overlays'}", highlight=False, soft_wrap=True)  # fmt: skip
    return rc


def _demo_synthetic(args: argparse.Namespace) -> int:
    import numpy as np

    from stereopose.fence import save_site
    from stereopose.fence.sinks import read_events
    from stereopose.io.results import load_people3d
    from stereopose.pipeline import reconstruct_files
    from stereopose.sim import evaluate, evaluate_tracking
    from stereopose.sim.events import evaluate_events, make_zones, track_workers, truth_events
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
    site = make_zones(scene, np.random.default_rng([args.seed, 7]))
    save_site(scene_dir / "site.toml", site)
    events_path = out_dir / "events.jsonl"
    for label, mode, tracked in runs:
        cfg = with_overrides(cfg0, triangulation={"mode": mode}, tracking={"enabled": tracked})
        poses = out_dir / f"poses3d_{mode}{'_tracked' * tracked}.jsonl"
        summary = reconstruct_files(
            scene_dir / "calib.toml",
            scene_dir / "pose",
            poses,
            cfg,
            site=site if tracked else None,
            events_path=events_path if tracked else None,
        )
        predictions = load_people3d(poses, len(scene.rig))
        m = evaluate(predictions, scene)
        ids = evaluate_tracking(predictions, scene) if tracked else None
        table.add_row(
            label,
            f"{m.mpjpe_mm:.1f}",
            f"{100 * m.pcp:.1f}",
            f"{100 * m.pcp_seen:.1f}",
            f"{100 * m.person_recall:.1f}",
            f"{m.false_people_per_frame:.3f}",
            f"{ids.ids}/{ids.workers}" if ids else "-",
            str(ids.id_switches) if ids else "-",
            f"{summary.fps_3d:.0f}",
        )
    out.print(table)
    events = read_events(events_path)
    truth = truth_events(scene, site)
    workers = track_workers(predictions, scene)
    em = evaluate_events(events, truth, workers)
    out.print(
        f"[bold]Zone events[/] ({len(site.zones)} zones in {scene_dir / 'site.toml'}): "
        f"{len(events)} raised -> {events_path}; enter/exit against the ground truth: precision "
        f"{em.precision:.2f}, recall {em.recall:.2f} ({em.matched} of {em.true}), raised "
        f"{em.latency_mean_s:.2f} s after the true onset on average (at most "
        f"{em.latency_max_s:.2f} s)."
    )
    out.print(
        "Per frame: pair is the reference two-camera method; weighted uses every view, weighted "
        "by confidence; robust (default) the views that agree, left/right swaps corrected. "
        "+ tracking (default): persistent ids, online smoothing, short gaps bridged. "
        "seen %: PCP of the limbs the detector reported in two cameras or more; recall: people "
        "found; false: people per frame where there is nobody (with tracking, including people "
        "still predicted for a moment after they left); ids: ids given / workers; IDSW: id "
        "switches; fps: 3D back end, frames/s."
    )
    from stereopose.pipeline.run import write_reconstruction_report

    report = write_reconstruction_report(
        out_dir, summary, scene_dir / "calib.toml", site, poses, events_path
    )
    out.print(f"3D poses: {out_dir}/poses3d_*.jsonl; ground truth: {scene_dir}/truth.jsonl; "
              f"report: {report}", highlight=False, soft_wrap=True)  # fmt: skip
    return 0


def _detect(args: argparse.Namespace) -> int:
    from stereopose.detection import make_detector
    from stereopose.pipeline import detect_videos

    if args.max_frames is not None and args.max_frames <= 0:
        raise StereoposeError(f"--max-frames must be positive, got {args.max_frames}")
    detector = make_detector(
        args.backend, args.model, args.imgsz, args.conf, args.iou, args.device, args.threads
    )
    progress = Progress(
        TextColumn("detecting"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[fps]:.1f} frames/s"),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    )
    with progress:
        task = progress.add_task("detecting", total=None, fps=0.0)
        summary = detect_videos(
            args.videos,
            args.out,
            detector,
            names=args.names,
            sync=args.sync,
            fps=args.fps,
            max_frames=args.max_frames,
            on_step=lambda done, total, fps: progress.update(
                task, completed=done, total=total, fps=fps
            ),
        )
    table = Table(title=f"2D keypoints written to {args.out}")
    for col in ("camera", "frames", "with people", "people/frame", "dropped", "reconnects"):
        table.add_column(col, justify="left" if col == "camera" else "right")
    for name in summary.cameras:
        n = summary.frames[name]
        st = summary.sources[name]
        table.add_row(
            name,
            str(n),
            str(summary.frames_with_people[name]),
            f"{summary.people[name] / n:.2f}" if n else "-",
            str(st.dropped),
            str(st.reconnects),
        )
    out.print(table)
    steps_s = summary.seconds_decode + summary.seconds_detect + summary.seconds_write
    out.print(
        f"{summary.steps} time steps, {summary.images} images with the {summary.backend} backend: "
        f"{summary.ms_per_image:.1f} ms per image detecting, "
        f"{1000 * summary.seconds_decode / max(summary.steps, 1):.1f} ms per step decoding, "
        f"{summary.steps / steps_s if steps_s else 0:.1f} time steps/s overall",
        highlight=False,
    )
    if summary.interrupted:
        out.print("interrupted: the files above are complete up to the last time step")
        return 130
    return 0


def _models(args: argparse.Namespace) -> int:
    from stereopose.detection import models

    if args.action == "fetch":
        out.print(str(models.fetch_default_weights()), highlight=False, soft_wrap=True)
    elif args.action == "export":
        if args.weights is None and args.out is None and not args.force:
            target = models.models_dir() / f"{models.DEFAULT_MODEL}.onnx"
            path = target if target.is_file() else models.default_onnx()
        else:
            path = models.export_onnx(args.weights, args.out)
        out.print(str(path), highlight=False, soft_wrap=True)
    else:
        found = models.list_models()
        if not found:
            out.print(f"no models in {models.models_dir()}; run `stereopose models export`")
        for path in found:
            out.print(f"{path}  {path.stat().st_size / 1e6:.1f} MB", highlight=False)
    return 0


def _run_config(config_path: Path, title: str) -> int:
    from stereopose.fence.sinks import describe
    from stereopose.pipeline.run import run

    progress = Progress(
        TextColumn("running"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[fps]:.1f} frames/s"),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    )
    with progress:
        task = progress.add_task("running", total=None, fps=0.0)

        def show(events) -> None:
            for e in events:
                progress.console.print(describe(e), markup=False, highlight=False)

        summary = run(
            config_path,
            on_step=lambda done, total, fps: progress.update(
                task, completed=done, total=total, fps=fps
            ),
            on_events=show,
        )
    d = summary.as_dict()
    table = Table(title=title, show_header=False)
    table.add_row("cameras", ", ".join(summary.cameras))
    table.add_row("frames", f"{summary.steps} ({'live' if summary.live else 'recorded'}, "
                  f"{summary.fps_input:g} frames/s)")  # fmt: skip
    table.add_row("speed", f"{summary.fps:.1f} frames/s overall")
    table.add_row(
        "per stage, frames/s",
        ", ".join(f"{k} {v:.0f}" for k, v in summary.stage_fps().items() if v is not None),
    )
    table.add_row("people", f"{len(summary.people)} tracked, {summary.people_per_frame:.2f} "
                  "per frame")  # fmt: skip
    events = ", ".join(f"{v} {k}" for k, v in sorted(summary.events.items()))
    table.add_row("zone events", events or "none")
    table.add_row(
        "reprojection error (median)",
        ", ".join(
            f"{k} {_px(v['reprojection_median_px'] or float('nan'))}"
            for k, v in d["per_camera"].items()
        ),
    )
    out.print(table)
    if summary.people:
        people = Table(title="People tracked")
        for col in ("id", "first frame", "last frame", "time in view s", "path m"):
            people.add_column(col, justify="right")
        for p in summary.people:
            people.add_row(str(p["id"]), str(p["first_frame"]), str(p["last_frame"]),
                           f"{p['duration_s']:.2f}", f"{p['path_m']:.2f}")  # fmt: skip
        out.print(people)
    out.print(f"outputs in {summary.out_dir}:", highlight=False)
    for path in summary.outputs:
        out.print(f"  {path}", markup=False, highlight=False, soft_wrap=True)
    if summary.interrupted:
        out.print("interrupted: every output above is complete up to the last frame processed")
        return 130
    return 0


def _run(args: argparse.Namespace) -> int:
    return _run_config(args.config, f"run {args.config}")


def _init(args: argparse.Namespace) -> int:
    from importlib import resources

    path = Path(args.path)
    if path.exists() and not args.force:
        raise StereoposeError(f"{path}: already exists (use --force to overwrite)")
    text = (resources.files("stereopose") / "data" / "example_run.toml").read_text("utf-8")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write: {e.strerror}") from None
    out.print(f"wrote {path}: edit the calibration, cameras and outputs, then "
              f"`stereopose run {path}`", highlight=False, soft_wrap=True)  # fmt: skip
    return 0


def _report(args: argparse.Namespace) -> int:
    from stereopose.viz.report import write_report

    out.print(f"wrote {write_report(args.run_dir)}", markup=False, highlight=False, soft_wrap=True)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="stereopose",
        description="3D positions and body joints of workers from several fixed cameras.",
    )
    p.add_argument("--version", action="version", version=f"stereopose {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log debugging detail")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = sub.add_parser("reconstruct", help="2D keypoints of calibrated cameras -> 3D poses JSONL")
    r.add_argument("--calib", required=True, type=Path, help="calibration (.toml or .qca.txt)")
    r.add_argument("--pose", required=True, type=Path, help="folder of <camera>_json folders")
    r.add_argument("--out", required=True, type=Path, help="3D poses JSON lines to write")
    r.add_argument("--mode", choices=MODES, help="triangulation mode (default: robust)")
    r.add_argument("--config", type=Path, help="TOML file overriding the defaults")
    r.add_argument("--fps", type=float, help="frame rate giving each frame its time (default 25)")
    r.add_argument("--trc", type=Path, metavar="DIR", help="write one TRC file per person here")
    r.add_argument("--csv", type=Path, metavar="FILE", help="write every joint as CSV rows")
    r.add_argument("--tracks", type=Path, metavar="FILE", help="write trajectory summaries (JSON)")
    r.add_argument("--site", type=Path, metavar="SITE.toml", help="zones: raise zone events")
    r.add_argument("--events", type=Path, metavar="FILE", help="write zone events (JSON lines)")
    r.add_argument(
        "--events-db", type=Path, metavar="FILE", help="append zone events to an SQLite log"
    )
    r.add_argument("--webhook", metavar="URL", help="POST each zone event as JSON to this URL")
    r.add_argument(
        "--no-tracking",
        action="store_true",
        help="per-frame people: no ids over time, no smoothing",
    )
    r.set_defaults(func=_reconstruct)

    dt = sub.add_parser("detect", help="videos, image folders or streams -> 2D keypoint files")
    dt.add_argument(
        "--videos",
        required=True,
        nargs="+",
        metavar="SOURCE",
        help="video files, image folders or rtsp:// / http:// stream URLs, one per camera",
    )
    dt.add_argument("--names", nargs="+", metavar="NAME", help="camera names (default: file stems)")
    dt.add_argument("--out", required=True, type=Path, help="folder for the <camera>_json folders")
    dt.add_argument("--backend", choices=("onnx", "ultralytics"), default="onnx")
    dt.add_argument(
        "--model", type=Path, help="local .onnx or .pt pose model (default yolo11n-pose)"
    )
    dt.add_argument("--imgsz", type=int, default=640, help="model input size, long side (640)")
    dt.add_argument("--conf", type=float, default=0.25, help="person score threshold (0.25)")
    dt.add_argument("--iou", type=float, default=0.7, help="NMS overlap threshold (0.7)")
    dt.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto (cpu)")
    dt.add_argument("--threads", type=int, help="inference threads (default: all cores)")
    dt.add_argument(
        "--sync",
        choices=("index", "time"),
        default="index",
        help="align recorded cameras by frame index or by time from each file's frame rate",
    )
    dt.add_argument("--fps", type=float, help="time-step rate (default: the first camera's)")
    dt.add_argument("--max-frames", type=int, help="stop after this many time steps")
    dt.set_defaults(func=_detect)

    ru = sub.add_parser("run", help="cameras -> 3D people, tracks, zone events, report")
    ru.add_argument("config", type=Path, metavar="CONFIG.toml", help="run configuration")
    ru.set_defaults(func=_run)

    it = sub.add_parser("init", help="write a commented example run configuration")
    it.add_argument("path", nargs="?", default="stereopose.toml", help="(stereopose.toml)")
    it.add_argument("--force", action="store_true", help="overwrite an existing file")
    it.set_defaults(func=_init)

    rp = sub.add_parser("report", help="rebuild report.html of a run folder")
    rp.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    rp.set_defaults(func=_report)

    mo = sub.add_parser("models", help="list, fetch or export the pose models in the cache")
    mo.add_argument("action", choices=("list", "fetch", "export"), nargs="?", default="list")
    mo.add_argument("weights", type=Path, nargs="?", help="export: a YOLO pose .pt file")
    mo.add_argument("--out", type=Path, help="export: the .onnx file to write")
    mo.add_argument("--force", action="store_true", help="export again even if cached")
    mo.set_defaults(func=_models)

    cal = sub.add_parser("calibrate", help="camera calibration from checkerboard photos")
    csub = cal.add_subparsers(dest="step", required=True, metavar="STEP")
    board_help = "inner corners COLSxROWS: a board of 15 x 11 squares has 14x10 inner corners"
    ci = csub.add_parser("intrinsics", help="focal length, principal point, lens distortion")
    ci.add_argument(
        "--images",
        required=True,
        type=Path,
        help="one camera's photos, a video, or one sub-folder per camera (int_cam01_img -> cam01)",
    )
    ci.add_argument("--board", required=True, help=board_help)
    ci.add_argument("--square", required=True, type=float, help="square size in metres")
    ci.add_argument("--out", required=True, type=Path, help="CALIB.toml, or a folder for intri.yml")
    ci.add_argument("--k3", action="store_true", help="also estimate k3")
    ci.add_argument("--report", type=Path, metavar="DIR", help="write report pictures here")
    ci.set_defaults(func=_calibrate_intrinsics)
    ce = csub.add_parser("extrinsics", help="every camera's pose in one world frame")
    ce.add_argument(
        "--images",
        required=True,
        type=Path,
        help="one sub-folder per camera, the same file name per board position",
    )
    ce.add_argument("--intrinsics", required=True, type=Path, help="calibration with intrinsics")
    ce.add_argument("--board", required=True, help=board_help)
    ce.add_argument("--square", required=True, type=float, help="square size in metres")
    ce.add_argument("--out", required=True, type=Path, help="CALIB.toml, or a folder for *.yml")
    ce.add_argument(
        "--floor",
        metavar="POSITION",
        help="the board position (file name without extension) where the board lay on the floor: "
        "z = 0 there, z up (default: the first position, with a warning)",
    )
    ce.add_argument(
        "--origin",
        nargs=2,
        type=float,
        default=(0.0, 0.0),
        metavar=("X", "Y"),
        help="world origin, metres from the floor board's first corner along its rows, columns",
    )
    ce.add_argument("--yaw", type=float, default=0.0, help="turn the world x axis (degrees)")
    ce.add_argument("--refine-intrinsics", action="store_true", help="refine intrinsics too")
    ce.add_argument(
        "--intrinsics-images",
        type=Path,
        metavar="DIR",
        help="the cameras' intrinsics photos, adjusted together with the rig (best with "
        "--refine-intrinsics: fx and the camera distances then agree)",
    )
    ce.add_argument("--report", type=Path, metavar="DIR", help="write report pictures here")
    ce.set_defaults(func=_calibrate_extrinsics)

    e = sub.add_parser("events", help="list the events of an SQLite event log")
    e.add_argument("db", type=Path, metavar="EVENTS.sqlite")
    e.add_argument("--person", type=int, help="only this person id")
    e.add_argument("--zone", help="only this zone")
    e.add_argument("--type", help="only this event type (enter, exit, approach, dwell, ...)")
    e.add_argument("--since", type=float, metavar="T", help="only events at t >= T seconds")
    e.add_argument("--csv", action="store_true", help="CSV on standard output instead of a table")
    e.set_defaults(func=_events)

    s = sub.add_parser("simulate", help="write a simulated substation scene with ground truth")
    s.add_argument("out_dir", type=Path, metavar="OUT_DIR")
    s.add_argument("--cameras", type=int, help="2-12 (default: by difficulty)")
    s.add_argument("--people", type=int, help="0-12 (default: by difficulty)")
    s.add_argument("--frames", type=int, default=250)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--difficulty", choices=("easy", "mid", "hard"), default="mid")
    s.add_argument("--fps", type=float, default=25.0)
    s.set_defaults(func=_simulate)

    d = sub.add_parser(
        "demo", help="run the real 4-camera demo end to end (--synthetic: a simulated substation)"
    )
    d.add_argument("--out", type=Path, default=Path("out/demo"))
    d.add_argument(
        "--synthetic",
        action="store_true",
        help="simulate a substation instead, and print the accuracy against its ground truth "
        "(the options below apply to it)",
    )
    d.add_argument("--difficulty", choices=("easy", "mid", "hard"), default="hard")
    d.add_argument("--frames", type=int, default=250)
    d.add_argument("--seed", type=int, default=1)
    d.add_argument("--mode", choices=MODES, help="only this triangulation mode (default: all)")
    d.add_argument("--config", type=Path, help="TOML file overriding the defaults")
    d.set_defaults(func=_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(message)s",
        handlers=[RichHandler(console=console, show_time=False, show_path=False)],
    )
    try:
        return args.func(args)
    except StereoposeError as e:
        console.print(f"[bold red]error:[/] {escape(str(e))}", highlight=False, soft_wrap=True)
        return 2
    except KeyboardInterrupt:
        console.print("interrupted")
        return 130


if __name__ == "__main__":
    sys.exit(main())
