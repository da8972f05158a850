"""Command line: parse, load configuration, call the pipeline, report.

Only the standard library is imported here. A command's module, and with it rich, NumPy and the
pipeline, is imported when that command runs, so `--help` and usage errors come at once.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from stereopose import __version__
from stereopose.cli.commands import CALIBRATE_STEPS, COMMANDS
from stereopose.cli.control_room_args import add_control_room, control_room_argv
from stereopose.errors import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    IncompleteOutputError,
    StereoposeError,
)

if TYPE_CHECKING:
    from rich.console import Console

__all__ = ["COMMANDS", "build_parser", "main"]

# config.MODES written out: importing the configuration schema would double the time `--help`
# takes. A mode missing here is not offered; one config no longer has is refused by _config.
MODES: tuple[str, ...] = ("pair", "weighted", "robust")


def _add_reconstruct(r: argparse.ArgumentParser, e: argparse.ArgumentParser) -> None:
    """`reconstruct` and `events`."""
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
        "--ticket",
        type=Path,
        metavar="TICKET.toml",
        help="a work or operation ticket, active from the first frame to the last (needs --site)",
    )
    r.add_argument(
        "--zone-states",
        type=Path,
        metavar="FILE.csv",
        help="a switching log (time,zone,state) the energized zones are judged with (needs --site)",
    )
    r.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the person files a previous run left in the --trc folder",
    )
    r.add_argument(
        "--no-tracking",
        action="store_true",
        help="per-frame people: no ids over time, no smoothing",
    )

    e.add_argument("db", type=Path, metavar="EVENTS.sqlite")
    e.add_argument("--person", type=int, help="only this person id")
    e.add_argument("--zone", help="only this zone")
    e.add_argument("--type", help="only this event type (enter, exit, approach, dwell, ...)")
    e.add_argument("--since", type=float, metavar="T", help="only events at t >= T seconds")
    e.add_argument("--csv", action="store_true", help="CSV on standard output instead of a table")


def _add_cameras(parsers: dict[str, argparse.ArgumentParser]) -> None:
    """`detect`, `run`, `serve`, `points`, `detect-node`, `control-room`, `users`, `init`,
    `report`, `models` and `demo`."""
    _add_detect(parsers["detect"])
    parsers["run"].add_argument(
        "config", type=Path, metavar="CONFIG.toml", help="run configuration"
    )
    parsers["run"].add_argument(
        "--overwrite",
        action="store_true",
        help="replace the outputs of a previous run in the output folder",
    )
    parsers["run"].add_argument(
        "--ticket",
        type=Path,
        metavar="TICKET.toml",
        help="a work or operation ticket, active from the first frame to the last",
    )
    parsers["run"].add_argument(
        "--zone-states",
        type=Path,
        metavar="FILE.csv",
        help="a switching log (time,zone,state) the energized zones are judged with",
    )
    _add_serve(parsers["serve"])
    _add_points(parsers["points"])
    _add_detect_node(parsers["detect-node"])
    add_control_room(parsers["control-room"])
    _add_users(parsers["users"])
    _add_init(parsers["init"])
    parsers["report"].add_argument("run_dir", type=Path, metavar="RUN_DIR")
    _add_models(parsers["models"])
    _add_demo(parsers["demo"])


def _add_detect(dt: argparse.ArgumentParser) -> None:
    """`detect`."""
    dt.add_argument(
        "--videos",
        required=True,
        nargs="+",
        metavar="SOURCE",
        help="video files, image folders or rtsp:// / http:// stream URLs, one per camera",
    )
    dt.add_argument("--names", nargs="+", metavar="NAME", help="camera names (default: file stems)")
    dt.add_argument("--out", required=True, type=Path, help="folder for the <camera>_json folders")
    dt.add_argument(
        "--backend",
        choices=("auto", "onnx", "openvino", "ultralytics"),
        default="auto",
        help="auto: the fastest on this machine within the docs' accuracy (default)",
    )
    dt.add_argument(
        "--model", type=Path, help="local .onnx or .pt pose model (default yolo11n-pose)"
    )
    dt.add_argument("--imgsz", type=int, default=640, help="model input size, long side (640)")
    dt.add_argument("--conf", type=float, default=0.25, help="person score threshold (0.25)")
    dt.add_argument("--iou", type=float, default=0.7, help="NMS overlap threshold (0.7)")
    dt.add_argument(
        "--device",
        default="cpu",
        help="cpu, cuda, cuda:N, tensorrt, "
        "tensorrt:N or auto (cpu); openvino: cpu, gpu, gpu.N or auto",
    )
    dt.add_argument("--threads", type=int, help="inference threads (default: all cores)")
    dt.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16", "int8", "fp16"),
        default="auto",
        help="auto (with --backend auto: bf16 where chosen, else fp32); fp32; int8: the "
        "INT8-quantised model (onnx); bf16: openvino on a CPU with bfloat16 instructions; "
        "fp16: onnx on --device tensorrt",
    )
    dt.add_argument(
        "--regions",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="detect where the people are (each camera's own people, motion, a "
        "full scan every --full-scan-s), at the camera's own resolution; "
        "--no-regions: every whole frame at --imgsz (default: regions)",
    )
    dt.add_argument(
        "--region-imgsz",
        type=int,
        default=320,
        help="each region's model input side, a multiple of 32 (320)",
    )
    dt.add_argument(
        "--full-scan-s",
        type=float,
        default=3.0,
        help="each camera's whole frame scanned this often, seconds (3)",
    )
    dt.add_argument(
        "--sync",
        choices=("index", "time"),
        default="index",
        help="align recorded cameras by frame index or by time from each file's frame rate",
    )
    dt.add_argument("--fps", type=float, help="time-step rate (default: the first camera's)")
    dt.add_argument("--max-frames", type=int, help="stop after this many time steps")
    dt.add_argument(
        "--overwrite", action="store_true", help="replace the keypoint files of a previous run"
    )


def _add_detect_node(dn: argparse.ArgumentParser) -> None:
    """`detect-node`."""
    dn.add_argument(
        "config",
        type=Path,
        metavar="CONFIG.toml",
        help="the site's service configuration (its cameras, [detector], [mqtt])",
    )
    dn.add_argument("--cameras", metavar="A,B", help="the node's cameras, comma-separated")
    dn.add_argument("--node", metavar="NAME", help="the node's [[nodes]] entry (its cameras)")
    dn.add_argument(
        "--name",
        help="the node's name on the broker (default: its [[nodes]] "
        "name, or the host name and its cameras)",
    )


def _add_init(it: argparse.ArgumentParser) -> None:
    """`init`."""
    it.add_argument(
        "path",
        nargs="?",
        default=None,
        help="(stereopose.toml; with --serve: stereopose-serve.toml)",
    )
    it.add_argument(
        "--serve",
        action="store_true",
        help="write the example service configuration (`stereopose serve`)",
    )
    it.add_argument("--force", action="store_true", help="overwrite an existing file")


def _add_models(mo: argparse.ArgumentParser) -> None:
    """`models`."""
    mo.add_argument("action", choices=("list", "fetch", "export"), nargs="?", default="list")
    mo.add_argument("weights", type=Path, nargs="?", help="export: a YOLO pose .pt file")
    mo.add_argument(
        "--out", type=Path, help="export: the .onnx file to write (.xml with --openvino-int8)"
    )
    mo.add_argument("--force", action="store_true", help="export again even if cached")
    mo.add_argument(
        "--int8",
        action="store_true",
        help="export: the INT8-quantised ONNX model ([detector] precision = "
        '"int8"), from the .onnx or .pt given or the default model',
    )
    mo.add_argument(
        "--openvino-int8",
        action="store_true",
        help="export: OpenVINO's INT8 model (.xml and .bin, quantised by NNCF and checked "
        "against fp32) of the .onnx or .pt given or the default model; a plain export of the "
        "default model makes it too where OpenVINO and NNCF are installed",
    )


def _add_demo(d: argparse.ArgumentParser) -> None:
    """`demo`."""
    d.add_argument("--out", type=Path, default=Path("out/demo"))
    d.add_argument(
        "--overwrite",
        action="store_true",
        help="replace another run's outputs in --out (a previous demo is always replaced)",
    )
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


def _add_serve(sv: argparse.ArgumentParser) -> None:
    """`serve`."""
    sv.add_argument(
        "config",
        type=Path,
        nargs="?",
        metavar="CONFIG.toml",
        help="service configuration (the run schema plus [serve], [mqtt], [storage])",
    )
    sv.add_argument(
        "--demo",
        action="store_true",
        help="serve the real 4-camera demo, its videos looped for ever",
    )
    sv.add_argument(
        "--port",
        type=int,
        help="HTTP port of the console, its API, health and metrics (default 8787)",
    )
    sv.add_argument(
        "--data",
        type=Path,
        metavar="DIR",
        help="--demo: the service's data folder (default <out>/data)",
    )
    sv.add_argument(
        "--out",
        type=Path,
        default=Path("out/serve-demo"),
        metavar="DIR",
        help="--demo: where its configuration is written (out/serve-demo)",
    )


def _add_points(pt: argparse.ArgumentParser) -> None:
    """`points`."""
    pt.add_argument(
        "config",
        type=Path,
        metavar="CONFIG.toml",
        help="the service's configuration (its calibration, site and [iec104])",
    )


def _add_users(us: argparse.ArgumentParser) -> None:
    """`users`."""
    us.add_argument("action", choices=("add", "list", "remove", "passwd"))
    us.add_argument("name", nargs="?", metavar="NAME", help="the user (add, remove, passwd)")
    us.add_argument(
        "--role",
        choices=("viewer", "operator", "admin"),
        help="add: viewer (sees), operator (also acknowledges alarms), admin (also users)",
    )
    us.add_argument(
        "--sites",
        metavar="SITE,SITE",
        help="add, for a control room: the only sites this user sees and acts on "
        "(default: every site)",
    )
    us.add_argument(
        "--config",
        required=True,
        type=Path,
        metavar="CONFIG.toml",
        help="the service's configuration: its users live in its output folder",
    )


def _add_calibrate(cal: argparse.ArgumentParser) -> None:
    from stereopose.cli.calibrate_args import add_calibrate_site

    """`calibrate intrinsics`, `extrinsics`, `points`, `people` and `refine`."""
    csub = cal.add_subparsers(dest="step", required=True, metavar="STEP")
    steps = {}
    for name, (help_text, handler) in CALIBRATE_STEPS.items():
        steps[name] = csub.add_parser(name, help=help_text)
        steps[name].set_defaults(handler=handler)
    board_help = "inner corners COLSxROWS: a board of 15 x 11 squares has 14x10 inner corners"
    ci = steps["intrinsics"]
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

    ce = steps["extrinsics"]
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
    add_calibrate_site(steps)


def _add_simulate(s: argparse.ArgumentParser) -> None:
    """`simulate`."""
    s.add_argument("out_dir", type=Path, metavar="OUT_DIR")
    s.add_argument("--cameras", type=int, help="2-12 (default: by difficulty)")
    s.add_argument("--people", type=int, help="0-12 (default: by difficulty)")
    s.add_argument("--frames", type=int, default=250)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--difficulty", choices=("easy", "mid", "hard"), default="mid")
    s.add_argument("--fps", type=float, default=25.0)


def build_parser() -> argparse.ArgumentParser:
    """The parser of every command; each parsed command carries its handler's "module:function"
    as `handler` (see COMMANDS)."""
    p = argparse.ArgumentParser(
        prog="stereopose",
        description="3D positions and body joints of workers from several fixed cameras.",
    )
    p.add_argument("--version", action="version", version=f"stereopose {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log debugging detail")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parsers = {}
    for name, (help_text, handler) in COMMANDS.items():
        parsers[name] = sub.add_parser(name, help=help_text)
        if handler is not None:
            parsers[name].set_defaults(handler=handler)
    _add_reconstruct(parsers["reconstruct"], parsers["events"])
    _add_cameras(parsers)
    _add_calibrate(parsers["calibrate"])
    _add_simulate(parsers["simulate"])
    return p


def _handler(spec: str) -> Callable[[argparse.Namespace], int]:
    """The function named by "module:function", imported now."""
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(
        control_room_argv(list(sys.argv[1:] if argv is None else argv))
    )
    import logging

    from rich.logging import RichHandler
    from rich.markup import escape

    from stereopose.cli.common import console

    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(message)s",
        handlers=[RichHandler(console=console, show_time=False, show_path=False)],
    )
    from stereopose.faults import log_native_faults

    log_native_faults()  # a native crash (FFmpeg, a model runtime) leaves its stack in the log
    try:
        return _handler(args.handler)(args)
    except IncompleteOutputError as e:
        _incomplete(e, console)
        return e.exit_code
    except StereoposeError as e:
        console.print(f"[bold red]error:[/] {escape(str(e))}", highlight=False, soft_wrap=True)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        console.print("interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader of our output went away (`... | head`): end quietly
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def _incomplete(e: IncompleteOutputError, console: Console) -> None:
    """What a command that finished kept, and which outputs it could not write (exit 3)."""
    from rich.markup import escape

    from stereopose.io.summary import RunSummary

    for path in e.written:
        console.print(f"wrote {path}", markup=False, highlight=False, soft_wrap=True)
    if e.note:
        console.print(e.note, markup=False, highlight=False, soft_wrap=True)
    if isinstance(e.summary, RunSummary) and e.summary.interrupted:
        console.print("interrupted: the outputs above are complete up to the last frame processed")
    n = len(e.failures)
    console.print(
        f"[bold red]error:[/] finished, but {n} output{'s' * (n != 1)} could not be written:",
        highlight=False,
    )
    for what, why in e.failures.items():
        console.print(f"  {escape(what)}: {escape(why)}", highlight=False, soft_wrap=True)
