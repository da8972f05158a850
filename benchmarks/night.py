"""The real demo at night: night versions of its four videos at several darkness and noise
levels, through `stereopose run`, with the night preparation (`[detector] night = true`, the
default) and without it.

Variants, made with ffmpeg (imageio-ffmpeg's) from the demo's videos and encoded with libx264
as a camera would (the encoding smears the noise into blotches, which is what hides people):
- day: the demo as it is (with night on and off: the same outputs, the day path unchanged);
- dusk: `format=gray, eq=brightness=-0.15:contrast=0.7, noise=alls=12:allf=t`;
- night: `format=gray, eq=brightness=-0.25:contrast=0.5, noise=alls=25:allf=t`;
- dark: `format=gray, eq=brightness=-0.32:contrast=0.4, noise=alls=30:allf=t`.

Figures per variant and set-up: people per frame in 3D, the frames in which the two longest
tracks are both there ("ids stable"), the median reprojection of the 3D joints onto the day
detections (the shared YOLO11n detections of the demo, the 3D people matched one-to-one to
them per camera, every matched joint's distance; matches over GATE_PX off counted apart, and
a median of every match beside), each camera's light mode, the preparation's ms per step,
and the step's ms.

    python benchmarks/night.py [--frames 100]

Results in results/night.{json,md}.
"""

from __future__ import annotations

import argparse
import datetime
import filecmp
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, save
from regions import one_run
from stereopose.calibration.formats import load_calibration
from stereopose.detection.models import demo_videos
from stereopose.detection.openpose import read_pose_dir
from stereopose.geometry.camera import project_to_rig
from stereopose.io.pose2sim_data import pose2sim_demo_dir

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "pose2sim-demo-yolo11n"
VARIANTS = {
    "day": None,
    "dusk": "format=gray,eq=brightness=-0.15:contrast=0.7,noise=alls=12:allf=t",
    "night": "format=gray,eq=brightness=-0.25:contrast=0.5,noise=alls=25:allf=t",
    "dark": "format=gray,eq=brightness=-0.32:contrast=0.4,noise=alls=30:allf=t",
}
SETUPS = {"prepared": "night = true", "as_is": "night = false"}
MIN_CONF = 0.5
GATE_PX = 50.0  # a 3D person this far (median) from a day detection is not that person


def _ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def variant(folder: Path, recipe: str | None, frames: int) -> dict[str, Path]:
    """The demo's four videos, `frames` long, through the recipe (None: as they are)."""
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for v in demo_videos():
        target = folder / v.name
        cmd = [_ffmpeg(), "-loglevel", "error", "-y", "-i", str(v), "-frames:v", str(frames)]
        if recipe:
            cmd += ["-vf", recipe]
        cmd += ["-c:v", "libx264", "-preset", "veryfast", "-crf", "18", "-pix_fmt", "yuv420p"]
        subprocess.run([*cmd, str(target)], check=True, timeout=600)
        out[v.stem] = target
    return out


