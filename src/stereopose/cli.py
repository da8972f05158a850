"""Command line: parse, load configuration, call the pipeline, report."""

from __future__ import annotations

import argparse
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
    if getattr(args, "fps", None) is not None:
        if args.fps <= 0:
            raise StereoposeError(f"--fps must be positive, got {args.fps}")
        cfg = Config(fps=args.fps, reconstruction=cfg.reconstruction)
    return cfg


def _px(value: float) -> str:
    return f"{value:.2f} px" if value == value else "n/a (no joint reconstructed)"


def _reconstruct(args: argparse.Namespace) -> int:
    from stereopose.pipeline import reconstruct_files

    cfg = _config(args)
    with _progress() as progress:
        task = progress.add_task("reconstructing", total=None)
        summary = reconstruct_files(
            args.calib,
            args.pose,
            args.out,
            cfg,
            on_frame=lambda done, total: progress.update(task, completed=done, total=total),
        )
    table = Table(title=f"3D poses written to {args.out}", show_header=False)
    table.add_row("cameras", ", ".join(summary.cameras))
    table.add_row("mode", summary.mode)
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
    table.add_row("3D stage speed", f"{summary.fps_3d:.0f} frames/s")
    if summary.skipped_files:
        table.add_row("skipped files", f"{len(summary.skipped_files)} (listed below)")
    out.print(table)
    for path, why in summary.skipped_files:
        out.print(f"skipped {path}: {why}", markup=False, highlight=False, soft_wrap=True)
    return 0


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
    from stereopose.pipeline import evaluate_poses_file, reconstruct_files
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
    for col in ("mode", "MPJPE mm", "PCP %", "PCP seen %", "recall %", "false/frame", "3D fps"):
        table.add_column(col, justify="right")
    modes = (args.mode,) if args.mode else MODES
    cfg0 = _config(args)
    for mode in modes:
        cfg = with_overrides(
            Config(fps=scene.fps, reconstruction=cfg0.reconstruction), triangulation={"mode": mode}
        )
        poses = out_dir / f"poses3d_{mode}.jsonl"
        summary = reconstruct_files(scene_dir / "calib.toml", scene_dir / "pose", poses, cfg)
        m = evaluate_poses_file(poses, scene)
        table.add_row(
            mode,
            f"{m.mpjpe_mm:.1f}",
            f"{100 * m.pcp:.1f}",
            f"{100 * m.pcp_seen:.1f}",
            f"{100 * m.person_recall:.1f}",
            f"{m.false_people_per_frame:.3f}",
            f"{summary.fps_3d:.0f}",
        )
    out.print(table)
    out.print(
        "pair: the reference two-camera method; weighted: every view, weighted by confidence; "
        "robust (default): views that agree, left/right swaps corrected. PCP seen: limbs whose "
        "joints the detector reported in two cameras or more; recall: people found; false/frame: "
        "people reconstructed where there is nobody."
    )
    out.print(f"3D poses: {out_dir}/poses3d_<mode>.jsonl; ground truth: {scene_dir}/truth.jsonl")
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
    r.set_defaults(func=_reconstruct)

    s = sub.add_parser("simulate", help="write a simulated substation scene with ground truth")
    s.add_argument("out_dir", type=Path, metavar="OUT_DIR")
    s.add_argument("--cameras", type=int, help="2-12 (default: by difficulty)")
    s.add_argument("--people", type=int, help="0-12 (default: by difficulty)")
    s.add_argument("--frames", type=int, default=250)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--difficulty", choices=("easy", "mid", "hard"), default="mid")
    s.add_argument("--fps", type=float, default=25.0)
    s.set_defaults(func=_simulate)

    d = sub.add_parser("demo", help="simulate a substation, reconstruct it, print the accuracy")
    d.add_argument("--out", type=Path, default=Path("out/demo"))
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
        console.print(f"[bold red]error:[/] {escape(str(e))}", highlight=False)
        return 2
    except KeyboardInterrupt:
        console.print("interrupted")
        return 130


if __name__ == "__main__":
    sys.exit(main())
