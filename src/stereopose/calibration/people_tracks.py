"""People matched across cameras by their tracks: the rig from people where single frames
do not tell who is who (a few people close together, moving little, seen by cameras facing
each other).

calibration.people_match pairs two cameras' people frame by frame, which needs many pairings
that agree with one essential matrix within a few pixels. With the detector's noise near 10 px
and people who stay where they are, few do. Here each camera's detections are first linked in
time into tracks (a person stays near where he was one frame before), and whole tracks are
paired, so that a pairing of two cameras' tracks pools every frame they share:

1. Per camera pair, every one-to-one assignment of their tracks (at most MAX_TRACKS each)
   gives one essential matrix (MAGSAC) on every joint of every frame the paired tracks share;
   its agreeing share says how well the assignment fits.
2. Each pair whose best assignment stands clear of its second starts a reconstruction: its
   tracks triangulated into persons, then every other camera placed by PnP (RANSAC) on them,
   with the assignment of its tracks to the persons that most joints agree with, and the
   persons triangulated again.
3. The start whose reconstruction agrees best (the median reprojection error over every
   placed camera) gives the groups (one person at one frame, seen by several cameras) for
   calibration.people's placement and bundle adjustment.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterator

import cv2
import numpy as np

from stereopose.calibration.people_match import (
    MIN_CONF,
    PairMatch,
    Views,
    _ray_angles,
    _sampson,
    triangulate_groups,
)
from stereopose.calibration.poses import robust_pnp

logger = logging.getLogger(__name__)

MAX_TRACKS = 4  # a camera's longest tracks paired (4 x 4: 24 assignments)
MIN_TRACK = 0.1  # a track shorter than this share of the frames is left out
LINK = 0.5  # a detection links to a track within this share of its person's height
MARGIN = 1.15  # a start's best assignment agrees with this many times its second's joints
STARTS = 4  # reconstructions tried, from the pairs most sure of their assignment
MIN_SHARED = 200  # joints two cameras' assigned tracks share, at least


def _centre_size(kp: np.ndarray) -> tuple[np.ndarray, float]:
    ok = kp[:, 2] >= MIN_CONF
    xy = kp[ok, :2]
    return np.median(xy, axis=0), float(np.ptp(xy[:, 1])) if len(xy) > 1 else 0.0


def camera_tracks(views: Views, c: int) -> list[dict[int, int]]:
    """Camera c's tracks (frame index -> detection), longest first: each detection linked to
    the track whose last detection (at most 3 frames back) is nearest, within LINK of its
    person's height; greedy, nearest first."""
    tracks: list[dict[int, int]] = []
    for f in range(len(views.frames)):
        ids = views.of(f, c)
        if not ids:
            continue
        here = [_centre_size(views.det[k][2]) for k in ids]
        open_ = [t for t in tracks if f - max(t) <= 3]
        cost = []
        for ti, t in enumerate(open_):
            centre, size = _centre_size(views.det[t[max(t)]][2])
            for q, (cq, sq) in enumerate(here):
                d = float(np.linalg.norm(cq - centre))
                if d <= LINK * max(size, sq, 1.0):
                    cost.append((d, ti, q))
        used_t, used_q = set(), set()
        for _d, ti, q in sorted(cost):
            if ti in used_t or q in used_q:
                continue
            used_t.add(ti)
            used_q.add(q)
            open_[ti][f] = ids[q]
        tracks += [{f: ids[q]} for q in range(len(ids)) if q not in used_q]
    keep = [t for t in tracks if len(t) >= max(3, MIN_TRACK * len(views.frames))]
    return sorted(keep, key=len, reverse=True)[:MAX_TRACKS]


