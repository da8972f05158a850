"""Accuracy of reconstructed 3D people against a simulated scene's ground truth."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from stereopose.association.assignment import linear_sum_assignment
from stereopose.sim.scene import Scene
from stereopose.skeleton import NUM_JOINTS, PCP_LIMBS
from stereopose.types import People3D

_LIMB_A = np.array([a for a, _ in PCP_LIMBS])
_LIMB_B = np.array([b for _, b in PCP_LIMBS])


@dataclass(frozen=True)
class Metrics:
    """Scores over the evaluated frames (NaN where nothing was there to score).

    mpjpe_mm: mean over matched people of their mean joint error over reconstructed joints (mm).
    pcp: fraction of correct PCP limbs over all counted true people x 10 limbs.
    person_recall: matched / counted true people.
    false_people_per_frame: predictions matching no present worker, per frame.
    joint_coverage: fraction of the joints of matched people that were reconstructed.
    pcp_seen: PCP over the limbs whose two joints the detector reported in >= 2 cameras, the
        limbs any triangulation can reach (an unmatched person's such limbs count as wrong).
    """

    mpjpe_mm: float
    pcp: float
    pcp_seen: float
    person_recall: float
    false_people_per_frame: float
    joint_coverage: float
    frames: int

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def _mean_distance(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """(P, N) mean distance over the joints present in both; inf where none are."""
    d = np.linalg.norm(pred[:, None] - true[None], axis=-1)  # (P, N, 17)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmean(d, axis=-1)
    return np.where(np.isfinite(m), m, np.inf)


def match_people(
    pred_joints: np.ndarray, true_joints: np.ndarray, max_dist_m: float = 0.5
) -> list[tuple[int, int]]:
    """Pairs (pred index, true index), one-to-one, minimising the mean joint distance.

    pred_joints: (P, 17, 3), true_joints: (N, 17, 3) metres, NaN where missing. The distance of
    a pair is the mean over joints present in both; pairs farther than `max_dist_m` stay
    unmatched.
    """
    pred = np.asarray(pred_joints, dtype=np.float64).reshape(-1, NUM_JOINTS, 3)
    true = np.asarray(true_joints, dtype=np.float64).reshape(-1, NUM_JOINTS, 3)
    if pred.shape[0] == 0 or true.shape[0] == 0:
        return []
    cost = _mean_distance(pred, true)
    big = 1e6
    rows, cols = linear_sum_assignment(np.minimum(cost, big))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] <= max_dist_m]


def detectable(scene: Scene, min_views: int = 2) -> np.ndarray:
    """(T, N) bool: worker present and detected (the simulated detector reported them) in
    >= min_views cameras: a person the 2D input holds in fewer views cannot be triangulated."""
    views = np.zeros(scene.present.shape, dtype=np.int64)
    for t, per_camera in enumerate(scene.detection_truth):
        for owners in per_camera.values():
            views[t, np.unique(owners[owners >= 0])] += 1
    return scene.present & (views >= min_views)


def joint_views(scene: Scene) -> np.ndarray:
    """(T, N, 17) number of cameras whose detections report each joint of each worker."""
    views = np.zeros((*scene.present.shape, NUM_JOINTS), dtype=np.int64)
    for t, per_camera in enumerate(scene.detection_truth):
        for name, owners in per_camera.items():
            reported = scene.detections[t][name].keypoints[..., 2] > 0
            for k in np.flatnonzero(owners >= 0):
                views[t, owners[k]] += reported[k]
    return views


def evaluate(predictions: Sequence[People3D], scene: Scene, min_views: int = 2) -> Metrics:
    """Score `predictions` (one People3D per evaluated frame, `frame` indexing the scene).

    Only workers that are present and detectable (see `detectable`) are counted; predictions
    matching a present but undetectable worker are neither counted nor false.
    """
    counted_mask = detectable(scene, min_views)
    seen = joint_views(scene) >= min_views  # (T, N, 17)
    errors_m: list[float] = []
    limbs_ok = counted = matched = false = reconstructed = 0
    seen_total = seen_ok = 0
    for pred in predictions:
        t = int(pred.frame)
        if not 0 <= t < scene.num_frames:
            raise ValueError(f"prediction frame {t} outside the scene's 0..{scene.num_frames - 1}")
        idx = np.flatnonzero(scene.present[t])
        true = scene.truth[t, idx]
        pairs = match_people(pred.joints, true)
        false += len(pred) - len(pairs)
        is_counted = counted_mask[t, idx]
        counted += int(is_counted.sum())
        limb_seen = seen[t, idx][:, _LIMB_A] & seen[t, idx][:, _LIMB_B]  # (n, 10)
        seen_total += int(limb_seen[is_counted].sum())
        for p, n in pairs:
            if not is_counted[n]:
                continue
            matched += 1
            err = np.linalg.norm(pred.joints[p] - true[n], axis=-1)  # (17,)
            have = np.isfinite(err)
            reconstructed += int(have.sum())
            if have.any():
                errors_m.append(float(err[have].mean()))
            length = np.linalg.norm(true[n, _LIMB_A] - true[n, _LIMB_B], axis=-1)
            with np.errstate(invalid="ignore"):
                ok = 0.5 * (err[_LIMB_A] + err[_LIMB_B]) <= 0.5 * length
            limbs_ok += int(ok.sum())
            seen_ok += int((ok & limb_seen[n]).sum())
    nan = float("nan")
    frames = len(predictions)
    return Metrics(
        mpjpe_mm=1000.0 * float(np.mean(errors_m)) if errors_m else nan,
        pcp=limbs_ok / (counted * len(PCP_LIMBS)) if counted else nan,
        pcp_seen=seen_ok / seen_total if seen_total else nan,
        person_recall=matched / counted if counted else nan,
        false_people_per_frame=false / frames if frames else nan,
        joint_coverage=reconstructed / (matched * NUM_JOINTS) if matched else nan,
        frames=frames,
    )


@dataclass(frozen=True)
class TrackingMetrics:
    """Identity scores of tracked predictions (CLEAR MOT and IDF1 conventions).

    id_switches: times a worker's matched id differs from the id matched before (gaps
        ignored). fragmented: workers seen under more than one id.
    idf1: 2 IDTP / (true person-frames + predicted person-frames), with one id per worker
        chosen to maximise the frames they share (IDTP).
    mota: 1 - (misses + false people + id switches) / true person-frames.
    ghost_ids: ids matched to a worker in fewer than half of their frames.
    Only detectable workers (see `detectable`) count as true person-frames; predictions on a
    present worker who is not detectable are neither true nor false.
    """

    id_switches: int
    fragmented: int
    idf1: float
    mota: float
    ids: int
    workers: int
    ghost_ids: int

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def evaluate_tracking(
    predictions: Sequence[People3D], scene: Scene, min_views: int = 2
) -> TrackingMetrics:
    counted_mask = detectable(scene, min_views)
    last: dict[int, int] = {}
    share: dict[tuple[int, int], int] = {}
    frames_of: dict[int, int] = {}
    matched_of: dict[int, int] = {}
    ids_of: dict[int, set[int]] = {}
    switches = misses = false = gt = pred_total = 0
    for pred in predictions:
        t = int(pred.frame)
        idx = np.flatnonzero(scene.present[t])
        pairs = match_people(pred.joints, scene.truth[t, idx])
        counted = counted_mask[t, idx]
        gt += int(counted.sum())
        hit = np.zeros(idx.size, dtype=bool)
        matched_pred = set()
        for p, n in pairs:
            i, w = int(pred.ids[p]), int(idx[n])
            matched_pred.add(p)
            matched_of[i] = matched_of.get(i, 0) + 1
            if not counted[n]:
                continue
            hit[n] = True
            share[(w, i)] = share.get((w, i), 0) + 1
            ids_of.setdefault(w, set()).add(i)
            if w in last and last[w] != i:
                switches += 1
            last[w] = i
        misses += int((counted & ~hit).sum())
        for p in range(len(pred)):
            i = int(pred.ids[p])
            frames_of[i] = frames_of.get(i, 0) + 1
            if p not in matched_pred:
                false += 1
        pred_total += len(pred) - sum(1 for p, n in pairs if not counted[n])
    workers = sorted({w for w, _ in share})
    ids = sorted(frames_of)
    idtp = 0
    if share:
        m = np.zeros((len(workers), len(ids)))
        for (w, i), k in share.items():
            m[workers.index(w), ids.index(i)] = k
        r, c = linear_sum_assignment(-m)
        idtp = int(m[r, c].sum())
    denom = gt + pred_total
    return TrackingMetrics(
        id_switches=switches,
        fragmented=sum(len(v) > 1 for v in ids_of.values()),
        idf1=2.0 * idtp / denom if denom else float("nan"),
        mota=1.0 - (misses + false + switches) / gt if gt else float("nan"),
        ids=len(ids),
        workers=int(counted_mask.any(0).sum()),
        ghost_ids=sum(matched_of.get(i, 0) < 0.5 * frames_of[i] for i in ids),
    )
