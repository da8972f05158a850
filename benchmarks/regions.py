"""Detection in regions against whole frames at 640 and at 1280, through `stereopose run`, on the
real demo and on scenes made from it.

Scenes (every one from the real 4-camera recording and its calibration):
- full: the demo as it is (1088x1920 portrait frames, people 600-1000 px tall);
- far_0.2, far_0.3: each frame shrunk to a fifth (a third) into a grey 1920x1080 canvas, the
  calibration scaled to match (stereopose.sim.distant): people about 120-200 (180-300) px tall,
  as workers 8-10 m from a wide 1080p camera;
- empty: the canvas alone with sensor noise (sigma 2 grey levels): nobody, nothing moving, at
  5 frames/s (a served camera's step rate: the full scans come as often as they would);
- newcomer: the canvas empty for 3 s, then the far_0.3 workers there at once and standing
  still (their frame frozen) for the rest, at 10 frames/s.

Set-ups: whole frames at 640 (the old path: regions off, ONNX Runtime fp32, every camera
detected at every step) and at 1280, regions (ONNX Runtime fp32), and the defaults (backend
auto: OpenVINO bf16 where the CPU has bfloat16 instructions; regions on; carried steps) with
regions off, and with every camera detected at every step. For each scene and set-up in the
same run:
detection ms per step and the whole step's, people
per camera per frame, the frames in which the two longest tracks are both there ("ids
stable"), the median reprojection error, the 3D joints against the whole-frame 1280 result
(people matched per frame, mm), and for the newcomer scene the time from his appearance to
his first 3D output (regions with motion, regions by the full scans alone, whole frames).
Capacity: cameras one box holds at 5 steps/s, from the whole step's time per camera. With
`--repeat N` each set-up runs N times and the fastest is kept (its outputs are the same each
time: only the time varies with what else the machine does).

    python benchmarks/regions.py [--frames 100] [--scenes full,far_0.3] [--setups ...]

Results in results/regions.{json,md}.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from backends import _f, joints_moved  # 3D joints matched per frame; a figure or -
from common import machine, save
from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.detection.models import demo_videos
from stereopose.fence.site import Site, load_site, save_site
from stereopose.pipeline.demo import CAMERAS, write_demo_config
from stereopose.pipeline.run import run
from stereopose.sim.distant import Distant

SETUPS = {  # name: [detector] lines; ONNX Runtime fp32 unless it says otherwise
    "whole_640": 'backend = "onnx"\nregions = false\ncarry = false\nimgsz = 640',  # the old path
    "whole_1280": 'backend = "onnx"\nregions = false\ncarry = false\nimgsz = 1280',
    "regions": 'backend = "onnx"\nregions = true\ncarry = false',
    "default": "",  # every default: backend auto (detection.choose), regions, carried steps
    "default_whole": "regions = false",  # backend auto, whole frames at 640, carried steps
    "default_every_step": "carry = false",  # backend auto, regions, every camera every step
}
OLD_PATH = "whole_640"
NEWCOMER_AT_S = 3.0
NEWCOMER_FPS = 10.0
EMPTY_FPS = 5.0
STEP_RATE = 5.0  # steps/s a box must keep up with, for its capacity
AWAY_M = 50.0  # --hazards-away: how far the energized zones are moved


def _frames(n: int) -> dict[str, list[np.ndarray]]:
    out = {}
    for name, video in zip(CAMERAS, demo_videos(), strict=True):
        cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
        frames = []
        while len(frames) < n:
            ok, im = cap.read()
            if not ok:
                break
            frames.append(im)
        cap.release()
        out[name] = frames
    return out


def _write(folder: Path, frames: dict[str, list[np.ndarray]], fps: float) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, images in frames.items():
        path = folder / f"{name}.mp4"
        h, w = images[0].shape[:2]
        out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
        for im in images:
            out.write(im)
        out.release()
        paths[name] = path
    return paths


def scenes(work: Path, n: int) -> dict[str, tuple[Path, dict[str, Path], float]]:
    """name -> (calibration, videos by camera, fps)."""
    demo_cfg = write_demo_config(work / "demo")
    lines = demo_cfg.read_text().splitlines()
    calib = Path(
        next(ln.split("=", 1)[1].strip().strip('"') for ln in lines if ln.startswith("calibration"))
    )
    rig = load_calibration(calib)
    real = _frames(n)
    out = {"full": (calib, dict(zip(CAMERAS, demo_videos(), strict=True)), 60.0)}
    rng = np.random.default_rng(0)
    for scale in (0.2, 0.3):
        d = Distant(scale)
        path = work / f"far_{scale}.toml"
        save_calibration(path, d.rig(rig))
        frames = {c: [d.frame(im) for im in real[c]] for c in CAMERAS}
        out[f"far_{scale}"] = (path, _write(work / f"far_{scale}", frames, 60.0), 60.0)
    d = Distant(0.3)
    path = work / "far_0.3.toml"
    empty = {
        c: [
            np.clip(d.empty() + rng.normal(0, 2, d.empty().shape), 0, 255).astype(np.uint8)
            for _ in range(n)
        ]
        for c in CAMERAS
    }
    # at 5 frames/s, a served camera's step rate: 100 frames hold several full scans
    out["empty"] = (path, _write(work / "empty", empty, EMPTY_FPS), EMPTY_FPS)
    first = round(NEWCOMER_AT_S * NEWCOMER_FPS)
    newcomer = {c: [d.empty()] * first + [d.frame(real[c][0])] * max(n - first, 1) for c in CAMERAS}
    out["newcomer"] = (path, _write(work / "newcomer", newcomer, NEWCOMER_FPS), NEWCOMER_FPS)
    return out


def one_run(
    work: Path, calib: Path, videos: dict[str, Path], detector: str, site: Path | None = None
) -> tuple[dict, Path]:
    work.mkdir(parents=True, exist_ok=True)
    lines = [
        f'calibration = "{calib}"',
        *([f'site = "{site}"'] if site is not None else []),
        'output = "."',
        "",
        "[detector]",
        detector,
        "",
        "[outputs]",
        "trc = false",
        "csv = false",
        "overlays = false",
        "report = false",
        "",
    ]
    for name, video in videos.items():
        lines += ["[[cameras]]", f'name = "{name}"', f'source = "{video}"', ""]
    config = work / "run.toml"
    config.write_text("\n".join(lines))
    t0 = time.perf_counter()
    s = run(config)
    wall = time.perf_counter() - t0
    poses = work / "poses3d.jsonl"
    return {
        "frames": s.frames,
        "wall_s": wall,
        "detect_ms_per_step": 1000 * s.seconds.get("detect", 0.0) / max(s.frames, 1),
        "step_ms": 1000 * sum(s.seconds.values()) / max(s.frames, 1),
        # the frame loop's wall time per step: decoding read ahead overlaps detection
        "wall_ms_per_step": 1000 * s.wall_s / max(s.frames, 1),
        "people_per_camera": {
            c: v.as_dict()["detections_per_frame"] for c, v in s.per_camera.items()
        },
        "reprojection_median_px": s.reprojection_median_px,
        "ids_stable_frames": _stable(poses),
        "regions": s.regions,
        "detector": s.detector,
        "carried_share": sum(c["carried"] for c in s.carry.values())
        / max(sum(c["carried"] + c["detected"] for c in s.carry.values()), 1),
        # the camera-steps detected that would have been carried but for someone near a
        # hazard (detection.carry, zones.hazard)
        "held_share": sum(c.get("near_hazard", 0) for c in s.carry.values())
        / max(sum(c["carried"] + c["detected"] for c in s.carry.values()), 1),
    }, poses


def _stable(poses: Path) -> int:
    """Frames in which the two ids seen in most frames are both there."""
    frames, count = [], {}
    for line in poses.read_text().splitlines():
        ids = {p["id"] for p in json.loads(line)["people"]}
        frames.append(ids)
        for i in ids:
            count[i] = count.get(i, 0) + 1
    top = sorted(count, key=count.get, reverse=True)[:2]
    return sum(1 for ids in frames if len(top) == 2 and set(top) <= ids)


def first_output_s(poses: Path, fps: float) -> float | None:
    """Seconds from the newcomer's appearance to the first frame with someone in 3D."""
    first = round(NEWCOMER_AT_S * fps)
    for line in poses.read_text().splitlines():
        rec = json.loads(line)
        if rec["frame"] >= first and rec["people"]:
            return (rec["frame"] - first) / fps
    return None


