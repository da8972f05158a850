"""Detections claimed by the poses expected in a frame (the prior from past frames).

Each camera's detections are matched to the expected poses reprojected into it; the detections
one pose claims in two cameras or more, checked against each other with the epipolar
constraint, form that person, and take that pose's left/right labels.
"""

from __future__ import annotations

import numpy as np

from stereopose.arrays import checked
from stereopose.association._kernels import claim_costs
from stereopose.association.affinity import Detections
from stereopose.association.assignment import linear_sum_assignment
from stereopose.geometry._kernels import project_all
from stereopose.skeleton import JOINT_PARTS, NUM_JOINTS, PART_OF_JOINT, SWAP

_JOINTS = np.arange(NUM_JOINTS)


def pose_costs(
    det: Detections, prior: np.ndarray, P: np.ndarray, min_conf: float, min_common_joints: int
) -> tuple[np.ndarray, np.ndarray]:
    """Cost of every detection against every expected pose, labels as detected or exchanged.

    prior: (T, 17, 3) poses (NaN where unknown); P: (C, 3, 4). Returns best (N, T), the mean
    distance of the detection's confident joints (conf >= min_conf) to the pose reprojected
    into its camera, divided by the detection's size, the lower of the two labelings (inf
    with fewer than min_common_joints joints), and per labeling (2, N, T, 2) the mean distance
    per body part (NaN where the part shares no joint).
    """
    prior = checked(prior, "prior", (None, NUM_JOINTS, 3))
    proj = project_all(prior, checked(P, "P", (None, 3, 4)))
    ok = det.conf >= min_conf  # (N, 17)
    return claim_costs(
        det.xy, ok, det.size, det.camera, proj, SWAP, JOINT_PARTS, int(min_common_joints)
    )


def claim(
    det: Detections,
    prior: np.ndarray,
    P: np.ndarray,
    min_conf: float,
    min_common_joints: int,
    max_cost: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Which expected pose each detection belongs to.

    det: one frame's detections; prior: (T, 17, 3) poses expected at this frame (NaN where
    unknown); P: (C, 3, 4) the rig's [R | t]. Returns (N,) the index of the pose each detection
    belongs to (-1: none), and (N, 2) whether its left/right labels are exchanged against that
    pose, per body part (upper body, legs).

    In each camera, detections and expected poses are matched one to one (Hungarian) on the
    mean distance of confident joints (conf >= min_conf, at least min_common_joints) to the
    reprojected pose, divided by the detection's size, up to max_cost; left/right exchanged
    poses count as the same pose.
    """
    best, part = pose_costs(det, prior, P, min_conf, min_common_joints)
    claims = np.full(len(det), -1, dtype=np.int64)
    pick = best.argmin(1)
    fine = best[np.arange(len(det)), pick] <= max_cost
    key = det.camera * best.shape[1] + pick
    # where no two detections of a camera pick the same pose, the row minima are optimal
    picks = np.bincount(key[fine], minlength=P.shape[0] * best.shape[1])
    dup = fine & (picks[key] > 1)
    claims[fine & ~dup] = pick[fine & ~dup]
    for cam in np.unique(det.camera[dup]) if dup.any() else ():
        rows = np.flatnonzero(det.camera == cam)
        sub = best[rows]
        r, k = linear_sum_assignment(np.where(np.isfinite(sub), sub, 1e9))
        claims[rows] = -1
        fine = sub[r, k] <= max_cost
        claims[rows[r[fine]]] = k[fine]
    t = np.maximum(claims, 0)
    n = np.arange(len(det))
    swap = part[1][n, t] < part[0][n, t]  # NaN (part not seen) compares False
    return claims, swap


def exchanged(det: Detections, swap: np.ndarray) -> Detections:
    """det with left/right labels exchanged where swap (N, 2) is true, per body part."""
    if not swap.any():
        return det
    rows = np.flatnonzero(swap.any(1))  # only the detections that change
    # per joint, the part whose swap moves it (the nose: a column that is never set)
    sw = swap[rows]
    flip = np.concatenate([sw, np.zeros((len(sw), 1), dtype=bool)], 1)[:, PART_OF_JOINT]
    idx = np.where(flip, SWAP[None, :], _JOINTS[None, :])
    n = rows[:, None]
    pixels, xy, conf = det.pixels.copy(), det.xy.copy(), det.conf.copy()
    pixels[rows], xy[rows], conf[rows] = det.pixels[n, idx], det.xy[n, idx], det.conf[n, idx]
    return Detections(det.camera, det.index, pixels, xy, conf, det.size, det.size_px)


def claimed_groups(claims: np.ndarray) -> tuple[list[np.ndarray], list[int]]:
    """Detections claimed by the same predicted pose in two cameras or more, as groups (each
    in detection order), by pose. A frame's few detections: plain Python is quickest."""
    members: dict[int, list[int]] = {}
    for n, t in enumerate(claims.tolist()):
        if t >= 0:
            members.setdefault(t, []).append(n)
    groups, seeds = [], []
    for t in sorted(members):
        if len(members[t]) >= 2:
            groups.append(np.array(members[t], dtype=np.int64))
            seeds.append(t)
    return groups, seeds