def onto_day(
    poses: Path, rig, day, gate_px: float | None = GATE_PX
) -> tuple[float | None, int, int]:
    """The 3D joints projected into each camera against the day's detections there: per frame
    and camera, the 3D people matched one-to-one to the day's (Hungarian, on the median
    distance over the joints both have, the day's at confidence MIN_CONF or more); each
    matched joint's distance. A match farther than gate_px (median) is a different person or
    a ghost, counted apart (None: every match kept). Returns the median over the joints, the
    matches kept and the matches beyond the gate."""
    from scipy.optimize import linear_sum_assignment

    errors: list[np.ndarray] = []
    kept = beyond = 0
    for line in poses.read_text().splitlines():
        rec = json.loads(line)
        if not rec["people"]:
            continue
        people2d = day.frame(rec["frame"])
        joints = np.array(
            [[j if j is not None else [np.nan] * 3 for j in p["joints"]] for p in rec["people"]],
            float,
        )
        px = project_to_rig(np.nan_to_num(joints), rig)  # (P, 17, C, 2)
        ok = ~np.isnan(joints[..., 0])  # (P, 17)
        for ci, cam in enumerate(rig):
            found = people2d.get(cam.name)
            if found is None or not len(found.keypoints):
                continue
            kp = np.asarray(found.keypoints)  # (D, 17, 3)
            dist = np.linalg.norm(px[:, None, :, ci] - kp[None, :, :, :2], axis=-1)  # (P, D, 17)
            both = ok[:, None] & (kp[None, :, :, 2] >= MIN_CONF)
            enough = both.sum(-1) >= 6
            with np.errstate(all="ignore"):
                cost = np.nanmedian(np.where(both, dist, np.nan), axis=-1)
            cost = np.where(enough, cost, np.inf)
            rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
            for a, b in zip(rows, cols, strict=True):
                if not np.isfinite(cost[a, b]):
                    continue
                if gate_px is not None and cost[a, b] > gate_px:
                    beyond += 1
                    continue
                kept += 1
                errors.append(dist[a, b][both[a, b]])
    if not errors:
        return None, kept, beyond
    return float(np.median(np.concatenate(errors))), kept, beyond


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    args = ap.parse_args()
    if not demo_videos():
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    calib = pose2sim_demo_dir() / "Demo_MultiPerson" / "calibration" / "Calib.qca.txt"
    rig = load_calibration(calib)
    day = read_pose_dir(SHARED / "pose", rig.names)
    r: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", "all cores"),
        "frames": args.frames,
        "variants": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name, recipe in VARIANTS.items():
            videos = variant(work / "videos" / name, recipe, args.frames)
            runs = {}
            for setup, line in SETUPS.items():
                s, poses = one_run(work / name / setup, calib, videos, line)
                summary = json.loads((work / name / setup / "summary.json").read_text())
                light = summary.get("light", {})
                s["modes"] = {c: v["mode"] for c, v in light.items()}
                s["prepare_ms_per_step"] = sum(
                    v["prepare_ms"] * v["prepared_steps"] for v in light.values()
                ) / max(s["frames"], 1)
                s["people_per_frame"] = summary.get("people_per_frame")
                s["onto_day_px"], s["matched"], s["beyond_gate"] = onto_day(poses, rig, day)
                s["onto_day_all_px"] = onto_day(poses, rig, day, None)[0]
                s.pop("regions", None)
                runs[setup] = s
                print(name, setup, s, flush=True)
            if name == "day":
                a, b = (work / name / k / "poses3d.jsonl" for k in SETUPS)
                runs["prepared"]["same_as_without"] = filecmp.cmp(a, b, shallow=False)
            r["variants"][name] = runs
    save("night", r, markdown(r))


def markdown(r: dict) -> list[str]:
    md = [
        "# The real demo at night",
        "",
        f"`python benchmarks/night.py --frames {r['frames']}`, {r['date']}, {r['machine']}. "
        "Night versions of the demo's four videos (ffmpeg recipes in the script, libx264), "
        "through `stereopose run` with its defaults, with the night preparation (`[detector] "
        "night = true`, the default) and without it (`night = false`). Onto the day: the 3D "
        "joints projected into each camera, each 3D person matched one-to-one to the day's "
        "YOLO11n detections there (the shared data; Hungarian on the median distance), the "
        f"median over every matched joint the day is sure of (confidence {MIN_CONF} or more); "
        f"a match more than {GATE_PX:g} px off (median) is another person or a ghost, "
        "counted apart (beyond), and in the median of every match (all).",
        "",
        "| variant | set-up | light (cam01-04) | people per frame | ids stable (frames) | "
        "onto the day px | all matches px | matches beyond | preparation ms/step | step ms |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, runs in r["variants"].items():
        for setup, x in runs.items():
            modes = " / ".join(x["modes"].values()) or "-"
            ppf = x["people_per_frame"]
            onto = x["onto_day_px"]
            md.append(
                f"| {name} | {setup.replace('_', ' ')} | {modes} | "
                f"{ppf:.2f} | {x['ids_stable_frames']} of {x['frames']} | "
                f"{onto:.1f} | {x['onto_day_all_px']:.1f} | {x['beyond_gate']} of "
                f"{x['matched'] + x['beyond_gate']} | {x['prepare_ms_per_step']:.1f} | "
                f"{x.get('wall_ms_per_step', x['step_ms']):.0f} |"
                if ppf is not None and onto is not None
                else f"| {name} | {setup} | {modes} | - | - | - | - | - | - | "
                f"{x.get('wall_ms_per_step', x['step_ms']):.0f} |"
            )
    same = r["variants"].get("day", {}).get("prepared", {}).get("same_as_without")
    if same is not None:
        md += [
            "",
            f"Day with the night preparation on and off: poses3d.jsonl identical: {same}.",
        ]
    return md


if __name__ == "__main__":
    main()
