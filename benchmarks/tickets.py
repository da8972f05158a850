"""Tickets: each deviation found on simulated jobs, none on compliant ones, and the energized
alarms of a maintenance job with static zones against a ticket that isolates the bay.

Jobs (sim.jobs): compliant, swapped steps, a skipped step, a step from the wrong position,
the supervisor leaving, and a work ticket whose worker touches the isolated panel twice and
its live neighbour once. The 3D back end (association, triangulation, tracking:
pipeline.stage3d) runs on each job's simulated 2D detections; the fences, the incident book
and the ticket desk (pipeline.incidents.IncidentStep, as run and serve wire them) on its
tracked people. Truth: the deviations each job scripts. Step-completion latency: a step_done
against the same monitor on the true joints. Results: benchmarks/results/tickets.{md,json}.

usage: python benchmarks/tickets.py [--seeds 3] [--difficulties easy,mid]
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
import datetime
import time

from common import machine, save
from stereopose.alarms import IncidentBook
from stereopose.alarms.priority import AlarmSettings
from stereopose.config import Config
from stereopose.fence import FenceMonitor
from stereopose.pipeline.incidents import IncidentStep
from stereopose.pipeline.stage3d import Stage3D
from stereopose.pipeline.step_rules import step_chain
from stereopose.sim.behaviour_events import truth_frames
from stereopose.sim.jobs import VARIANTS, simulate_job
from stereopose.tickets import TicketDesk

DEVIATIONS = ("step_out_of_order", "step_wrong_position", "step_timeout", "supervisor_absent")


def tracked(scene):
    stage = Stage3D(scene.rig, dataclasses.replace(Config(), fps=scene.fps))
    return [stage.step(t, [d[n] for n in scene.rig.names]) for t, d in enumerate(scene.detections)]


def through_step(js, frames, ticket: bool) -> list:
    """Every event of the job's frames through the incident step (with the ticket or not)."""
    site, fps = js.site, js.scene.fps
    fences = FenceMonitor(site, fps)
    desk = None
    if ticket:
        desk = TicketDesk(site.zones)
        desk.add(js.ticket)
        desk.start(js.ticket.id, "benchmark")
    step = IncidentStep(
        IncidentBook(AlarmSettings.from_site(site)),
        step_chain(fences, tickets=desk),
        holding=fences,
        clock=lambda: 0.0,
    )
    out = []
    for p in frames:
        t = p.frame / fps
        events, _ = step.step(t, p.frame, p)
        out += events
    out += step.finish(t, p.frame)
    return out


def run_job(variant: str, seed: int, difficulty: str) -> dict:
    js = simulate_job(variant, seed=seed, difficulty=difficulty)
    t0 = time.perf_counter()
    frames = tracked(js.scene)
    events = through_step(js, frames, ticket=True)
    truth = through_step(js, truth_frames(js.scene), ticket=True)
    static = through_step(js, frames, ticket=False)
    found = [(e.type, e.step) for e in events if e.type in DEVIATIONS]
    true_done = {e.step: e.t for e in truth if e.type == "step_done"}
    latency = [
        e.t - true_done[e.step] for e in events if e.type == "step_done" and e.step in true_done
    ]
    iso = set(js.ticket.isolated)

    def alarms(evs, zones):  # energized incidents' alarm events at these zones
        return sum(1 for e in evs if e.kind == "energized" and e.incident and e.zone in zones)

    live = set(js.live_touches)
    return {
        "variant": variant,
        "seed": seed,
        "difficulty": difficulty,
        "true": [list(d) for d in js.deviations],
        "found": [list(d) for d in found],
        "steps_true": list(js.steps_done),
        "steps_found": [e.step for e in events if e.type == "step_done"],
        "latency_s": latency,
        "isolated_alarms_static": alarms(static, iso),
        "isolated_alarms_ticket": alarms(events, iso),
        "live_touches": len(live),
        "live_alarmed_ticket": len(
            {e.zone for e in events if e.kind == "energized" and e.incident} & live
        ),
        "seconds": time.perf_counter() - t0,
        "duration_s": js.duration_s,
    }


