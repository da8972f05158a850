"""Whole processes on one core: `stereopose reconstruct` against the pure-Python yardstick.

A simulated substation (mid difficulty, 6 cameras x 5 people, 400 frames: what `stereopose
simulate` writes) goes to a temporary folder; then each command runs as its own process, pinned
to one core with one thread, timed by the wall clock from start to exit: `stereopose reconstruct`
(tracking on, the default, and --no-tracking), `python benchmarks/yardstick.py`, `stereopose
--help`, `python -c "import stereopose.cli"` and, for where the time of a reconstruction goes,
`python -c "import stereopose.pipeline"`. One warm-up round, then --runs rounds, the commands
taking turns. Accuracy against the scene's ground truth (stereopose.sim), and what the
`reconstruct` command's own summary says. Results go to
benchmarks/results/reconstruct_process.{md,json}.

usage: python benchmarks/reconstruct_process.py [--runs 5] [--frames 400] [--seed 0]
"""

from __future__ import annotations

import os

THREADS = {v: "1" for v in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
THREADS["MKL_NUM_THREADS"] = "1"
os.environ.update(THREADS)  # one core, before numpy loads

import argparse
import datetime
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from stereopose.io.results import load_people3d
from stereopose.pipeline import evaluate_poses_file
from stereopose.sim import evaluate_tracking, simulate
from stereopose.sim.io import write_scene

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import machine, save

CAMERAS, PEOPLE, DIFFICULTY = 6, 5, "mid"


def stereopose_command() -> list[str]:
    script = Path(sys.executable).with_name("stereopose")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "stereopose.cli"]


def commands(scene_dir: Path, out_dir: Path) -> dict[str, list[str]]:
    sp = stereopose_command()
    calib, pose = str(scene_dir / "calib.toml"), str(scene_dir / "pose")
    rec = [*sp, "reconstruct", "--calib", calib, "--pose", pose]
    py = sys.executable
    return {
        "stereopose reconstruct": [*rec, "--out", str(out_dir / "tracked.jsonl")],
        "stereopose reconstruct --no-tracking": [
            *rec,
            "--out",
            str(out_dir / "frames.jsonl"),
            "--no-tracking",
        ],
        "python benchmarks/yardstick.py": [
            py,
            str(HERE / "yardstick.py"),
            calib,
            pose,
            str(out_dir / "yardstick.jsonl"),
        ],
        "stereopose --help": [*sp, "--help"],
        'python -c "import stereopose.cli"': [py, "-c", "import stereopose.cli"],
        'python -c "import stereopose.pipeline"': [py, "-c", "import stereopose.pipeline"],
    }


def timed(cmd: list[str], env: dict[str, str]) -> tuple[float, str]:
    t = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return seconds, done.stdout


def summary_rows(stdout: str) -> dict[str, str]:
    """The rows of the `reconstruct` summary table (two columns, rich box characters)."""
    rows: dict[str, str] = {}
    key = None
    for line in stdout.splitlines():
        cells = [c.strip() for c in line.strip().strip("│").split("│")]
        if len(cells) != 2 or "─" in line:
            continue
        if cells[0]:
            key = cells[0]
            rows[key] = cells[1]
        elif key is not None:  # a value wrapped onto the next line
            rows[key] += " " + cells[1]
    return rows


def breakdown(total_s: float, import_s: float, rows: dict[str, str], frames: int) -> dict:
    """Where a `reconstruct` process's time goes, from the imports' own process and the
    command's summary (the frame loop's speed, the compiled loops' loading when reported)."""
    fps = re.search(r"([\d.]+) frames/s", rows.get("3D back end speed", ""))
    loaded = re.search(r"in ([\d.]+) s", rows.get("compiled loops loaded", ""))
    parts = {"start and imports": import_s}
    if loaded:
        parts["compiled loops loaded"] = float(loaded.group(1))
    if fps and float(fps.group(1)) > 0:
        parts["3D back end (frame loop)"] = frames / float(fps.group(1))
    parts["the rest (reading keypoints, outputs, summary)"] = total_s - sum(parts.values())
    return parts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):  # the child processes inherit the one core
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    env = {**os.environ, **THREADS, "COLUMNS": "200"}  # wide: summary rows on one line
    scene = simulate(CAMERAS, PEOPLE, args.frames, seed=args.seed, difficulty=DIFFICULTY)
    with tempfile.TemporaryDirectory() as tmp:
        scene_dir, out_dir = Path(tmp) / "scene", Path(tmp) / "out"
        write_scene(scene, scene_dir)
        out_dir.mkdir()
        cmds = commands(scene_dir, out_dir)
        seconds: dict[str, list[float]] = {name: [] for name in cmds}
        printed: dict[str, str] = {}
        for round_ in range(args.runs + 1):  # round 0 warms the caches (disk, numba)
            for name, cmd in cmds.items():
                s, printed[name] = timed(cmd, env)
                if round_:
                    seconds[name].append(s)
                print(f"round {round_}: {name}: {s:.3f} s", flush=True)
        outputs = {
            "stereopose reconstruct": out_dir / "tracked.jsonl",
            "stereopose reconstruct --no-tracking": out_dir / "frames.jsonl",
            "python benchmarks/yardstick.py": out_dir / "yardstick.jsonl",
        }
        accuracy = {name: evaluate_poses_file(p, scene).as_dict() for name, p in outputs.items()}
        tracked = load_people3d(outputs["stereopose reconstruct"], len(scene.rig))
        ids = evaluate_tracking(tracked, scene).as_dict()
        files = sum(1 for _ in (scene_dir / "pose").glob("*/*.json"))
    results = report(args, scene, files, seconds, accuracy, ids, printed)
    save("reconstruct_process", results, markdown(results))