def kept_after_first(poses: Path, fps: float) -> float | None:
    """The share of frames after the newcomer's first output with someone in 3D."""
    recs = [json.loads(line) for line in poses.read_text().splitlines()]
    first = round(NEWCOMER_AT_S * fps)
    seen = [bool(r["people"]) for r in recs if r["frame"] >= first]
    if True not in seen:
        return None
    after = seen[seen.index(True) :]
    return sum(after) / len(after)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--scenes", help="comma-separated scenes (default: every one)")
    ap.add_argument("--setups", help="comma-separated set-ups (default: every one)")
    ap.add_argument("--name", default="regions", help="results/<name>.{json,md} (regions)")
    ap.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="runs of each set-up, the fastest kept (the same outputs: only time varies)",
    )
    ap.add_argument(
        "--site",
        action="store_true",
        help="every scene watched as the demo's site (its zones, in the recording's world "
        "frame): the scans plan their tiles on how small its farthest worker looks",
    )
    ap.add_argument(
        "--hazards-away",
        action="store_true",
        help="with --site: the site's energized zones moved 50 m along x, away from everyone "
        "(the same zones otherwise): where carried steps are allowed",
    )
    args = ap.parse_args()
    if args.hazards_away and not args.site:
        ap.error("--hazards-away needs --site")
    only = set(args.scenes.split(",")) if args.scenes else None
    chosen = args.setups.split(",") if args.setups else list(SETUPS)
    chosen = [*dict.fromkeys([OLD_PATH, *chosen])]  # the old path: the speed-ups' reference
    if not demo_videos():
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    r: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", "all cores"),
        "frames": args.frames,
        "scenes": {},
    }
    r["site"] = bool(args.site)
    r["hazards_away"] = bool(args.hazards_away)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        site = write_demo_config(work / "site").parent / "demo_site.toml" if args.site else None
        if site is not None and args.hazards_away:
            save_site(site, hazards_moved(load_site(site), AWAY_M))
        for scene, (calib, videos, fps) in scenes(work / "scenes", args.frames).items():
            if only is not None and scene not in only:
                continue
            runs, poses = {}, {}
            setups = {k: SETUPS[k] for k in chosen}
            if scene == "newcomer":
                setups["regions_scans_only"] = SETUPS["regions"] + "\nmotion_threshold = 255"
            if scene == "full" and args.setups is None:  # people too large for a region
                setups["regions_detail_0.5"] = SETUPS["regions"] + "\nregion_detail = 0.5"
            for name, det in setups.items():
                tries = [
                    one_run(work / scene / f"{name}_{k}", calib, videos, det, site)
                    for k in range(max(args.repeat, 1))
                ]
                runs[name], poses[name] = min(tries, key=lambda x: x[0]["wall_ms_per_step"])
                print(
                    scene, name, {k: v for k, v in runs[name].items() if k != "regions"}, flush=True
                )
            for name in setups:
                if name != "whole_1280" and "whole_1280" in poses:
                    runs[name]["joints_against_1280"] = joints_moved(
                        poses["whole_1280"], poses[name]
                    )
                if scene == "newcomer":
                    runs[name]["first_output_s"] = first_output_s(poses[name], fps)
                    runs[name]["kept_after_first"] = kept_after_first(poses[name], fps)
            r["scenes"][scene] = {"fps": fps, "runs": runs}
        if only is None or "empty" in only:
            r["empty_camera"] = empty_camera(videos_of(work / "scenes" / "empty"))
    r["command"] = " ".join(["python benchmarks/regions.py", *sys.argv[1:]])
    save(args.name, r, markdown(r))


