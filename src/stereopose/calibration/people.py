"""The rig from the people who walk through the site: no board, no overlap needed between
every pair of cameras, only people seen by cameras two at a time.

1. People matched across views without a calibration (calibration.people_match): relative
   poses per camera pair, and groups (one person at one frame, seen by several cameras).
   Where single frames leave a camera with no agreeing pairing, whole tracks are paired
   instead (calibration.people_tracks), and give the first pair and the groups.
2. Incremental, as COLMAP's mapper: the pair with most agreeing joints and a wide enough
   angle starts; each next camera is placed by PnP (RANSAC) on the joints already
   triangulated; the joints are triangulated again with every camera placed.
3. One bundle adjustment of every camera and joint (robust loss); detections left/right
   swapped are turned back, observations that stand out are dropped, then a second one.
4. Scale and world: scale from two cameras' measured distance, the walkers' height or the
   surveyed points; z up and z = 0 on the floor under the feet (the ankles' plane, less the
   ankle's height above the floor); x along the first camera's view on the floor, the origin
   under it. With surveyed points, the points' own frame instead.

Several recordings of the same cameras (walks at different times) are matched each on its
own (its frame numbers, its tracks) and pooled for 2 and 3: every recording's first pair
starts a placement of all the groups, and the one that fits best is adjusted. With two or
more, each is held out in turn, and the rig from the others is measured on it
(calibration.people_check).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import cv2
import numpy as np

from stereopose.calibration.bundle import Bundle, Solution, adjust, project_px
from stereopose.calibration.people_check import (
    camera_fit_px,
    fit_px,
    point_like_joints,
    thin_warnings,
)
from stereopose.calibration.people_match import (
    MIN_CONF,
    MIN_JOINTS,
    PairMatch,
    Views,
    collect_views,
    group_detections,
    match_pair,
    triangulate_groups,
)
from stereopose.calibration.people_tracks import match_tracks
from stereopose.calibration.people_world import coverage_advice, to_world
from stereopose.calibration.poses import camera_with_pose, intrinsics_row, robust_pnp
from stereopose.errors import CalibrationError
from stereopose.skeleton import SWAP
from stereopose.types import Camera, People2D, Rig

if TYPE_CHECKING:
    from stereopose.calibration.surveyed import Survey

__all__ = [
    "Matched",
    "PeopleResult",
    "Solved",
    "calibrate_people",
    "match_recordings",
    "solve_poses",
]

logger = logging.getLogger(__name__)

MIN_PNP = 30  # 2D-3D correspondences to place a camera
TRACK_PX = 8.0  # an agreeing joint's residual where cameras are matched by tracks
DROP_MIN_PX = (
    8.0  # a joint's residual this far off or more may be dropped before the last adjustment
)


@dataclass
class PeopleResult:
    """The rig; per camera its RMS reprojection error (px), joints and frames used, the part
    of its view the walkers covered (0-1) and advice where too thin; the scale's source.
    fit_px: each camera's median reprojection error (confident joints) on the recordings it
    was calibrated on; held_out_px: recording index -> the same on that recording by the rig
    from the others, and held_out_all_px the median over all its cameras; point_like: each
    camera's observations of joints that are nearly points in every view (nose, eyes, ears,
    wrists, ankles) in the adjustment; recordings: how many were used."""

    rig: Rig
    camera_rms_px: dict[str, float]
    joints_used: dict[str, int]
    frames_used: dict[str, int]
    coverage: dict[str, float]
    advice: list[str]
    scale_from: str
    seconds: float
    warnings: list[str] = field(default_factory=list)
    fit_px: dict[str, float] = field(default_factory=dict)
    held_out_px: dict[int, dict[str, float]] = field(default_factory=dict)
    held_out_all_px: dict[int, float] = field(default_factory=dict)
    point_like: dict[str, int] = field(default_factory=dict)
    recordings: int = 1


def _place(
    views: Views, groups: list[dict[int, int]], X: np.ndarray, c: int, thr: float
) -> tuple[np.ndarray, int] | None:
    """Camera c's pose (6,) by PnP RANSAC on the joints triangulated, and its inliers."""
    obj, img = [], []
    for g, members in enumerate(groups):
        if c in members:
            xy = views.det[members[c]][3]
            ok = np.isfinite(X[g, :, 0]) & np.isfinite(xy[:, 0])
            obj.append(X[g, ok])
            img.append(xy[ok])
    if not obj or sum(len(o) for o in obj) < MIN_PNP:
        return None
    obj, img = np.concatenate(obj), np.concatenate(img)
    found = robust_pnp(obj, img, np.eye(3), None, thr, 5000)
    if found is None or len(found[2]) < MIN_PNP:
        return None
    r, t, keep = found
    return np.concatenate([r.ravel(), t.ravel()]), len(keep)


