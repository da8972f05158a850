"""Command line: parse, load configuration, call the pipeline, report."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from rich.logging import RichHandler
from rich.markup import escape

from stereopose import __version__
from stereopose.cli.calibrate import _calibrate_extrinsics, _calibrate_intrinsics
from stereopose.cli.common import console
from stereopose.cli.reconstruct import _events, _reconstruct
from stereopose.cli.run import _demo, _detect, _init, _models, _report, _run
from stereopose.cli.sim import _simulate
from stereopose.config import MODES
from stereopose.errors import StereoposeError

__all__ = ["build_parser", "main"]


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
    r.add_argument(
        "--two-way",
        action="store_true",
        help="smooth the TRC and CSV exports both ways over each track (offline: each frame also "
        "uses the frames after it; written at the end); the poses file stays online",
    )
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
