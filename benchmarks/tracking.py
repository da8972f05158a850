"""Identities, smoothing and speed of the whole 3D back end (association + triangulation +
tracking).

Simulated scenes of three difficulties (people entering, leaving, crossing, occluding each
other) give id switches, IDF1, MOTA and MPJPE per frame vs tracked without and with online
smoothing; short ghosts injected into hard scenes check that none gets an id; a 6-camera x
5-person scene gives frames/s on one core; the shared real detections give the ids of the two
main people. Results are written to benchmarks/results/tracking.{md,json}.

usage: python benchmarks/tracking.py [--frames 300] [--seeds 5]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, before numpy loads

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from stereopose.calibration.formats import load_calibration
from stereopose.config import Config, with_overrides
from stereopose.detection.openpose import read_pose_dir
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim import evaluate, evaluate_tracking, simulate
from stereopose.sim.metrics import detectable
from stereopose.sim.scene import ghost_frame
from stereopose.types import People2D

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "pose2sim-demo-yolo11n"
sys.path.insert(0, str(HERE))
from common import save, start


def frames_of(scene) -> list[list[People2D | None]]:
    return [[d[name] for name in scene.rig.names] for d in scene.detections]


def tracked(scene, frames=None, **tracking):
    cfg = with_overrides(dataclasses.replace(Config(), fps=scene.fps), tracking=tracking)
    tracker = Stage3D(scene.rig, cfg)
    frames = frames_of(scene) if frames is None else frames
    return [tracker.step(t, f) for t, f in enumerate(frames)]


def _timed(stage: Stage3D, data) -> tuple[float, float]:
    """frames/s of one pass over data, by the wall clock and by the process's CPU time; the
    compiled loops are loaded before (Stage3D.load), as a run does before its first frame."""
    stage.load()
    t0, c0 = time.perf_counter(), time.process_time()
    for t, f in enumerate(data):
        stage.step(t, f)
    return len(data) / (time.perf_counter() - t0), len(data) / (time.process_time() - c0)


def speed(frames: int, runs: int = 9) -> dict:
    scene = simulate(num_cameras=6, num_people=5, num_frames=frames, seed=7, difficulty="mid")
    data = frames_of(scene)
    per_frame, whole = [], []
    for _ in range(runs):
        recent = with_overrides(Config(), tracking={"memory": "recent"})
        per_frame.append(_timed(Stage3D(scene.rig, recent), data))
        whole.append(_timed(Stage3D(scene.rig, dataclasses.replace(Config(), fps=scene.fps)), data))
    wall, cpu = np.array(whole).T
    pf_wall, pf_cpu = np.array(per_frame).T
    row = {
        "cameras": 6,
        "people": 5,
        "back_end_fps": float(wall.max()),
        "back_end_median_fps": float(np.median(wall)),
        "back_end_cpu_fps": float(cpu.max()),
        "back_end_cpu_median_fps": float(np.median(cpu)),
        "per_frame_fps": float(pf_wall.max()),
        "per_frame_median_fps": float(np.median(pf_wall)),
        "per_frame_cpu_fps": float(pf_cpu.max()),
        "per_frame_cpu_median_fps": float(np.median(pf_cpu)),
    }
    print(
        f"speed: whole back end {row['back_end_fps']:.0f} frames/s best, "
        f"{row['back_end_median_fps']:.0f} median (by CPU time {row['back_end_cpu_fps']:.0f} "
        f"best, {row['back_end_cpu_median_fps']:.0f} median); per-frame 3D stage alone "
        f"{row['per_frame_fps']:.0f} best, {row['per_frame_median_fps']:.0f} median (by CPU "
        f"time {row['per_frame_cpu_fps']:.0f} best, {row['per_frame_cpu_median_fps']:.0f})",
        flush=True,
    )
    return row


def awaiting_confirmation(scene, config: Config | None = None) -> float:
    """Share of the counted person-frames in which a worker who is new (first seen, or back
    after longer than max_lost_s, when their track has ended) has not yet been seen long enough
    to be confirmed: no tracker output holds these people, which caps the tracked PCP and
    recall below 100 %."""
    config = config or Config()
    counted = detectable(scene)
    confirm, lost = config.tracking.confirm_frames, config.tracking.max_lost_s * scene.fps
    last = np.full(counted.shape[1], -np.inf)
    run = np.zeros(counted.shape[1], dtype=np.int64)
    new = np.zeros(counted.shape[1], dtype=bool)
    waiting = 0
    for t, row in enumerate(counted):
        starts = row & (run == 0)
        new = np.where(starts, t - last > lost, new)
        run = np.where(row, run + 1, 0)
        waiting += int((row & new & (run < confirm)).sum())
        last = np.where(row, t, last)
    return waiting / max(int(counted.sum()), 1)


def accuracy(frames: int, seeds: int) -> list[dict]:
    rows = []
    for difficulty in ("easy", "mid", "hard"):
        per_scene = []
        for seed in range(seeds):
            scene = simulate(num_frames=frames, seed=seed, difficulty=difficulty)
            rec = Stage3D(scene.rig, with_overrides(Config(), tracking={"memory": "recent"})).step
            base = evaluate([rec(t, f) for t, f in enumerate(frames_of(scene))], scene)
            raw = tracked(scene, smoothing=False)
            recorder = Stage3D(scene.rig, dataclasses.replace(Config(), fps=scene.fps), record=True)
            smooth = [recorder.step(t, f) for t, f in enumerate(frames_of(scene))]
            ids = evaluate_tracking(smooth, scene)
            m_raw, m_smooth = evaluate(raw, scene), evaluate(smooth, scene)
            m_two = evaluate(recorder.two_way(smooth), scene)
            per_scene.append(
                {
                    "seed": seed,
                    "workers": ids.workers,
                    "ids": ids.ids,
                    "id_switches": ids.id_switches,
                    "fragmented": ids.fragmented,
                    "ghost_ids": ids.ghost_ids,
                    "idf1": ids.idf1,
                    "mota": ids.mota,
                    "mpjpe_per_frame_mm": base.mpjpe_mm,
                    "mpjpe_tracked_raw_mm": m_raw.mpjpe_mm,
                    "mpjpe_smoothed_mm": m_smooth.mpjpe_mm,
                    "mpjpe_two_way_mm": m_two.mpjpe_mm,
                    "pcp_per_frame": base.pcp,
                    "pcp_smoothed": m_smooth.pcp,
                    "recall_smoothed": m_smooth.person_recall,
                    "awaiting_confirmation": awaiting_confirmation(scene),
                }
            )
        row = {
            "difficulty": difficulty,
            "cameras": len(scene.rig),
            "people": int(scene.truth.shape[1]),
            "scenes": per_scene,
            "max_id_switches": max(s["id_switches"] for s in per_scene),
        }
        for key in per_scene[0]:
            if key != "seed":
                row[key] = float(np.mean([s[key] for s in per_scene]))
        row["smoothing_gain"] = 1.0 - row["mpjpe_smoothed_mm"] / row["mpjpe_per_frame_mm"]
        rows.append(row)
        print(
            f"{difficulty:5s} id switches/scene {row['id_switches']:.1f} (max "
            f"{row['max_id_switches']}), IDF1 {row['idf1']:.3f}, MOTA {row['mota']:.3f}, ids "
            f"{row['ids']:.1f} for {row['workers']:.1f} workers; MPJPE per frame "
            f"{row['mpjpe_per_frame_mm']:.1f}, tracked raw {row['mpjpe_tracked_raw_mm']:.1f}, "
            f"smoothed {row['mpjpe_smoothed_mm']:.1f} mm ({100 * row['smoothing_gain']:.0f}% "
            f"lower), two-way {row['mpjpe_two_way_mm']:.1f} mm",
            flush=True,
        )
    return rows


def ghosts(frames: int, seeds: int, per_scene: int = 10) -> dict:
    """Ghosts of 1 and 2 frames (consistent false people in every camera) at random places
    and times of hard scenes: the ids given to them."""
    given = total = 0
    for seed in range(seeds):
        scene = simulate(num_frames=frames, seed=seed, difficulty="hard")
        rng = np.random.default_rng([seed, 99])
        data = frames_of(scene)
        placed = []
        for k in range(per_scene):
            t0 = int(rng.integers(5, frames - 5))
            length = 1 + k % 2
            where = rng.uniform([1.0, 1.0], [scene.room[0] - 1.0, scene.room[1] - 1.0])
            if any(abs(t0 - t) < 4 for t, _ in placed) or not scene.present[t0].any():
                continue
            placed.append((t0, where))
            for t in range(t0, t0 + length):
                data[t] = ghost_frame(scene, t, where)
        truth_ids = {int(i) for p in tracked(scene) for i in p.ids}
        ids = {int(i) for p in tracked(scene, data) for i in p.ids}
        given += len(ids) - len(truth_ids)
        total += len(placed)
    print(f"ghosts: {given} ids given to {total} ghosts of 1-2 frames", flush=True)
    return {"ghosts": total, "ids_given": given}


def real() -> dict | None:
    if not SHARED.is_dir():
        print(f"shared real detections not found at {SHARED}; skipped", file=sys.stderr)
        return None
    rig = load_calibration(SHARED / "calib.toml")
    tracker = Stage3D(rig, dataclasses.replace(Config(), fps=60.0))
    outs = [tracker.step(f, d) for f, d in read_pose_dir(SHARED / "pose", rig.names)]
    trajectories = tracker.trajectories()
    main = sorted(trajectories, key=lambda t: -t.frames_seen)[:2]
    row = {
        "frames": len(outs),
        "ids": len(trajectories),
        "main": [
            {
                "id": t.id,
                "first_frame": t.first_frame,
                "last_frame": t.last_frame,
                "frames_seen": t.frames_seen,
                "path_m": t.path_m,
            }
            for t in main
        ],
    }
    print(f"real: {row['ids']} ids; two main people: {row['main']}", flush=True)
    return row


def write(results: dict) -> None:
    md = _accuracy_md(results) + _speed_md(results) + _real_md(results)
    save("tracking", results, md)


def _accuracy_md(results: dict) -> list[str]:
    md = [
        "# Tracking: identities, smoothing, and the whole 3D back end's speed",
        "",
        f"Measured {results['date']} on {results['machine']} by `benchmarks/tracking.py "
        f"--frames {results['frames']} --seeds {results['seeds']}`.",
        "",
        "## Simulated substations",
        "",
        f"{results['seeds']} scenes of {results['frames']} frames (25 fps) per difficulty; "
        "workers enter, leave, stop, reach and cross. ID switches: times a worker's matched id "
        "changes; IDF1 and MOTA as in the MOT benchmarks; ids: ids given (workers: workers "
        "seen in >= 2 cameras); ghost ids: ids matched to a worker in fewer than half their "
        "frames. MPJPE: per frame (robust mode, no tracking), tracked without smoothing, "
        "tracked with online smoothing (the default; lower by: against per frame), and two-way "
        "(offline) smoothing of the same tracks, as the `--two-way` exports.",
        "",
        "| difficulty | cameras x people | ID switches / scene (max) | IDF1 | MOTA | ids / workers "
        "| ghost ids | MPJPE per frame mm | tracked raw mm | smoothed mm | lower by "
        "| two-way mm |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results["accuracy"]:
        md.append(
            f"| {r['difficulty']} | {r['cameras']} x {r['people']} | {r['id_switches']:.1f} "
            f"({r['max_id_switches']}) | {r['idf1']:.3f} | {r['mota']:.3f} | "
            f"{r['ids']:.1f} / {r['workers']:.1f} | {r['ghost_ids']:.1f} | "
            f"{r['mpjpe_per_frame_mm']:.1f} | {r['mpjpe_tracked_raw_mm']:.1f} | "
            f"{r['mpjpe_smoothed_mm']:.1f} | {100 * r['smoothing_gain']:.0f}% | "
            f"{r['mpjpe_two_way_mm']:.1f} |"
        )
    md += [
        "",
        "PCP (as in `benchmarks/results/reconstruction.md`) per frame (robust mode) and tracked "
        "(the default pipeline). A tracked person is output from their confirmation on; waiting: "
        "the share of counted person-frames of workers who are new (first seen, or back after "
        "their track ended) and not yet seen in enough frames to be confirmed, which no tracker "
        "output holds.",
        "",
        "| difficulty | PCP per frame % | PCP tracked % | person recall tracked % | waiting % |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in results["accuracy"]:
        md.append(
            f"| {r['difficulty']} | {100 * r['pcp_per_frame']:.2f} | "
            f"{100 * r['pcp_smoothed']:.2f} | {100 * r['recall_smoothed']:.2f} | "
            f"{100 * r['awaiting_confirmation']:.2f} |"
        )
    g = results["ghosts"]
    md += [
        "",
        f"Short ghosts: {g['ghosts']} false people of 1 or 2 frames, consistent in every camera, "
        f"injected into the hard scenes: {g['ids_given']} got an id.",
    ]
    return md


def _speed_md(results: dict) -> list[str]:
    s = results["speed"]
    return [
        "",
        "## Speed of the whole 3D back end (one core)",
        "",
        f"Association + triangulation + tracking, {results['frames']} frames of a mid scene "
        "with 6 cameras and 5 people, file reading excluded; 9 runs, best and median (this "
        "machine's speed varies between runs). Frames/s by the wall clock, and by the process's "
        "CPU time (they differ when the process waits for the CPU; where they agree, the "
        "variation between runs is the machine's own speed). The per-frame 3D stage alone (no "
        "tracking: the memory of recent people, as `--no-tracking` runs) was timed in the same "
        "runs. The one-time loading of the compiled loops (numba; `make install` compiles them, "
        "later processes load them from the cache) is done before each timed pass, as a run does "
        "before its first frame, and is not in these figures.",
        "",
        "| cameras x people | back end frames/s, best | median | by CPU time, best | median "
        "| per-frame stage, best | median | by CPU time, best | median |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        f"| {s['cameras']} x {s['people']} | {s['back_end_fps']:.0f} | "
        f"{s['back_end_median_fps']:.0f} | {s['back_end_cpu_fps']:.0f} | "
        f"{s['back_end_cpu_median_fps']:.0f} | {s['per_frame_fps']:.0f} | "
        f"{s['per_frame_median_fps']:.0f} | {s['per_frame_cpu_fps']:.0f} | "
        f"{s['per_frame_cpu_median_fps']:.0f} |",
    ]


def _real_md(results: dict) -> list[str]:
    md: list[str] = []
    if results["real"]:
        r = results["real"]
        md += [
            "",
            "## Shared real detections (pose2sim demo, 4 cameras, 100 frames at 60 fps)",
            "",
            f"{r['ids']} ids in all (the two main people and a bystander). The two main people:",
            "",
            "| id | first frame | last frame | frames seen | path m |",
            "|---:|---:|---:|---:|---:|",
        ]
        for t in r["main"]:
            md.append(
                f"| {t['id']} | {t['first_frame']} | {t['last_frame']} | {t['frames_seen']} | "
                f"{t['path_m']:.2f} |"
            )
        md.append("")
        md.append(
            "Ids are given after 3 consecutive frames (a confirmed person); the first two frames "
            "are output for nobody."
        )
    return md


def main() -> None:
    args, head = start(__doc__)
    results = {
        **head,
        "speed": speed(args.frames),
        "accuracy": accuracy(args.frames, args.seeds),
        "ghosts": ghosts(args.frames, args.seeds),
        "real": real(),
    }
    write(results)


if __name__ == "__main__":
    main()