def _observations(
    views: Views, groups: list[dict[int, int]], X: np.ndarray, placed: np.ndarray, drop: set
) -> tuple:
    """The bundle's points ((group, joint) with two placed views or more) and observations."""
    pid = -np.ones((len(groups), 17), dtype=int)
    cam, pt, uv, w, src = [], [], [], [], []
    n = 0
    for g, members in enumerate(groups):
        for j in range(17):
            if not np.isfinite(X[g, j, 0]):
                continue
            seen = [
                (c, k)
                for c, k in members.items()
                if placed[c] and views.det[k][2][j, 2] >= MIN_CONF and (k, j) not in drop
            ]
            if len(seen) < 2:
                continue
            pid[g, j] = n
            for c, k in seen:
                cam.append(c)
                pt.append(n)
                uv.append(views.det[k][2][j, :2])
                w.append(views.det[k][2][j, 2])
                src.append((k, j))
            n += 1
    return pid, np.array(cam), np.array(pt), np.array(uv).reshape(-1, 2), np.array(w), src


def _median_error(uv: np.ndarray, kp: np.ndarray, ok: np.ndarray) -> float:
    """Median pixel distance of the confident joints of kp (17, 3) to uv (17, 2) where ok."""
    d = np.linalg.norm(uv - kp[:, :2], axis=1)
    return float(np.nanmedian(np.where(ok & (kp[:, 2] >= MIN_CONF), d, np.nan)))


def _unswap(views: Views, groups: list[dict[int, int]], poses: np.ndarray, intr: np.ndarray) -> int:
    """Detections whose joints fit the others' person better left/right swapped are swapped
    (in views); how many."""
    X = triangulate_groups(views, groups, poses, np.ones(len(poses), dtype=bool))
    turned = 0
    for g, members in enumerate(groups):
        ok = np.isfinite(X[g, :, 0])
        if len(members) < 3 or not ok.any():
            continue
        for c, k in members.items():
            kp = views.det[k][2]
            at = np.repeat(poses[c : c + 1], 17, 0), np.repeat(intr[c : c + 1], 17, 0)
            uv, _ = project_px(*at, np.nan_to_num(X[g]))
            e0, e1 = _median_error(uv, kp, ok), _median_error(uv, kp[SWAP], ok)
            if np.isfinite(e0) and np.isfinite(e1) and e1 < 0.5 * e0 and e0 > 6.0:
                views.det[k] = (views.det[k][0], c, kp[SWAP].copy(), views.det[k][3][SWAP].copy())
                turned += 1
    return turned


def _start(matches: list[PairMatch]) -> PairMatch:
    return max(matches, key=lambda m: m.inliers * min(m.angle_deg / 8.0, 1.0))


Frames = list[tuple[int, dict[str, People2D]]]


@dataclass
class Matched:
    """One recording's views, its people grouped across cameras and its first pair."""

    views: Views
    groups: list[dict[int, int]]
    first: PairMatch
    thr: float
    recording: int = 0