def score(runs: list[dict]) -> dict:
    per = {}
    for d in DEVIATIONS:
        tp = fp = fn = 0
        for r in runs:
            true = [tuple(x) for x in r["true"] if x[0] == d]
            found = [tuple(x) for x in r["found"] if x[0] == d]
            left = list(true)
            for f in found:
                if f in left:
                    left.remove(f)
                    tp += 1
                else:
                    fp += 1
            fn += len(left)
        per[d] = {
            "true": tp + fn,
            "found": tp + fp,
            "precision": tp / (tp + fp) if tp + fp else None,
            "recall": tp / (tp + fn) if tp + fn else None,
        }
    compliant = [r for r in runs if r["variant"] == "compliant"]
    lat = [x for r in runs for x in r["latency_s"]]
    steps_true = sum(len(r["steps_true"]) for r in runs)
    steps_found = sum(len(set(r["steps_found"]) & set(r["steps_true"])) for r in runs)
    work = [r for r in runs if r["variant"] == "neighbour_live"]
    return {
        "deviations": per,
        "false_deviations_per_compliant_job": (
            sum(len(r["found"]) for r in compliant) / len(compliant) if compliant else None
        ),
        "steps_completed": f"{steps_found}/{steps_true}",
        "step_latency_mean_s": sum(lat) / len(lat) if lat else None,
        "step_latency_max_s": max(lat) if lat else None,
        "isolated_alarms_static": sum(r["isolated_alarms_static"] for r in work),
        "isolated_alarms_ticket": sum(r["isolated_alarms_ticket"] for r in work),
        "live_touches": sum(r["live_touches"] for r in work),
        "live_touches_alarmed": sum(r["live_alarmed_ticket"] for r in work),
        "jobs": len(runs),
    }


def _f(x) -> str:
    return "-" if x is None else (f"{x:.3f}" if isinstance(x, float) else str(x))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--difficulties", default="easy,mid")
    args = ap.parse_args()
    results = {"machine": machine(), "date": datetime.date.today().isoformat(), "by": {}}
    md = [
        "# Tickets",
        "",
        f"Machine: {results['machine']}. Date: {results['date']}. `python benchmarks/tickets.py "
        f"--seeds {args.seeds} --difficulties {args.difficulties}`: each job of sim.jobs "
        "through the 3D back end (simulated detections), then the fences, the incident book "
        "and the ticket desk as run and serve wire them.",
        "",
    ]
    for diff in args.difficulties.split(","):
        runs = [run_job(v, s, diff) for v in VARIANTS for s in range(args.seeds)]
        sc = score(runs)
        results["by"][diff] = {"score": sc, "runs": runs}
        md += [
            f"## {diff} ({sc['jobs']} jobs)",
            "",
            "| deviation | true | found | precision | recall |",
            "|---|---|---|---|---|",
        ]
        for d, v in sc["deviations"].items():
            md.append(
                f"| {d} | {v['true']} | {v['found']} | {_f(v['precision'])} | {_f(v['recall'])} |"
            )
        md += [
            "",
            f"- false deviations per compliant job: {_f(sc['false_deviations_per_compliant_job'])}",
            f"- steps completed: {sc['steps_completed']}; step-completion latency against the "
            f"true joints: mean {_f(sc['step_latency_mean_s'])} s, "
            f"max {_f(sc['step_latency_max_s'])} s",
            f"- energized alarms on the isolated panel during the maintenance jobs: static zones "
            f"{sc['isolated_alarms_static']}, with the ticket {sc['isolated_alarms_ticket']}",
            f"- touches of the live neighbour alarmed with the ticket: "
            f"{sc['live_touches_alarmed']}/{sc['live_touches']}",
            "",
        ]
        print("\n".join(md[-14:]), flush=True)
    save("tickets", results, md)


if __name__ == "__main__":
    main()