def report(args, scene, files, seconds, accuracy, ids, printed) -> dict:
    timing = {
        name: {"best_s": min(v), "median_s": statistics.median(v), "runs_s": v}
        for name, v in seconds.items()
    }
    yard = timing["python benchmarks/yardstick.py"]
    rows = summary_rows(printed["stereopose reconstruct"])
    parts = breakdown(
        timing["stereopose reconstruct"]["best_s"],
        timing['python -c "import stereopose.pipeline"']["best_s"],
        rows,
        scene.num_frames,
    )
    speedup = {
        name: {
            "best": yard["best_s"] / timing[name]["best_s"],
            "median": yard["median_s"] / timing[name]["median_s"],
        }
        for name in ("stereopose reconstruct", "stereopose reconstruct --no-tracking")
    }
    return {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "scene": {
            "difficulty": DIFFICULTY,
            "cameras": CAMERAS,
            "people": PEOPLE,
            "frames": scene.num_frames,
            "seed": args.seed,
            "keypoint_files": files,
        },
        "runs": args.runs,
        "timing": timing,
        "speedup_vs_yardstick": speedup,
        "accuracy": accuracy,
        "tracking": ids,
        "breakdown_s": parts,
        "summary": {
            "tracked": rows,
            "no_tracking": summary_rows(printed["stereopose reconstruct --no-tracking"]),
        },
    }


def markdown(r: dict) -> list[str]:
    sc, t, frames = r["scene"], r["timing"], r["scene"]["frames"]
    sp = r["speedup_vs_yardstick"]
    md = [
        "# Whole processes: `stereopose reconstruct` against the pure-Python yardstick",
        "",
        f"{r['date']}, {r['machine']} (each command a process pinned to one core). A simulated "
        f"{sc['difficulty']} scene of {sc['cameras']} cameras x {sc['people']} people, "
        f"{frames} frames ({sc['keypoint_files']} keypoint files); wall clock from start to "
        f"exit, best and median of {r['runs']} runs after one warm-up round.",
        "",
        f"**Speed-up over the yardstick: {sp['stereopose reconstruct']['best']:.2f}x** "
        f"(best; median {sp['stereopose reconstruct']['median']:.2f}x) with tracking, "
        f"{sp['stereopose reconstruct --no-tracking']['best']:.2f}x "
        f"(median {sp['stereopose reconstruct --no-tracking']['median']:.2f}x) without.",
        "",
        "| command | best s | median s | frames/s (best) |",
        "|---|---:|---:|---:|",
    ]
    for name, v in t.items():
        fps = f"{frames / v['best_s']:.0f}" if name in r["accuracy"] else "-"
        md.append(f"| `{name}` | {v['best_s']:.3f} | {v['median_s']:.3f} | {fps} |")
    md += [
        "",
        "## Accuracy against the ground truth",
        "",
        "| command | MPJPE mm | PCP % | PCP seen % | recall % | false/frame |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, m in r["accuracy"].items():
        md.append(
            f"| `{name}` | {m['mpjpe_mm']:.1f} | {100 * m['pcp']:.2f} | "
            f"{100 * m['pcp_seen']:.2f} | {100 * m['person_recall']:.2f} | "
            f"{m['false_people_per_frame']:.3f} |"
        )
    ids = r["tracking"]
    md += [
        "",
        f"With tracking: {ids['ids']} ids for {ids['workers']} workers, {ids['id_switches']} id "
        f"switches, IDF1 {ids['idf1']:.3f}.",
        "",
        "## What `stereopose reconstruct` reports",
        "",
        "| | tracking on | --no-tracking |",
        "|---|---|---|",
    ]
    on, off = r["summary"]["tracked"], r["summary"]["no_tracking"]
    for key in on:
        if key != "cameras":
            md.append(f"| {key} | {on[key]} | {off.get(key, '-')} |")
    md += [
        "",
        "## Where the time of `stereopose reconstruct` goes (best run, tracking on)",
        "",
        "| part | s |",
        "|---|---:|",
    ]
    md += [f"| {k} | {v:.2f} |" for k, v in r["breakdown_s"].items()]
    md += [
        "",
        "Start and imports: the best `import stereopose.pipeline` process (Python, NumPy, "
        "SciPy, numba, the stages); the compiled loops' loading and the frame loop's speed "
        "are the command's own figures; the rest is the remainder of the run.",
        "",
        "The yardstick (`benchmarks/yardstick.py`) is the straightforward per-frame version in "
        "pure Python: OpenCV's iterative undistortion, greedy grouping by the mean symmetric "
        "epipolar distance, all-view DLT, no tracking; its frames/s above include its start, "
        "reading the files and writing the poses.",
    ]
    return md


if __name__ == "__main__":
    main()