@dataclass
class Solved:
    """The pooled views and groups, the poses (C, 6), the last adjustment's solution, each
    (group, joint)'s point in it (-1: none) and its observations' cameras and pixels."""

    views: Views
    groups: list[dict[int, int]]
    poses: np.ndarray
    sol: Solution
    pid: np.ndarray
    cam: np.ndarray
    uv: np.ndarray


def _recordings(frames: Frames | list[Frames]) -> list[Frames]:
    """One recording (a list of frames) or several (a list of such lists)."""
    recordings = [list(r) for r in frames if isinstance(r, list)]
    single = [f for f in frames if not isinstance(f, list)]
    if recordings and single:
        raise CalibrationError("the frames mix whole recordings with single frames")
    return recordings or [single]


def _match(views: Views, focal: float, rng: np.random.Generator) -> Matched:
    """The groups and first pair of one recording: same-frame pairings, or whole tracks where
    single frames leave a camera unlinked."""
    names, C = views.cameras, len(views.cameras)
    thr = 3.0 / focal
    matches = [
        m for a in range(C) for b in range(a + 1, C) if (m := match_pair(views, a, b, thr, rng))
    ]
    linked = {c for m in matches for c in (m.a, m.b)}
    alone = [names[c] for c in range(C) if c not in linked]
    if not alone:
        return Matched(views, group_detections(views, matches), _start(matches), thr)
    # single frames do not say who is who: whole tracks paired (people_tracks)
    thr = TRACK_PX / focal
    by_tracks = match_tracks(views, thr)
    if by_tracks is None:
        raise CalibrationError(
            f"camera(s) {', '.join(alone)} share no walker with any other camera "
            f"({len(views.det)} people seen in {len(views.frames)} frames); walk where they "
            "and another camera both see"
        )
    logger.info("people: camera(s) %s placed by tracks", ", ".join(alone))
    first, groups = by_tracks
    return Matched(views, groups, first, thr)


def _pool(parts: list[Matched]) -> tuple[Views, list[dict[int, int]], list[PairMatch]]:
    """The recordings' views in one (frame and detection indices shifted), their groups and
    their first pairs (pairings shifted likewise)."""
    det, numbers, groups, firsts = [], [], [], []
    for m in parts:
        f0, k0 = len(numbers), len(det)
        numbers.extend(m.views.frames.tolist())
        det.extend((f + f0, c, kp, xy) for f, c, kp, xy in m.views.det)
        groups.extend({c: k + k0 for c, k in g.items()} for g in m.groups)
        firsts.append(replace(m.first, pairings=[(i + k0, j + k0) for i, j in m.first.pairings]))
    views = Views(parts[0].views.cameras, np.array(numbers, dtype=np.int64), det)
    return views, groups, firsts


def match_recordings(
    recordings: list[Frames], cams: dict[str, Camera], seed: int = 0
) -> tuple[list[Matched], list[str]]:
    """Each recording matched on its own (its own frame numbers, its own tracks); a recording
    that matches nobody is left out with a warning while another one matches."""
    focal = float(np.median([c.focal for c in cams.values()]))
    rng = np.random.default_rng(seed)
    parts, warnings, errors = [], [], []
    for i, frames in enumerate(recordings):
        views = collect_views(frames, cams)
        if not views.det:
            errors.append(
                f"no person with {MIN_JOINTS} or more confident joints in {len(frames)} frame(s)"
            )
        else:
            try:
                parts.append(replace(_match(views, focal, rng), recording=i))
                continue
            except CalibrationError as e:
                errors.append(str(e))
        if len(recordings) > 1:
            warnings.append(f"recording {i + 1} left out: {errors[-1]}")
    if not parts:
        if len(errors) == 1:
            raise CalibrationError(errors[0])
        raise CalibrationError("; ".join(f"recording {i + 1}: {e}" for i, e in enumerate(errors)))
    return parts, warnings


