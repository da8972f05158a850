"""Behaviour rules: precision, recall and latency per rule on simulated scenes of each
difficulty, and false alarms per worker-hour on routine work without falls.

Scenes (sim.behaviour): "falls" (each worker falls once among kneeling, squatting, sitting,
bending and reaching: stays down, gets up after more than down_s, or scrambles up at once),
"work" (jobs at energized panels alone or in pairs, from the work area or not) and "routine"
(the falls scenes' activities without falls). The 3D back end (association, triangulation,
tracking: pipeline.stage3d) runs on each scene's simulated 2D detections, the behaviour monitor
on its tracked people; the same monitor on the true joints gives the true events. A raised
alarm matches a true one of the same rule and worker raised within 2 s (sim.behaviour_events);
person_down is also scored against the scripted falls: found within 2 s after the scripted
landing + down_s. Results: benchmarks/results/behaviour.{md,json}.

usage: python benchmarks/behaviour.py [--seeds 3] [--hours 0.5] [--quick]
       [--part all|accuracy|two_cameras|false_alarms]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, before numpy loads

import argparse
import dataclasses
import datetime
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from stereopose.config import Config
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim.behaviour import simulate_behaviour
from stereopose.sim.behaviour_events import (
    evaluate_alarms,
    monitor_events,
    scene_rules,
    score_falls,
    truth_events,
)
from stereopose.sim.events import track_workers

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import RESULTS, machine, save

DIFFICULTIES = ("easy", "mid", "hard")
TYPES = ("person_down", "lone_worker", "work_position", "immobile", "overreach")
DOWN_S = 3.0
WITHIN_S = 2.0


def tracked(scene):
    stage = Stage3D(scene.rig, dataclasses.replace(Config(), fps=scene.fps))
    return [stage.step(t, [d[n] for n in scene.rig.names]) for t, d in enumerate(scene.detections)]


def run_scene(
    kind: str, seed: int, difficulty: str, duration_s: float, people: int, cameras=None
) -> dict:
    """One scene through the 3D back end and the monitor: its events, the truth's, the track ->
    worker map (ids offset by kind, seed and difficulty: one namespace across scenes) and the
    falls."""
    t0 = time.perf_counter()
    bs = simulate_behaviour(
        kind, seed, difficulty, duration_s, people, num_cameras=cameras, down_s=DOWN_S
    )
    t1 = time.perf_counter()
    preds = tracked(bs.scene)
    t2 = time.perf_counter()
    rules = scene_rules(bs)
    # alarms of a scene's last 2 s, true or raised, are left out: the other side has no time
    events = [e for e in monitor_events(bs, rules, preds) if e.t <= bs.duration_s - WITHIN_S]
    t3 = time.perf_counter()
    truth = [e for e in truth_events(bs, rules) if e.t <= bs.duration_s - WITHIN_S]
    workers = track_workers(preds, bs.scene)
    kinds = ("falls", "work", "routine")
    off = 1000 * (seed + 1) + 10_000_000 * DIFFICULTIES.index(difficulty)
    off += 0 if cameras is None else 100_000_000 * cameras
    off += 1_000_000 * kinds.index(kind)
    shift = lambda evs: [dataclasses.replace(e, person=e.person + off) for e in evs]  # noqa: E731
    falls = score_falls(bs, events, truth, workers, within_s=WITHIN_S)
    return {
        "events": shift(events),
        "truth": shift(truth),
        "workers": {k + off: v + off for k, v in workers.items()},
        "falls": falls,
        "worker_s": float(bs.scene.present.sum() / bs.scene.fps),
        "frames": bs.scene.num_frames,
        "sim_s": t1 - t0,
        "back_end_s": t2 - t1,
        "monitor_s": t3 - t2,
    }


def pooled(runs: list[dict]) -> tuple[list, list, dict]:
    events, truth, workers = [], [], {}
    for r in runs:
        events += r["events"]
        truth += r["truth"]
        workers.update(r["workers"])
    return events, truth, workers


def accuracy(
    difficulty: str, seeds: int, falls_s: float, work_s: float, cameras: int | None = None
) -> dict:
    """Falls and work scenes of a difficulty (with `cameras`: falls scenes only, seen by that
    many cameras)."""
    runs = [run_scene("falls", s, difficulty, falls_s, 4, cameras) for s in range(seeds)]
    if cameras is None:
        runs += [run_scene("work", s, difficulty, work_s, 3) for s in range(seeds)]
    events, truth, workers = pooled(runs)
    per_type = {t: evaluate_alarms(events, truth, workers, t).as_dict() for t in TYPES}
    falls = [f for r in runs for f in r["falls"]]
    due = [f for f in falls if f.due]
    delays = np.array([f.delay_s for f in due])
    found = np.isfinite(delays) & (delays <= WITHIN_S)
    # falls landing too late in their scene to be scored are neither due nor not due
    late = [f for f in falls if f.t_floor + DOWN_S + WITHIN_S > falls_s]
    not_due = [f for f in falls if not f.due and f not in late]
    row = {
        "difficulty": difficulty if cameras is None else f"{difficulty}, {cameras} cameras",
        "scenes": len(runs),
        "frames": sum(r["frames"] for r in runs),
        "worker_h": sum(r["worker_s"] for r in runs) / 3600.0,
        "rules": per_type,
        "falls": {
            "scripted": len(falls),
            "due": len(due),
            "found_in_time": int(found.sum()),
            "recall_in_time": float(found.mean()) if due else math.nan,
            "delay_mean_s": float(np.nanmean(delays)) if np.isfinite(delays).any() else math.nan,
            "delay_max_s": float(np.nanmax(delays)) if np.isfinite(delays).any() else math.nan,
            "missed": [f.as_dict() for f, ok in zip(due, found, strict=True) if not ok],
            "too_late": len(late),
            "not_due": len(not_due),
            "not_due_raised": sum(math.isfinite(f.delay_s) for f in not_due),
        },
        "time_s": {k: sum(r[k] for r in runs) for k in ("sim_s", "back_end_s", "monitor_s")},
    }
    pd, f = per_type["person_down"], row["falls"]
    print(
        f"{difficulty:5s} person_down: {f['found_in_time']}/{f['due']} falls in time "
        f"(delay mean {f['delay_mean_s']:.2f} s, max {f['delay_max_s']:.2f} s), precision "
        f"{pd['precision']:.3f}; "
        + "; ".join(
            f"{t} P {per_type[t]['precision']:.3f} R {per_type[t]['recall']:.3f} "
            f"({per_type[t]['matched']}/{per_type[t]['true']}, {per_type[t]['predicted']} raised)"
            for t in TYPES[1:]
        ),
        flush=True,
    )
    return row


def false_alarms(hours: float, scene_s: float, people: int) -> dict:
    """Routine scenes (no falls) of every difficulty in turn until `hours` worker-hours."""
    runs, seed = [], 0
    while sum(r["worker_s"] for r in runs) < hours * 3600.0:
        difficulty = DIFFICULTIES[seed % 3]
        runs.append(run_scene("routine", 500 + seed, difficulty, scene_s, people))
        seed += 1
    events, truth, workers = pooled(runs)
    worker_h = sum(r["worker_s"] for r in runs) / 3600.0
    counts = {t: len([e for e in events if e.type == t and not e.lost]) for t in TYPES}
    true = {t: len([e for e in truth if e.type == t and not e.lost]) for t in TYPES}
    per_type = {t: evaluate_alarms(events, truth, workers, t).as_dict() for t in TYPES}
    downs = [
        {"t": e.t, "person": e.person, "posture": e.posture, "speed_m_s": e.speed_m_s}
        for e in events
        if e.type == "person_down"
    ]
    row = {
        "scenes": len(runs),
        "worker_h": worker_h,
        "raised": counts,
        "true": true,
        "rules": per_type,
        "person_down_per_worker_h": counts["person_down"] / worker_h,
        "person_down_raised": downs,
        "time_s": {k: sum(r[k] for r in runs) for k in ("sim_s", "back_end_s", "monitor_s")},
    }
    print(
        f"routine: {worker_h:.2f} worker-hours, person_down raised {counts['person_down']} "
        f"({row['person_down_per_worker_h']:.2f} per worker-hour; true {true['person_down']}); "
        + ", ".join(f"{t} {counts[t]} raised / {true[t]} true" for t in TYPES[1:]),
        flush=True,
    )
    return row


def _f(x: float, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def write(results: dict) -> None:
    a = results["args"]
    acc, fa = results["accuracy"], results["false_alarms"]
    how = ["--quick"] if a["quick"] else []
    if not a["quick"]:
        how += [f"--seeds {a['seeds']}"] if "seeds" in a else []
        how += [f"--hours {a['hours']}"] if "hours" in a else []
    md = [
        "# Behaviour rules: precision, recall, latency and false alarms",
        "",
        f"Measured {results['date']} on {results['machine']} by `benchmarks/behaviour.py "
        f"{' '.join(how)}` (the parts may be measured apart: `--part accuracy`, "
        "`--part two_cameras`, `--part false_alarms`).",
        "",
        "The 3D back end (association, triangulation, tracking) runs on each simulated scene's "
        "2D detections, the behaviour monitor on its tracked people; the same monitor on the true "
        "joints gives the true events. Rules: person_down "
        f"(down_s {DOWN_S:g}), lone_worker (the panels, buddy_m 2, lone_s 10), work_position "
        "(one per panel: its work area, facing it, tolerance 30 degrees), immobile (30 s), "
        "overreach (2.1 m). A raised alarm matches a true one of the same rule and worker raised "
        "within 2 s; latency: raise time minus the true alarm's.",
    ]
    if acc:
        md += [
            "",
            f'Per difficulty {a["seeds"]} "falls" scenes of {a["falls_s"]:.0f} s with 4 workers '
            f'(each falls once) and {a["seeds"]} "work" scenes of {a["work_s"]:.0f} s with 3 '
            "workers, 25 fps (sim.behaviour; the cameras and detector errors of each difficulty "
            "as in docs/simulation.md).",
            "",
            "## Person down against the scripted falls",
            "",
            f"In time: raised at most {WITHIN_S:g} s after the scripted landing + down_s "
            "(target: 98 %). Due: falls the true joints raise person_down for (down longer than "
            "down_s); not due: workers who scramble up at once; falls landing less than down_s "
            "+ 2 s before their scene ends are neither (and alarms raised in a scene's last 2 s "
            "are left out of the per-rule figures). The rows with 2 cameras: the same falls "
            "scenes seen by 2 cameras of the rig only (`--part two_cameras`).",
            "",
            "| difficulty | falls | due | in time | recall in time | delay mean s | delay max s "
            "| not due | not due raised |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in acc + results.get("two_cameras", []):
            f = r["falls"]
            md.append(
                f"| {r['difficulty']} | {f['scripted']} | {f['due']} | {f['found_in_time']} | "
                f"{_f(f['recall_in_time'])} | {_f(f['delay_mean_s'], 2)} | "
                f"{_f(f['delay_max_s'], 2)} | {f['not_due']} | {f['not_due_raised']} |"
            )
        md += [
            "",
            "## Per rule against the true events",
            "",
            "| difficulty | rule | true | raised | matched | precision | recall "
            "| latency mean s | latency max s |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in acc + results.get("two_cameras", []):
            for t in TYPES if "cameras" not in r["difficulty"] else ("person_down",):
                m = r["rules"][t]
                md.append(
                    f"| {r['difficulty']} | {t} | {m['true']} | {m['predicted']} | "
                    f"{m['matched']} | {_f(m['precision'])} | {_f(m['recall'])} | "
                    f"{_f(m['latency_mean_s'], 2)} | {_f(m['latency_max_s'], 2)} |"
                )
    if fa:
        md += [
            "",
            "## False alarms on routine work",
            "",
            f'{fa["scenes"]} "routine" scenes of {a["routine_s"]:.0f} s with '
            f"{a['routine_people']} workers (easy, mid and hard in turn): walking, standing, "
            "reaching overhead, bending, stooping, squatting, kneeling on one or both knees, "
            f"sitting on a box or on the floor, no falls; {fa['worker_h']:.2f} worker-hours. "
            "Target: at most one person_down per 10 worker-hours.",
            "",
            "| rule | raised | true | matched | per worker-hour raised |",
            "|---|---:|---:|---:|---:|",
        ]
        for t in TYPES:
            md.append(
                f"| {t} | {fa['raised'][t]} | {fa['true'][t]} | {fa['rules'][t]['matched']} | "
                f"{fa['raised'][t] / fa['worker_h']:.2f} |"
            )
    if a["quick"]:  # a smoke test leaves the measured figures alone
        print("\n".join(md))
    else:
        save("behaviour", results, md)


def _load() -> dict:
    """The results written so far (another part's), or none."""
    try:
        return json.loads((RESULTS / "behaviour.json").read_text())
    except (OSError, ValueError):
        return {}


def _merged(results: dict, mine: tuple[str, ...], partial: bool) -> dict:
    """results with the other parts' figures and arguments as last written (by runs of those
    parts alone, which may go on beside this one)."""
    if not partial:
        return results
    keep = _load()
    out = {**results, "args": dict(results["args"])}
    for part in PARTS:
        if part not in mine and part in keep:
            out[part] = keep[part]
            out["args"].update({k: v for k, v in keep.get("args", {}).items() if k in _ARGS[part]})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="scenes of each kind per difficulty")
    ap.add_argument("--hours", type=float, default=0.5, help="worker-hours of routine scenes")
    ap.add_argument("--quick", action="store_true", help="a smoke test: short scenes, 1 seed")
    ap.add_argument(
        "--part",
        choices=("all", *PARTS),
        default="all",
        help="measure one part only; the other's figures already written are kept",
    )
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    quick = args.quick
    seeds = 1 if quick else args.seeds
    hours = 0.02 if quick else args.hours
    falls_s, work_s, routine_s, routine_people = (
        (30.0, 40.0, 30.0, 3) if quick else (40.0, 100.0, 120.0, 4)
    )
    results = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "args": {"quick": quick},
        "accuracy": [],
        "two_cameras": [],
        "false_alarms": None,
    }
    mine = PARTS if args.part == "all" else (args.part,)
    partial = args.part != "all" and not quick
    if "accuracy" in mine or "two_cameras" in mine:
        results["args"].update(seeds=seeds, falls_s=falls_s, work_s=work_s)
    if "false_alarms" in mine:
        results["args"].update(hours=hours, routine_s=routine_s, routine_people=routine_people)
    t0 = time.perf_counter()
    if "accuracy" in mine:
        for d in DIFFICULTIES:  # written after each difficulty: a long run shows as it goes
            results["accuracy"].append(accuracy(d, seeds, falls_s, work_s))
            if not quick:
                write(_merged(results, mine, partial))
    if "two_cameras" in mine:  # the falls seen by two cameras only
        results["two_cameras"] = [accuracy("mid", seeds, falls_s, work_s, cameras=2)]
    if "false_alarms" in mine:
        results["false_alarms"] = false_alarms(hours, routine_s, routine_people)
    print(f"{time.perf_counter() - t0:.0f} s in all")
    write(_merged(results, mine, partial))


PARTS = ("accuracy", "two_cameras", "false_alarms")
_ARGS = {
    "accuracy": ("seeds", "falls_s", "work_s"),
    "two_cameras": ("seeds", "falls_s"),
    "false_alarms": ("hours", "routine_s", "routine_people"),
}


if __name__ == "__main__":
    main()
