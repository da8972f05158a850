"""Where the default (robust) mode's PCP errors on hard simulated scenes come from.

Every limb of a counted worker (see stereopose.sim.metrics) that is not correct is put in one
class, by the worse of its two joints: the worker not reconstructed at all (by how many cameras
detected them); the joint not reconstructed (by how many cameras reported it); the joint
mirrored (nearer the true joint of the other side); or the joint wrong otherwise; the last two
by how many views it rests on. Results are written to benchmarks/results/pcp_errors.{md,json}.

usage: python benchmarks/pcp_errors.py [--frames 300] [--seeds 5]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, before numpy loads

import collections
import sys
from pathlib import Path

import numpy as np

from stereopose.config import Config, with_overrides
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim import simulate
from stereopose.sim.metrics import detectable, joint_views, match_people
from stereopose.skeleton import PCP_LIMBS, SWAP

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import save, start

LIMB_A = np.array([a for a, _ in PCP_LIMBS])
LIMB_B = np.array([b for _, b in PCP_LIMBS])


def classify(scene, predictions, counter: collections.Counter) -> None:
    counted, views = detectable(scene), joint_views(scene)
    for pred in predictions:
        t = int(pred.frame)
        idx = np.flatnonzero(scene.present[t])
        true = scene.truth[t, idx]
        pairs = {n: p for p, n in match_people(pred.joints, true)}
        for n, w in enumerate(idx):
            if not counted[t, w]:
                continue
            counter["limbs"] += len(PCP_LIMBS)
            if n not in pairs:
                seen = sum(int((o == w).any()) for o in scene.detection_truth[t].values())
                counter[f"worker not reconstructed, detected in {min(seen, 4)} cameras"] += 10
                continue
            p = pairs[n]
            err = np.linalg.norm(pred.joints[p] - true[n], axis=-1)
            mirror = np.linalg.norm(pred.joints[p] - true[n][SWAP], axis=-1)
            length = np.linalg.norm(true[n, LIMB_A] - true[n, LIMB_B], axis=-1)
            with np.errstate(invalid="ignore"):
                ok = 0.5 * (err[LIMB_A] + err[LIMB_B]) <= 0.5 * length
            for k in np.flatnonzero(~ok):
                a, b = LIMB_A[k], LIMB_B[k]
                j = b if not np.isfinite(err[b]) or err[b] > err[a] else a
                used = min(int(pred.views[p, j]), 4)
                if not np.isfinite(err[j]):
                    key = f"joint not reconstructed, reported by {min(views[t, w, j], 3)} cameras"
                elif mirror[j] < 0.5 * err[j]:
                    key = f"joint mirrored, from {used} views"
                else:
                    key = f"joint wrong, from {used} views"
                counter[key] += 1


def main() -> None:
    args, results = start(__doc__)
    counter: collections.Counter = collections.Counter()
    for seed in range(args.seeds):
        scene = simulate(num_frames=args.frames, seed=seed, difficulty="hard")
        rec = Stage3D(scene.rig, with_overrides(Config(), tracking={"memory": "recent"})).step
        names = scene.rig.names
        preds = [rec(t, [d[c] for c in names]) for t, d in enumerate(scene.detections)]
        classify(scene, preds, counter)
    limbs = counter.pop("limbs")
    rows = [
        {"class": k, "limbs": v, "percent": 100.0 * v / limbs}
        for k, v in sorted(counter.items(), key=lambda kv: -kv[1])
    ]
    results.update(limbs=limbs, classes=rows, wrong_percent=sum(r["percent"] for r in rows))
    for r in rows:
        print(f"{r['percent']:6.3f} %  {r['class']}")
    print(f"PCP {100 - results['wrong_percent']:.2f} %")
    md = [
        "# Where the PCP errors come from (robust mode, hard simulated scenes)",
        "",
        f"Measured {results['date']} on {results['machine']} by `benchmarks/pcp_errors.py "
        f"--frames {results['frames']} --seeds {results['seeds']}`.",
        "",
        f"{limbs} limbs counted; PCP {100 - results['wrong_percent']:.2f} %. Each wrong limb is "
        "classed by its worse joint; percentages are of all counted limbs.",
        "",
        "| class | limbs | % of limbs |",
        "|---|---:|---:|",
    ]
    md += [f"| {r['class']} | {r['limbs']} | {r['percent']:.3f} |" for r in rows]
    save("pcp_errors", results, md)


if __name__ == "__main__":
    main()
