"""Zone events: precision, recall and latency on simulated scenes, and the cost of 20 zones.

Each simulated scene gets rectangular zones over the floor where the workers walk; the same
rules run on the ground truth give the true events. The tracked people of the scene's 2D
detections give the run's events; enter/exit events are matched to the true ones (same worker,
zone and type, onsets within 0.5 s). Latency: raise time minus the true onset (the first frame
truly inside, or truly outside for an exit). Cost: time per frame of the fence rules with 20
zones against the whole 3D back end's, on a 6-camera x 5-person scene. Results are written to
benchmarks/results/fences.{md,json}.

usage: python benchmarks/fences.py [--frames 300] [--seeds 5]
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

from stereopose.config import Config
from stereopose.fence import FenceMonitor
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim import simulate
from stereopose.sim.events import evaluate_events, make_zones, track_workers, truth_events

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import save, start


def tracked(scene):
    tracker = Stage3D(scene.rig, dataclasses.replace(Config(), fps=scene.fps))
    return [
        tracker.step(t, [d[name] for name in scene.rig.names])
        for t, d in enumerate(scene.detections)
    ]


def accuracy(frames: int, seeds: int) -> list[dict]:
    rows = []
    for difficulty in ("easy", "mid", "hard"):
        events, truth, worker_maps = [], [], []
        counts = {"enter": 0, "exit": 0, "approach": 0}
        for seed in range(seeds):
            scene = simulate(num_frames=frames, seed=seed, difficulty=difficulty)
            site = make_zones(scene, np.random.default_rng([seed, 7]))
            preds = tracked(scene)
            mon = FenceMonitor(site, scene.fps)
            evs = [e for p in preds for e in mon.update(p)]
            # one namespace of people across scenes: (seed, id)
            off = 1000 * seed
            evs = [dataclasses.replace(e, person=e.person + off) for e in evs]
            tru = [dataclasses.replace(e, person=e.person + off) for e in truth_events(scene, site)]
            workers = {k + off: v + off for k, v in track_workers(preds, scene).items()}
            events += evs
            truth += tru
            worker_maps.append(workers)
            for e in tru:
                if e.type in counts:
                    counts[e.type] += 1
        workers = {k: v for m in worker_maps for k, v in m.items()}
        m = evaluate_events(events, truth, workers)
        approach = evaluate_events(events, truth, workers, types=("approach",))
        row = {
            "difficulty": difficulty,
            "true_events": counts,
            **m.as_dict(),
            "approach": approach.as_dict(),
        }
        rows.append(row)
        print(
            f"{difficulty:5s} enter/exit: precision {m.precision:.3f} recall {m.recall:.3f} "
            f"({m.matched} of {m.true} true, {m.predicted} raised); latency mean "
            f"{m.latency_mean_s:.2f} s, max {m.latency_max_s:.2f} s, within 0.5 s "
            f"{100 * m.within_window:.1f}%; approach precision {approach.precision:.3f} "
            f"recall {approach.recall:.3f}",
            flush=True,
        )
    return rows


def cost(frames: int, zones: int = 20, runs: int = 9) -> dict:
    scene = simulate(num_cameras=6, num_people=5, num_frames=frames, seed=7, difficulty="mid")
    site = make_zones(scene, np.random.default_rng(11), count=zones)
    back, fence, events = [], [], 0
    for _ in range(runs):
        tracker = Stage3D(scene.rig, dataclasses.replace(Config(), fps=scene.fps))
        data = [[d[name] for name in scene.rig.names] for d in scene.detections]
        t0 = time.perf_counter()
        preds = [tracker.step(t, f) for t, f in enumerate(data)]
        back.append((time.perf_counter() - t0) / frames)
        mon = FenceMonitor(site, scene.fps)
        t0 = time.perf_counter()
        for p in preds:
            events += len(mon.update(p))
        fence.append((time.perf_counter() - t0) / frames)
    row = {
        "zones": zones,
        "cameras": 6,
        "people": 5,
        "back_end_ms": 1000 * min(back),
        "fences_ms": 1000 * min(fence),
        "back_end_median_ms": 1000 * float(np.median(back)),
        "fences_median_ms": 1000 * float(np.median(fence)),
        "events_per_run": events // runs,
    }
    row["added"] = row["fences_ms"] / row["back_end_ms"]
    row["added_median"] = row["fences_median_ms"] / row["back_end_median_ms"]
    print(
        f"cost: {zones} zones {row['fences_ms']:.3f} ms/frame against the back end's "
        f"{row['back_end_ms']:.3f} ms (+{100 * row['added']:.1f}%, median "
        f"+{100 * row['added_median']:.1f}%)",
        flush=True,
    )
    return row


def write(results: dict) -> None:
    c = results["cost"]
    md = [
        "# Zone events: accuracy, latency and cost",
        "",
        f"Measured {results['date']} on {results['machine']} by `benchmarks/fences.py "
        f"--frames {results['frames']} --seeds {results['seeds']}`.",
        "",
        "## Simulated substations",
        "",
        f"{results['seeds']} scenes of {results['frames']} frames (25 fps) per difficulty, each "
        "with 4 rectangular zones (1-3 m wide, 0-2.5 m high; energized ones with a 0.5 m "
        "approach margin) over the floor where the workers walk. True events: the same rules on "
        "the ground truth. A raised enter/exit event matches a true one of the same worker "
        "(the one its track follows), zone and type with onsets within 0.5 s. Latency: raise "
        "time minus the true onset (first frame truly inside, or truly outside for an exit); "
        "it includes the debounce (enter 0.08 s, exit 0.2 s).",
        "",
        "| difficulty | true enter/exit | raised | precision | recall | latency mean s "
        "| latency max s | within 0.5 s | approach precision | approach recall |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results["accuracy"]:
        a = r["approach"]
        md.append(
            f"| {r['difficulty']} | {r['true']} | {r['predicted']} | {r['precision']:.3f} | "
            f"{r['recall']:.3f} | {r['latency_mean_s']:.2f} | {r['latency_max_s']:.2f} | "
            f"{100 * r['within_window']:.1f}% | {a['precision']:.3f} | {a['recall']:.3f} |"
        )
    md += [
        "",
        "## Cost of 20 zones (one core)",
        "",
        f"The fence rules over the tracked people of a mid scene with 6 cameras and 5 people, "
        f"{results['frames']} frames, 9 runs (best and median), against the whole 3D back end "
        "(association + triangulation + tracking) in the same runs.",
        "",
        "| zones | back end ms/frame | fences ms/frame | added | added (medians) |",
        "|---:|---:|---:|---:|---:|",
        f"| {c['zones']} | {c['back_end_ms']:.3f} | {c['fences_ms']:.3f} | "
        f"{100 * c['added']:.1f}% | {100 * c['added_median']:.1f}% |",
    ]
    save("fences", results, md)


def main() -> None:
    args, head = start(__doc__)
    results = {
        **head,
        "cost": cost(args.frames),
        "accuracy": accuracy(args.frames, args.seeds),
    }
    write(results)


if __name__ == "__main__":
    main()