def solve_poses(parts: list[Matched], intr: np.ndarray) -> Solved:
    """Every camera's pose (C, 6) from the matched recordings pooled, in the frame of the
    best start (its first camera at the origin, unit baseline): each recording's first pair
    starts a placement of every camera on all the groups, and the one whose joints fit best
    is adjusted."""
    views, groups, firsts = _pool(parts)
    thr = max(m.thr for m in parts)
    names = views.cameras
    best = None
    for first in firsts:
        try:
            poses, X = _place_all(views, groups, first, names, thr)
        except CalibrationError:
            if len(firsts) == 1:
                raise
            continue
        fit = fit_px(views, groups, poses, intr)
        if best is None or fit < best[0]:
            best = (fit, first, poses, X)
    if best is None:
        raise CalibrationError("no recording's first pair places every camera")
    _, first, poses, X = best
    poses, sol, pid, cam, uv = _adjust_all(views, groups, poses, X, intr, first)
    return Solved(views, groups, poses, sol, pid, cam, uv)


def held_out_fit(
    parts: list[Matched], intr: np.ndarray
) -> tuple[dict[int, dict[str, float]], dict[int, float]]:
    """Recording index -> each camera's fit on it (median px) by the rig from the others, and
    the median over every camera's joints."""
    out, overall = {}, {}
    for m in parts:
        rest = [p for p in parts if p is not m]
        try:
            poses = solve_poses(rest, intr).poses
        except CalibrationError as e:
            logger.warning("people: no rig without recording %d: %s", m.recording + 1, e)
            continue
        out[m.recording] = camera_fit_px(m.views, m.groups, poses, intr)
        overall[m.recording] = fit_px(m.views, m.groups, poses, intr)
    return out, overall


def calibrate_people(
    frames: Frames | list[Frames],
    intrinsics: Rig,
    *,
    distance: tuple[str, str, float] | None = None,
    height_m: float | None = None,
    survey: Survey | None = None,
    ankle_m: float = 0.08,
    seed: int = 0,
    held_out: bool = True,
) -> PeopleResult:
    """The rig of `intrinsics`' cameras from the people of `frames` (frame number, camera ->
    People2D; synchronised), or of several recordings of the same cameras (a list of such
    lists, each with its own frame numbers), pooled. Exactly one of distance (camera, camera,
    metres), height_m (the walkers' standing height) or survey (calibration.surveyed.Survey)
    gives the scale. held_out: with two recordings or more, each one's fit by the rig from
    the others (PeopleResult.held_out_px)."""
    t0 = time.perf_counter()
    if sum(x is not None for x in (distance, height_m, survey)) != 1:
        raise CalibrationError("give exactly one scale: a distance, a height or surveyed points")
    cams = {c.name: c for c in intrinsics}
    names = list(cams)
    if distance is not None:
        for n in distance[:2]:
            if n not in cams:
                raise CalibrationError(f"--distance: no camera {n!r} (cameras: {', '.join(names)})")
    parts, warnings = match_recordings(_recordings(frames), cams, seed)
    intr = np.stack([intrinsics_row(cams[n]) for n in names])
    solved = solve_poses(parts, intr)
    views, groups, poses, sol = solved.views, solved.groups, solved.poses, solved.sol
    pid, cam, uv = solved.pid, solved.cam, solved.uv
    X = np.full((len(groups), 17, 3), np.nan)
    for g, j in zip(*np.nonzero(pid >= 0), strict=True):
        X[g, j] = sol.points[pid[g, j]]
    rig = Rig(tuple(camera_with_pose(cams[n], poses[c]) for c, n in enumerate(names)))
    rig, scale_from = to_world(
        rig, X, distance=distance, height_m=height_m, survey=survey, ankle_m=ankle_m
    )
    err = sol.residual_px
    rms = {
        n: float(np.sqrt(np.mean(err[cam == c] ** 2))) if np.any(cam == c) else float("nan")
        for c, n in enumerate(names)
    }
    used = {n: int(np.sum(cam == c)) for c, n in enumerate(names)}
    frames_used = {
        n: len({views.det[g[c]][0] for g in groups if c in g}) for c, n in enumerate(names)
    }
    cover, advice = coverage_advice(rig, {n: uv[cam == c] for c, n in enumerate(names)})
    warnings += [
        f"camera {n}: reprojection error {e:.2f} px is high" for n, e in rms.items() if e > 5
    ]
    point_like = point_like_joints(views, groups, pid, names)
    warnings += thin_warnings(point_like)
    held, held_all = held_out_fit(parts, intr) if held_out and len(parts) > 1 else ({}, {})
    return PeopleResult(
        rig,
        rms,
        used,
        frames_used,
        cover,
        advice,
        scale_from,
        time.perf_counter() - t0,
        warnings,
        fit_px=camera_fit_px(views, groups, poses, intr),
        held_out_px=held,
        held_out_all_px=held_all,
        point_like=point_like,
        recordings=len(parts),
    )


