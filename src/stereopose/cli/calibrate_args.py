"""The arguments of `calibrate points`, `calibrate people` and `calibrate refine`."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_calibrate_site(steps: dict[str, argparse.ArgumentParser]) -> None:
    """`calibrate points`, `calibrate people`, `calibrate refine`."""
    cp = steps["points"]
    cp.add_argument(
        "--points",
        required=True,
        type=Path,
        metavar="POINTS.toml",
        help="the points' site coordinates ([points]) and their pixels per camera "
        "([cameras.<name>])",
    )
    cp.add_argument("--intrinsics", required=True, type=Path, help="calibration with intrinsics")
    cp.add_argument("--out", required=True, type=Path, metavar="CALIB.toml")
    cp.add_argument("--report", type=Path, metavar="DIR", help="write points.json here")
    pe = steps["people"]
    pe.add_argument(
        "--pose",
        required=True,
        type=Path,
        nargs="+",
        metavar="DIR",
        help="detect's <camera>_json folders; several: recordings of the same cameras at "
        "different times, pooled (each with its own frame numbers)",
    )
    pe.add_argument("--intrinsics", required=True, type=Path, help="calibration with intrinsics")
    pe.add_argument("--out", required=True, type=Path, metavar="CALIB.toml")
    scale = pe.add_mutually_exclusive_group(required=True)
    scale.add_argument(
        "--distance",
        nargs=3,
        metavar=("CAM_A", "CAM_B", "METRES"),
        help="the measured distance between two cameras",
    )
    scale.add_argument("--height", type=float, metavar="METRES", help="the walkers' height")
    scale.add_argument(
        "--points", type=Path, metavar="POINTS.toml", help="surveyed points (also the world frame)"
    )
    pe.add_argument(
        "--ankle-height",
        type=float,
        default=0.08,
        metavar="METRES",
        help="the COCO ankle's height above the floor (default 0.08)",
    )
    pe.add_argument(
        "--max-frames", type=int, default=600, help="frames sampled at most, per recording"
    )
    pe.add_argument(
        "--held-out",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="with several recordings, each one's fit by the rig from the others (default: on)",
    )
    pe.add_argument("--report", type=Path, metavar="DIR", help="write people.json here")
    rf = steps["refine"]
    rf.add_argument("--calib", required=True, type=Path, metavar="CALIB.toml")
    rf.add_argument(
        "--pose",
        required=True,
        type=Path,
        nargs="+",
        metavar="DIR",
        help="detect's <camera>_json folders (several: recordings pooled)",
    )
    rf.add_argument("--out", required=True, type=Path, metavar="CALIB.toml")
    rf.add_argument(
        "--cameras",
        metavar="CAM,...",
        help="the cameras to place again (default: those the others place elsewhere)",
    )
    rf.add_argument(
        "--max-frames", type=int, default=600, help="frames sampled at most, per recording"
    )