def _shared(views: Views, ta: dict[int, int], tb: dict[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Normalised joints (xa, xb) both tracks' detections are sure of, at their shared frames."""
    xa, xb = [], []
    for f in ta.keys() & tb.keys():
        p, q = views.det[ta[f]][3], views.det[tb[f]][3]
        ok = np.isfinite(p[:, 0]) & np.isfinite(q[:, 0])
        xa.append(p[ok])
        xb.append(q[ok])
    if not xa:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.concatenate(xa), np.concatenate(xb)


def _assignments(n: int, m: int) -> Iterator[list[tuple[int, int]]]:
    """Every one-to-one assignment of n tracks to m (as many pairs as the fewer has)."""
    if n <= m:
        for p in itertools.permutations(range(m), n):
            yield list(zip(range(n), p, strict=True))
    else:
        for p in itertools.permutations(range(n), m):
            yield list(zip(p, range(m), strict=True))


def _pair(
    views: Views, T: dict[int, list[dict[int, int]]], a: int, b: int, thr: float
) -> tuple[int, int, np.ndarray, np.ndarray, list[tuple[int, int]], np.ndarray, np.ndarray] | None:
    """(agreeing joints, R, t, pairs, xa, xb) of the best assignment of a's and b's tracks, and
    the second best's agreeing joints; None when none shares enough."""
    found = []
    for pairs in _assignments(len(T[a]), len(T[b])):
        got = [_shared(views, T[a][i], T[b][j]) for i, j in pairs]
        xa = np.concatenate([g[0] for g in got])
        xb = np.concatenate([g[1] for g in got])
        if len(xa) < MIN_SHARED:
            continue
        E, _ = cv2.findEssentialMat(
            xa, xb, np.eye(3), method=cv2.USAC_MAGSAC, prob=0.999, threshold=thr, maxIters=5000
        )
        if E is None or E.shape != (3, 3):
            continue
        inl = _sampson(E, xa, xb) < thr
        found.append((int(inl.sum()), E, pairs, xa[inl], xb[inl]))
    if not found:
        return None
    found.sort(key=lambda x: -x[0])
    n, E, pairs, xa, xb = found[0]
    second = found[1][0] if len(found) > 1 else 0
    _, R, t, _ = cv2.recoverPose(E, xa, xb, np.eye(3))
    return n, second, R, t.ravel(), pairs, xa, xb


def _groups(
    views: Views, T: dict[int, list[dict[int, int]]], persons: list[dict[int, int]]
) -> tuple[list[dict[int, int]], list[tuple[int, int]]]:
    """Each person's detections at each frame seen by two cameras or more (camera ->
    detection), and the (person, frame) of each."""
    groups, where = [], []
    for p, person in enumerate(persons):
        for f in range(len(views.frames)):
            g = {c: T[c][ti][f] for c, ti in person.items() if f in T[c][ti]}
            if len(g) >= 2:
                groups.append(g)
                where.append((p, f))
    return groups, where


def _triangulate_persons(
    views: Views,
    T: dict[int, list[dict[int, int]]],
    persons: list[dict[int, int]],
    poses: np.ndarray,
    placed: set[int],
) -> np.ndarray:
    """(P, F, 17, 3) joints of every person at every frame from its placed cameras' tracks."""
    X = np.full((len(persons), len(views.frames), 17, 3), np.nan)
    groups, where = _groups(views, T, persons)
    if groups:
        mask = np.isin(np.arange(len(poses)), list(placed))
        for (p, f), x in zip(where, triangulate_groups(views, groups, poses, mask), strict=True):
            X[p, f] = x
    return X


def _place_camera(
    views: Views, T: dict[int, list[dict[int, int]]], c: int, X: np.ndarray, thr: float
) -> tuple[int, np.ndarray, dict[int, int]] | None:
    """Camera c's best (inliers, pose (6,), {person: its track}) by PnP on the persons X."""
    best = None
    for pairs in _assignments(len(T[c]), len(X)):
        obj, img = [], []
        for ti, p in pairs:
            for f, k in T[c][ti].items():
                xy = views.det[k][3]
                ok = np.isfinite(X[p, f, :, 0]) & np.isfinite(xy[:, 0])
                obj.append(X[p, f, ok])
                img.append(xy[ok])
        if not obj or sum(len(o) for o in obj) < MIN_SHARED:
            continue
        obj, img = np.concatenate(obj), np.concatenate(img)
        got = robust_pnp(obj, img, np.eye(3), None, thr, 2000)
        if got is None:
            continue
        r, t, keep = got
        if best is None or len(keep) > best[0]:
            best = (len(keep), np.concatenate([r.ravel(), t.ravel()]), dict(pairs))
    return best


def _reconstruct(
    views: Views,
    T: dict[int, list[dict[int, int]]],
    start: tuple[int, int, np.ndarray, np.ndarray, list[tuple[int, int]]],
    thr: float,
) -> tuple[float, np.ndarray, set[int], list[dict[int, int]]]:
    """From one start: (median error in normalised units, poses, placed, persons)."""
    a, b, R, t, pairs = start
    C = len(views.cameras)
    poses = np.zeros((C, 6))
    poses[b] = np.concatenate([cv2.Rodrigues(R)[0].ravel(), t])
    placed = {a, b}
    persons = [{a: i, b: j} for i, j in pairs]
    X = _triangulate_persons(views, T, persons, poses, placed)
    while len(placed) < C:
        tries = {
            c: r
            for c in range(C)
            if c not in placed and (r := _place_camera(views, T, c, X, 2 * thr)) is not None
        }
        if not tries:
            break
        c = max(tries, key=lambda c: tries[c][0])
        _, poses[c], own = tries[c]
        for ti, p in own.items():
            persons[p][c] = ti
        placed.add(c)
        X = _triangulate_persons(views, T, persons, poses, placed)
    errs = []
    for p, person in enumerate(persons):
        for c, ti in person.items():
            if c not in placed:
                continue
            Rc = cv2.Rodrigues(poses[c, :3])[0]
            for f, k in T[c][ti].items():
                ok = np.isfinite(X[p, f, :, 0]) & np.isfinite(views.det[k][3][:, 0])
                if not ok.any():
                    continue
                Y = X[p, f, ok] @ Rc.T + poses[c, 3:]
                uv = Y[:, :2] / np.maximum(Y[:, 2:], 1e-9)
                errs.append(np.linalg.norm(uv - views.det[k][3][ok], axis=1))
    err = float(np.median(np.concatenate(errs))) if errs else float("inf")
    return err, poses, placed, persons


def match_tracks(views: Views, thr: float) -> tuple[PairMatch, list[dict[int, int]]] | None:
    """The first pair and the groups (camera -> detection, per person and frame) from the
    cameras' tracks (see the module); None when no start places every camera."""
    C = len(views.cameras)
    T = {c: camera_tracks(views, c) for c in range(C)}
    starts = []
    for a, b in itertools.combinations(range(C), 2):
        if not T[a] or not T[b]:
            continue
        got = _pair(views, T, a, b, thr)
        if got is None:
            continue
        n, second, R, t, pairs, xa, xb = got
        if n >= MARGIN * second:
            angle = float(np.median(_ray_angles(xa, xb, R)))
            starts.append((n / max(second, 1), n, angle, (a, b, R, t, pairs)))
    starts.sort(key=lambda s: -s[0])
    best = None
    for _ratio, n, angle, start in starts[:STARTS]:
        err, _poses, placed, persons = _reconstruct(views, T, start, thr)
        logger.info(
            "people by tracks: start %s-%s, %d cameras placed, median error %.4f",
            views.cameras[start[0]],
            views.cameras[start[1]],
            len(placed),
            err,
        )
        if len(placed) == C and (best is None or err < best[0]):
            best = (err, start, n, angle, persons)
    if best is None:
        return None
    _err, (a, b, R, t, pairs), n, angle, persons = best
    groups, _ = _groups(views, T, persons)
    return PairMatch(a, b, R, t, [], n, angle), groups
