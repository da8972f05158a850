"""People matched across cameras without a calibration: the first half of the rig from
people (calibration.people).

1. The views: per sampled frame and camera, the detected people with enough confident joints,
   their joints undistorted to normalised coordinates with the camera's intrinsics.
2. Per pair of cameras, every pairing of a person of one view with a person of the other in
   the same frame gives candidate correspondences (joint to joint); one essential matrix
   (5-point RANSAC) finds the pairings that agree. Left/right swaps and ghosts are its
   outliers; a pairing is taken when most of its shared joints agree, one per person.
3. The pairings of every pair link detections into groups: one person at one frame, seen by
   several cameras (a camera twice in one group keeps its best linked detection).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from stereopose.geometry.camera import undistort_normalized
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.types import Camera, People2D

logger = logging.getLogger(__name__)

MIN_CONF = 0.3  # a joint this confident or more is used
MIN_JOINTS = 8  # a detection with fewer confident joints is left out
MIN_PAIRINGS = 20  # a camera pair with fewer agreeing pairings gives no relative pose
MAX_CANDIDATES = 60_000  # correspondences given to one RANSAC at most


@dataclass
class Views:
    """The sampled detections. cameras: names (intrinsics' order); frames (F,) frame numbers;
    det: list of (frame index, camera index, pixels (17, 3) as x, y, conf, normalised (17, 2)
    NaN where not confident)."""

    cameras: list[str]
    frames: np.ndarray
    det: list[tuple[int, int, np.ndarray, np.ndarray]]

    def of(self, f: int, c: int) -> list[int]:
        return self._index.get((f, c), [])

    def __post_init__(self) -> None:
        self._index: dict[tuple[int, int], list[int]] = {}
        for k, (f, c, _, _) in enumerate(self.det):
            self._index.setdefault((f, c), []).append(k)


def collect_views(
    frames: list[tuple[int, dict[str, People2D]]], cameras: dict[str, Camera]
) -> Views:
    """Views of the given frames (frame number, camera -> people)."""
    names = list(cameras)
    det = []
    for fi, (_, people) in enumerate(frames):
        for ci, name in enumerate(names):
            p2 = people.get(name)
            if p2 is None:
                continue
            for kp in p2.keypoints:
                good = kp[:, 2] >= MIN_CONF
                if good.sum() < MIN_JOINTS:
                    continue
                xy = undistort_normalized(np.where(good[:, None], kp[:, :2], 0.0), cameras[name])
                xy[~good] = np.nan
                det.append((fi, ci, kp.copy(), xy))
    return Views(names, np.array([n for n, _ in frames]), det)


@dataclass
class PairMatch:
    """Cameras a, b; R, t (b's frame from a's, unit baseline); the pairings taken (detection
    of a, detection of b); inliers: correspondences agreeing; angle_deg: the median angle
    between the two rays of an agreeing joint."""

    a: int
    b: int
    R: np.ndarray
    t: np.ndarray
    pairings: list[tuple[int, int]]
    inliers: int
    angle_deg: float


def _candidates(
    views: Views, a: int, b: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]]] | None:
    """Joint correspondences of every same-frame pairing: (xa (N, 2), xb (N, 2), pairing id
    (N,)), and the pairings (detection of a, detection of b)."""
    xa, xb, pid, pairs = [], [], [], []
    for f in range(len(views.frames)):
        for i in views.of(f, a):
            for j in views.of(f, b):
                ok = np.isfinite(views.det[i][3][:, 0]) & np.isfinite(views.det[j][3][:, 0])
                if ok.sum() < MIN_JOINTS - 2:
                    continue
                xa.append(views.det[i][3][ok])
                xb.append(views.det[j][3][ok])
                pid.append(np.full(int(ok.sum()), len(pairs)))
                pairs.append((i, j))
    if not pairs:
        return None
    xa, xb, pid = np.concatenate(xa), np.concatenate(xb), np.concatenate(pid)
    return xa, xb, pid, pairs


def match_pair(
    views: Views, a: int, b: int, thr_norm: float, rng: np.random.Generator
) -> PairMatch | None:
    """The relative pose of cameras a and b and the pairings that agree with it; None when they
    share too few people."""
    cand = _candidates(views, a, b)
    if cand is None:
        return None
    xa, xb, pid, pairs = cand
    sample = np.arange(len(xa))
    if len(sample) > MAX_CANDIDATES:
        sample = np.sort(rng.choice(len(xa), MAX_CANDIDATES, replace=False))
    E, _mask = cv2.findEssentialMat(
        xa[sample],
        xb[sample],
        np.eye(3),
        method=cv2.RANSAC,
        prob=0.99999,
        threshold=thr_norm,
        maxIters=20_000,
    )
    if E is None or E.shape != (3, 3):
        return None
    # every candidate judged against E (Sampson distance), then the pairings that agree
    inl = _sampson(E, xa, xb) < thr_norm
    counts = np.bincount(pid, weights=inl, minlength=len(pairs))
    sizes = np.bincount(pid, minlength=len(pairs))
    good = (counts >= MIN_JOINTS - 2) & (counts >= 0.6 * sizes)
    taken, used = [], set()
    for k in np.argsort(-counts):
        if not good[k]:
            break
        i, j = pairs[k]
        if i in used or j in used:
            continue
        used.update((i, j))
        taken.append(k)
    if len(taken) < MIN_PAIRINGS:
        return None
    sel = np.isin(pid, taken) & inl
    _n, R, t, _ = cv2.recoverPose(E, xa[sel], xb[sel], np.eye(3))
    angle = _ray_angles(xa[sel], xb[sel], R)
    return PairMatch(
        a, b, R, t.ravel(), [pairs[k] for k in taken], int(sel.sum()), float(np.median(angle))
    )


def _sampson(E: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    ha = np.column_stack([xa, np.ones(len(xa))])
    hb = np.column_stack([xb, np.ones(len(xb))])
    Ea, Etb = ha @ E.T, hb @ E
    num = np.einsum("ij,ij->i", hb, Ea) ** 2
    den = Ea[:, 0] ** 2 + Ea[:, 1] ** 2 + Etb[:, 0] ** 2 + Etb[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-18))


def _ray_angles(xa: np.ndarray, xb: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Degrees between the two rays of each correspondence (b's ray turned into a's frame)."""
    ra = np.column_stack([xa, np.ones(len(xa))])
    rb = np.column_stack([xb, np.ones(len(xb))]) @ R  # R^T rb
    c = np.einsum("ij,ij->i", ra, rb) / np.linalg.norm(ra, axis=1) / np.linalg.norm(rb, axis=1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def group_detections(views: Views, matches: list[PairMatch]) -> list[dict[int, int]]:
    """Groups (camera index -> detection) linked by the pairings of every pair; a camera seen
    twice in a group keeps the detection with most links."""
    parent = list(range(len(views.det)))

    def find(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    links = np.zeros(len(views.det), dtype=int)
    for m in matches:
        for i, j in m.pairings:
            parent[find(i)] = find(j)
            links[i] += 1
            links[j] += 1
    comps: dict[int, list[int]] = {}
    for k in np.flatnonzero(links):
        comps.setdefault(find(int(k)), []).append(int(k))
    groups = []
    for members in comps.values():
        g: dict[int, int] = {}
        for k in sorted(members, key=lambda k: -links[k]):
            g.setdefault(views.det[k][1], k)
        if len(g) >= 2:
            groups.append(g)
    return groups


def triangulate_groups(
    views: Views, groups: list[dict[int, int]], poses: np.ndarray, placed: np.ndarray
) -> np.ndarray:
    """(G, 17, 3) joints of every group (camera index -> detection) from its placed cameras,
    poses (C, 6) as rotation vector and translation (NaN: fewer than two views)."""
    X = np.full((len(groups), 17, 3), np.nan)
    for g, members in enumerate(groups):
        cams = [c for c in members if placed[c]]
        if len(cams) < 2:
            continue
        P = np.stack(
            [np.hstack([cv2.Rodrigues(poses[c, :3])[0], poses[c, 3:, None]]) for c in cams]
        )
        xy = np.stack([views.det[members[c]][3] for c in cams], axis=1)  # (17, V, 2)
        w = np.stack([views.det[members[c]][2][:, 2] for c in cams], axis=1)
        w = np.where(np.isfinite(xy[..., 0]), w, 0.0)
        X[g] = triangulate_dlt(np.nan_to_num(xy), P, w)
    return X
