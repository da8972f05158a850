"""The commands `stereopose` offers, in the order `--help` lists them, each with its help line
and its handler's "module:function" (imported when the command runs: see stereopose.cli)."""

from __future__ import annotations

__all__ = ["CALIBRATE_STEPS", "COMMANDS"]

# command -> (help, the handler's "module:function"), in the order `stereopose --help` lists them;
# calibrate's handlers belong to its steps
COMMANDS: dict[str, tuple[str, str | None]] = {
    "reconstruct": (
        "2D keypoints of calibrated cameras -> 3D poses JSONL",
        "stereopose.cli.reconstruct:_reconstruct",
    ),
    "detect": (
        "videos, image folders or streams -> 2D keypoint files",
        "stereopose.cli.run:_detect",
    ),
    "run": ("cameras -> 3D people, tracks, zone events, report", "stereopose.cli.run:_run"),
    "serve": (
        "the always-on service: cameras for ever, events out, health and metrics over HTTP",
        "stereopose.cli.serve:_serve",
    ),
    "detect-node": (
        "a detection node: some of a site's cameras detected here, their people to its broker",
        "stereopose.cli.detect_node:_detect_node",
    ),
    "control-room": (
        "one control room for many sites: their events over the central broker, stored once",
        "stereopose.cli.control_room:_control_room",
    ),
    "users": (
        "the operator console's users of a service: add, list, remove, passwd",
        "stereopose.cli.users:_users",
    ),
    "points": (
        "the IEC 60870-5-104 points of a service's configuration, as CSV (ioa,type,...)",
        "stereopose.cli.points:_points",
    ),
    "init": (
        "write a commented example run (or --serve: service) configuration",
        "stereopose.cli.run:_init",
    ),
    "report": ("rebuild report.html of a run folder", "stereopose.cli.run:_report"),
    "models": (
        "list, fetch or export the pose models in the cache",
        "stereopose.cli.run:_models",
    ),
    "calibrate": ("camera calibration: a checkerboard, surveyed points or walking people", None),
    "events": ("list the events of an SQLite event log", "stereopose.cli.reconstruct:_events"),
    "simulate": (
        "write a simulated substation scene with ground truth",
        "stereopose.cli.sim:_simulate",
    ),
    "demo": (
        "run the real 4-camera demo end to end (--synthetic: a simulated substation)",
        "stereopose.cli.run:_demo",
    ),
}
CALIBRATE_STEPS: dict[str, tuple[str, str]] = {
    "intrinsics": (
        "focal length, principal point, lens distortion",
        "stereopose.cli.calibrate:_calibrate_intrinsics",
    ),
    "extrinsics": (
        "every camera's pose in one world frame",
        "stereopose.cli.calibrate:_calibrate_extrinsics",
    ),
    "points": (
        "every camera's pose from surveyed points clicked in its view",
        "stereopose.cli.calibrate_site:_calibrate_points",
    ),
    "people": (
        "every camera's pose from people walking through the site",
        "stereopose.cli.calibrate_site:_calibrate_people",
    ),
    "refine": (
        "place some cameras again from the people the others see",
        "stereopose.cli.calibrate_site:_calibrate_refine",
    ),
}