def _place_all(
    views: Views, groups: list[dict[int, int]], first: PairMatch, names: list[str], thr: float
) -> tuple[np.ndarray, np.ndarray]:
    """Every camera's pose (C, 6) in the first pair's frame and the groups' joints."""
    C = len(names)
    poses = np.zeros((C, 6))
    poses[first.b] = np.concatenate([cv2.Rodrigues(first.R)[0].ravel(), first.t])
    placed = np.zeros(C, dtype=bool)
    placed[[first.a, first.b]] = True
    X = triangulate_groups(views, groups, poses, placed)
    while not placed.all():
        tries = {
            int(c): r
            for c in np.flatnonzero(~placed)
            if (r := _place(views, groups, X, int(c), 2 * thr)) is not None
        }
        if not tries:
            left = [names[c] for c in np.flatnonzero(~placed)]
            raise CalibrationError(
                f"camera(s) {', '.join(left)}: too few joints shared with the cameras placed "
                f"({', '.join(names[c] for c in np.flatnonzero(placed))}); walk where they see"
            )
        c = max(tries, key=lambda c: tries[c][1])
        poses[c], placed[c] = tries[c][0], True
        X = triangulate_groups(views, groups, poses, placed)
    return poses, X


def _adjust_all(
    views: Views,
    groups: list[dict[int, int]],
    poses: np.ndarray,
    X: np.ndarray,
    intr: np.ndarray,
    first: PairMatch,
) -> tuple[np.ndarray, Solution, np.ndarray, np.ndarray, np.ndarray]:
    """Two bundle adjustments, swapped detections turned back and outlying joints dropped
    between them: (poses, the solution, point of each (group, joint), observations' cameras
    and pixels)."""
    C = len(poses)
    placed = np.ones(C, dtype=bool)
    base = (first.a, first.b, float(np.linalg.norm(first.t)))
    drop: set = set()
    round_ = 0
    while True:  # two rounds: the second without the joints the first drops
        pid, cam, pt, uv, w, src = _observations(views, groups, X, placed, drop)
        free_cams = np.ones(C, dtype=bool)
        free_cams[first.a] = False
        pts = np.array([X[g, j] for g, j in zip(*np.nonzero(pid >= 0), strict=True)])
        every = np.ones(len(pts), dtype=bool)
        problem = Bundle(poses, intr, pts, cam, pt, uv, w, free_cams, every, baseline=base)
        sol = adjust(problem, f_scale_px=3.0, max_nfev=40 if round_ == 0 else 60)
        poses = sol.poses
        if round_ == 1:
            break
        turned = _unswap(views, groups, poses, intr)
        limit = max(DROP_MIN_PX, 4.0 * float(np.median(sol.residual_px)))
        drop = {src[i] for i in np.flatnonzero(sol.residual_px > limit)}
        logger.info("people: %d detections turned back, %d joints dropped", turned, len(drop))
        X = triangulate_groups(views, groups, poses, placed)
        round_ = 1
    return poses, sol, pid, cam, uv