def pairs_within(groups: list[np.ndarray], free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Detection pairs (n < m) inside each group and among the free detections."""
    n: list[int] = []
    m: list[int] = []
    for g in [*groups, free]:  # a frame's few detections: plain Python
        members = g.tolist()
        for i, a in enumerate(members):
            n.extend([a] * (len(members) - i - 1))
            m.extend(members[i + 1 :])
    return np.array(n, dtype=np.int64), np.array(m, dtype=np.int64)


def check_groups(
    groups: list[np.ndarray], seeds: list[int], cost: np.ndarray, max_cost: float
) -> tuple[list[np.ndarray], list[int], np.ndarray]:
    """Remove from each seeded group the detections that disagree with the rest.

    A detection whose mean cost to the other members exceeds max_cost is dropped, worst
    first; a group left with fewer than two detections is dissolved. Returns the groups,
    their seeds and the dropped detections.
    """
    # all groups at once: (G, S) members padded with a detection of infinite cost
    N = cost.shape[0]
    S = max(g.size for g in groups)
    pad = np.full((len(groups), S), N)
    for i, g in enumerate(groups):
        pad[i, : g.size] = g
    full = np.full((N + 1, N + 1), np.inf)
    full[:N, :N] = cost
    c = full[pad[:, :, None], pad[:, None, :]]  # (G, S, S); the diagonal is inf (same camera)
    fin = np.isfinite(c)
    n = fin.sum(-1)
    mean = np.divide(np.where(fin, c, 0.0).sum(-1), n, out=np.full(n.shape, np.nan), where=n > 0)
    bad = ~(mean <= max_cost) & (pad < N)
    if not bad.any():
        return groups, seeds, np.zeros(0, dtype=np.int64)
    kept, kept_seeds, dropped = [], [], []
    for i, (g, t) in enumerate(zip(groups, seeds, strict=True)):
        if not bad[i].any():
            kept.append(g)
            kept_seeds.append(t)
            continue
        while g.size >= 2:
            c = cost[np.ix_(g, g)]
            fin = np.isfinite(c)
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = np.where(fin, c, 0.0).sum(1) / fin.sum(1)
            mean[~np.isfinite(mean)] = np.inf
            worst = int(np.argmax(mean))
            if mean[worst] <= max_cost:
                break
            dropped.append(g[worst])
            g = np.delete(g, worst)
        if g.size >= 2:
            kept.append(g)
            kept_seeds.append(t)
        else:
            dropped.extend(g.tolist())
    return kept, kept_seeds, np.array(dropped, dtype=np.int64)