def hazards_moved(site: Site, dx: float) -> Site:
    """`site` with each energized zone moved dx metres along x (the rest as it is)."""
    zones = tuple(
        dataclasses.replace(z, polygon=np.add(z.polygon, [dx, 0.0])) if z.kind == "energized" else z
        for z in site.zones
    )
    return dataclasses.replace(site, zones=zones)


def videos_of(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.mp4"))


def empty_camera(videos: list[Path], steps: int = 60) -> dict:
    """One empty camera's detection once its first scan is done: ms per step at 5 steps/s
    (its idle steps and its later scans, full_scan_s apart), against a whole-frame inference
    at 640 of the same frame."""
    from stereopose.detection import make_detector
    from stereopose.detection.regional import RegionDetector

    cap = cv2.VideoCapture(str(videos[0]), cv2.CAP_FFMPEG)
    frames = []
    while len(frames) < steps + 1:
        ok, im = cap.read()
        if not ok:
            break
        frames.append(im)
    cap.release()
    det = make_detector("onnx")
    regions = RegionDetector(det)
    regions.detect({"cam": frames[0]}, 0.0)  # its first scan: the whole frame and every tile
    t0 = time.perf_counter()
    for k, im in enumerate(frames[1:], start=1):
        regions.detect({"cam": im}, k / EMPTY_FPS)
    per_step = (time.perf_counter() - t0) / (len(frames) - 1)
    det.detect([frames[0]])  # warm
    t0 = time.perf_counter()
    for im in frames[:10]:
        det.detect([im])
    whole = (time.perf_counter() - t0) / 10
    c = regions.report()["cam"]
    return {
        "steps": len(frames) - 1,
        "ms_per_step": 1000 * per_step,
        "whole_640_ms": 1000 * whole,
        "share_of_whole": per_step / whole,
        "full_scans": c["full_scans"] - 1,
        "idle_steps": c["idle_steps"],
    }


def _per_step(x: dict) -> float:
    """A run's ms per step: the frame loop's wall time (older results: its stages' sum)."""
    return x.get("wall_ms_per_step", x["step_ms"])


def capacity(step_ms: float, cameras: int = 4) -> float:
    """Cameras one box keeps at STEP_RATE steps/s, from the whole step's time of `cameras`."""
    return 1000 / STEP_RATE / (step_ms / cameras) if step_ms > 0 else float("inf")


def markdown(r: dict) -> list[str]:
    md = [
        "# Detection in regions against whole frames",
        "",
        f"`{r.get('command', 'python benchmarks/regions.py')}`, {r['date']}, {r['machine']}. "
        "Every figure from `stereopose run` (YOLO11n-pose, the 3D stage, tracking) on the real "
        "demo and on scenes made from it, all set-ups in the same run; the old path is whole "
        "frames at 640 on ONNX Runtime fp32; regions at their defaults "
        "(region_imgsz 320, full_scan_s 3, region_detail 1). ms per step: detection's, and the "
        "whole step's over 4 cameras (the frame loop's wall time: decoding, read ahead on its "
        "own thread, detection, 3D, writing)."
        + (
            " Every scene is watched as the demo's site (its zones, in the recording's world "
            "frame): a camera whose farthest watched worker is found in the whole frame scans "
            "it without tiles."
            if r.get("site")
            else ""
        )
        + (
            f" Its energized zone (the busbar) moved {AWAY_M:g} m along x, away from everyone: "
            "no camera is held for a hazard."
            if r.get("hazards_away")
            else " A camera that sees someone near an energized zone is never carried "
            "(held near a hazard)."
            if r.get("site")
            else ""
        ),
        "",
        "| scene | set-up | detector | detection ms/step | step ms | faster than the old path | "
        "people per camera (cam01 / 02 / 03 / 04) | ids stable (frames) | reprojection median "
        "px | 3D joints against 1280: median / p95 mm | model input against whole 640 | "
        "camera-steps carried | camera-steps held near a hazard | cameras at 5 steps/s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, sc in r["scenes"].items():
        old = sc["runs"].get(OLD_PATH)
        for name, x in sc["runs"].items():
            d = x.get("detector") or {}
            what = f"{d.get('backend', 'onnx')} {d.get('precision', 'fp32')}"
            faster = f"{_per_step(old) / _per_step(x):.2f}x" if old and _per_step(x) else "-"
            ppl = " / ".join(f"{v:.2f}" for v in x["people_per_camera"].values())
            m = x.get("joints_against_1280")
            moved = (
                f"{_f(m['median_mm'], 1)} / {_f(m['p95_mm'], 1)}"
                if m
                else "(reference)"
                if name == "whole_1280"
                else "-"
            )
            share = "-"
            if x["regions"]:
                used = sum(c["input_px"] for c in x["regions"].values())
                whole = sum(c["whole_input_px"] for c in x["regions"].values())
                share = f"{100 * used / whole:.0f} %" if whole else "-"
            md.append(
                f"| {scene} | {name.replace('_', ' ')} | {what} | "
                f"{x['detect_ms_per_step']:.0f} | {_per_step(x):.0f} | {faster} | {ppl} | "
                f"{x['ids_stable_frames']} of {x['frames']} | "
                f"{_f(x['reprojection_median_px'], 2)} | {moved} | {share} | "
                f"{100 * x.get('carried_share', 0.0):.0f} % | "
                f"{100 * x.get('held_share', 0.0):.0f} % | {capacity(_per_step(x)):.1f} |"
            )
    ec = r.get("empty_camera")
    if ec:
        md += [
            "",
            f"An empty camera once its first scan is done ({ec['steps']} steps at "
            f"{EMPTY_FPS:g} steps/s, {ec['full_scans']} later scans, {ec['idle_steps']} idle "
            f"steps): {ec['ms_per_step']:.1f} ms per step against {ec['whole_640_ms']:.1f} ms "
            f"for its whole frame at 640, {100 * ec['share_of_whole']:.1f} % of it.",
        ]
    nc = r["scenes"].get("newcomer")
    if nc:
        md += [
            "",
            f"Newcomer (appears at {NEWCOMER_AT_S:g} s and stands still, {nc['fps']:g} frames/s): "
            "seconds to his first 3D output, and the share of frames after it with him in 3D:",
            "",
            "| set-up | first output s | kept after |",
            "|---|---|---|",
        ]
        for name, x in nc["runs"].items():
            md.append(
                f"| {name.replace('_', ' ')} | {_f(x['first_output_s'], 2)} | "
                f"{_f(x['kept_after_first'], 3)} |"
            )
    return md


if __name__ == "__main__":
    main()
