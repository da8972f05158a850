"""The rig from surveyed points: each camera placed by robust PnP on the points it sees, then
one adjustment of every camera together (the points held near their surveyed positions).

The points file (TOML) gives the points' site coordinates in metres and, per camera, where it
sees them in pixels of its own (distorted) image:

    [points]
    P1 = [28.94, 9.19, 0.0]
    [cameras.cam01]
    P1 = [1238.9, 348.4]

The world frame is the points' own: zones drawn from the same drawings land on the equipment.
A click whose residual stands out is left out and named. A camera with fewer than MIN_POINTS
good points is not placed, named with the points it has and what would place it, and the
others are placed without it; no camera placed at all is an error.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stereopose.calibration.poses import camera_with_pose, intrinsics_row, robust_pnp
from stereopose.checks import read_limited
from stereopose.errors import CalibrationError
from stereopose.types import Camera, Rig

if TYPE_CHECKING:  # scipy's, an extra: imported where the adjustment runs
    from stereopose.calibration.bundle import Solution

__all__ = [
    "PointsResult",
    "Survey",
    "calibrate_points",
    "format_survey",
    "read_survey",
    "survey_from_doc",
]

MIN_POINTS = 6  # per camera, after the clicks left out (10 or more advised)
RANSAC_PX = 12.0  # PnP's inlier bound on a click's residual
MAX_POINTS = 10_000
COORD_LIMIT_M = 1e5
PIXEL_LIMIT = 1e5


@dataclass(frozen=True)
class Survey:
    """world: point name -> (3,) metres; clicks: camera -> point name -> (2,) pixels."""

    path: Path
    world: dict[str, np.ndarray]
    clicks: dict[str, dict[str, np.ndarray]]


def _vector(path: Path, where: str, value: object, n: int, limit: float) -> np.ndarray:
    unit = "metres" if n == 3 else "pixels"
    if (
        not isinstance(value, list)
        or len(value) != n
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise CalibrationError(f"{path}: {where}: expected {n} numbers ({unit}), got {value!r:.80}")
    a = np.array(value, dtype=np.float64)
    if not np.all(np.isfinite(a)) or np.any(np.abs(a) > limit):
        raise CalibrationError(f"{path}: {where}: not a finite number within {limit:g}: {value}")
    return a


def read_survey(path: str | Path) -> Survey:
    """Read and check a points file (see the module); CalibrationError naming the file, the
    key and the problem."""
    path = Path(path)
    raw = read_limited(path, "points file", CalibrationError)
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise CalibrationError(f"{path}: not UTF-8 text (byte {e.start}); expected TOML") from None
    except (ValueError, RecursionError) as e:
        raise CalibrationError(f"{path}: not valid TOML: {e}") from None
    return survey_from_doc(doc, path)


def survey_from_doc(doc: object, path: Path) -> Survey:
    """A points file's tables (as TOML or JSON give them) checked; CalibrationError naming
    `path`, the key and the problem."""
    if not isinstance(doc, dict):
        raise CalibrationError(f"{path}: expected the tables [points] and [cameras.<name>]")
    unknown = sorted(set(doc) - {"points", "cameras"})
    if unknown:
        raise CalibrationError(
            f"{path}: unknown table(s) {', '.join(unknown)}; expected [points] and [cameras.<name>]"
        )
    pts, cams = doc.get("points"), doc.get("cameras")
    if not isinstance(pts, dict) or not pts:
        raise CalibrationError(f"{path}: no [points] table: name = [x, y, z] in metres")
    if not isinstance(cams, dict) or not cams:
        raise CalibrationError(f"{path}: no [cameras.<name>] table: point = [u, v] in pixels")
    if len(pts) > MAX_POINTS:
        raise CalibrationError(f"{path}: {len(pts)} points; at most {MAX_POINTS}")
    world = {str(k): _vector(path, f"points.{k}", v, 3, COORD_LIMIT_M) for k, v in pts.items()}
    clicks: dict[str, dict[str, np.ndarray]] = {}
    for cam, table in cams.items():
        if not isinstance(table, dict):
            raise CalibrationError(f"{path}: cameras.{cam}: expected a table of point = [u, v]")
        seen = {}
        for k, v in table.items():
            if k not in world:
                raise CalibrationError(
                    f"{path}: cameras.{cam}.{k}: no point {k!r} in [points]"
                    f" (points: {', '.join(sorted(world)[:20])})"
                )
            seen[str(k)] = _vector(path, f"cameras.{cam}.{k}", v, 2, PIXEL_LIMIT)
        clicks[str(cam)] = seen
    return Survey(path, world, clicks)


def format_survey(survey: Survey) -> str:
    """The points file's text (TOML) of `survey`: read back, the same survey."""

    def key(name: str) -> str:  # a bare key where TOML allows one, else a quoted one
        bare = name and all(ch.isascii() and (ch.isalnum() or ch in "_-") for ch in name)
        return name if bare else json.dumps(name)

    def nums(v: np.ndarray) -> str:
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"

    lines = ["[points]", *(f"{key(k)} = {nums(v)}" for k, v in survey.world.items())]
    for cam, clicks in survey.clicks.items():
        lines += [
            "",
            f"[cameras.{key(cam)}]",
            *(f"{key(k)} = {nums(v)}" for k, v in clicks.items()),
        ]
    return "\n".join(lines) + "\n"


@dataclass
class PointsResult:
    """The rig (cameras in the intrinsics' order), each camera's RMS over its good clicks,
    every click's residual (camera -> point -> pixels), the clicks left out (camera, point,
    pixels), the points' adjusted positions and warnings."""

    rig: Rig
    camera_rms_px: dict[str, float]
    residuals_px: dict[str, dict[str, float]]
    left_out: list[tuple[str, str, float]]
    points: dict[str, np.ndarray]
    warnings: list[str] = field(default_factory=list)
    unplaced: dict[str, str] = field(default_factory=dict)  # camera -> why, and what would


def _pnp(cam: Camera, obj: np.ndarray, img: np.ndarray, names: list[str]) -> np.ndarray:
    """(6,) pose of one camera from its clicks; CalibrationError when it has too few."""
    if len(names) < MIN_POINTS:
        raise CalibrationError(
            f"camera {cam.name}: {len(names)} surveyed point(s) clicked "
            f"({', '.join(names) or 'none'}); at least {MIN_POINTS} are needed, 10 or more advised"
        )
    found = robust_pnp(obj, img, cam.matrix, cam.distortions, RANSAC_PX, 2000)
    if found is None or len(found[2]) < MIN_POINTS:
        agree = 0 if found is None else len(found[2])
        raise CalibrationError(
            f"camera {cam.name}: no pose agrees with {MIN_POINTS} or more of its points "
            f"({agree} of {len(names)} agree within {RANSAC_PX:g} px: {', '.join(names)}); "
            "check the clicks and the points' coordinates"
        )
    r, t, _ = found
    return np.concatenate([r.ravel(), t.ravel()])


def _outliers(err: np.ndarray, cam_of: np.ndarray, floor_px: float) -> np.ndarray:
    """Observations whose residual stands out from their camera's (a robust spread)."""
    bad = np.zeros(err.shape, dtype=bool)
    for c in np.unique(cam_of):
        e = err[cam_of == c]
        spread = 1.4826 * np.median(e)
        bad[cam_of == c] = e > max(floor_px, 3.0 * np.median(e) + 4.0 * spread)
    return bad


def calibrate_points(
    intrinsics: Rig,
    survey: Survey,
    *,
    outlier_px: float = 5.0,
    survey_sigma_m: float = 0.02,
) -> PointsResult:
    """The rig of the surveyed cameras (see the module): every camera that can be placed; each
    that cannot (no clicks, too few, too few left once the clicks that disagree are left out)
    is in `unplaced` with why and what would place it, and the others are placed without it.

    intrinsics: cameras with their intrinsics (their poses ignored); every camera of the survey
    must be there. outlier_px: a click is never left out under this residual. survey_sigma_m:
    how far a surveyed position may be off (the adjustment moves the points that much).
    CalibrationError when no camera can be placed."""
    missing = sorted(set(survey.clicks) - set(intrinsics.names))
    if missing:
        raise CalibrationError(
            f"{survey.path}: camera(s) {', '.join(missing)} have no intrinsics "
            f"(cameras there: {', '.join(intrinsics.names)})"
        )
    cams = {c.name: c for c in intrinsics}
    point_names = sorted(survey.world)
    world = np.array([survey.world[p] for p in point_names])
    unplaced = {
        n: f"no clicks in {survey.path}; {_WHAT_PLACES}"
        for n in intrinsics.names
        if n not in survey.clicks
    }
    poses = {}
    for c in (n for n in intrinsics.names if n in survey.clicks):
        clicked = sorted(survey.clicks[c])
        try:
            poses[c] = _pnp(
                cams[c],
                np.array([survey.world[p] for p in clicked]),
                np.array([survey.clicks[c][p] for p in clicked]).reshape(-1, 2),
                clicked,
            )
        except CalibrationError as e:
            unplaced[c] = f"{e}; {_WHAT_PLACES}"
    while True:
        if not poses:
            raise CalibrationError(
                f"{survey.path}: no camera can be placed: "
                + "; ".join(unplaced[n] for n in intrinsics.names if n in unplaced)
            )
        placed = _adjusted(cams, survey, point_names, world, poses, outlier_px, survey_sigma_m)
        if isinstance(placed, tuple):  # a camera left with too few good clicks: without it
            camera, why = placed
            unplaced[camera] = f"{why}; {_WHAT_PLACES}"
            del poses[camera]
            continue
        break
    return _result(placed, cams, survey, point_names, world, unplaced, survey_sigma_m)


# what would place a camera that could not be placed from the points
_WHAT_PLACES = (
    f"click at least {MIN_POINTS} of the surveyed points it sees (10 or more advised), spread "
    "over its picture, or place it with `calibrate people --points` (walkers, with these points "
    "for the site's frame)"
)


@dataclass
class _Adjusted:
    """The adjustment of the cameras placed: their names, observations and solution."""

    names: list[str]
    cam_of: np.ndarray
    pt_of: np.ndarray
    uv: np.ndarray
    err: np.ndarray
    keep: np.ndarray
    sol: Solution


def _adjusted(
    cams: dict[str, Camera],
    survey: Survey,
    point_names: list[str],
    world: np.ndarray,
    first: dict[str, np.ndarray],
    outlier_px: float,
    survey_sigma_m: float,
) -> _Adjusted | tuple[str, str]:
    """Every camera of `first` (its PnP pose) adjusted together, the clicks that disagree left
    out; (camera, why) for a camera left with fewer than MIN_POINTS good clicks."""
    from stereopose.calibration.bundle import Bundle, adjust, project_px  # scipy: an extra

    names = list(first)
    pi = {p: i for i, p in enumerate(point_names)}
    obs = [(ci, pi[p], uv) for ci, c in enumerate(names) for p, uv in survey.clicks[c].items()]
    cam_of = np.array([o[0] for o in obs])
    pt_of = np.array([o[1] for o in obs])
    uv = np.array([o[2] for o in obs]).reshape(-1, 2)
    poses = np.stack([first[c] for c in names])
    intr = np.stack([intrinsics_row(cams[c]) for c in names])
    keep = np.ones(len(obs), dtype=bool)
    passes = 0
    while True:  # adjust, leave the worst click out, again: three passes at most
        passes += 1
        sol = adjust(
            Bundle(
                poses,
                intr,
                world.copy(),
                cam_of[keep],
                pt_of[keep],
                uv[keep],
                np.ones(int(keep.sum())),
                np.ones(len(names), dtype=bool),
                np.ones(len(world), dtype=bool),
                prior=world,
                prior_sigma_m=survey_sigma_m,
            ),
            f_scale_px=2.0,
            max_nfev=200,
        )
        poses = sol.poses
        all_uv, depth = project_px(poses[cam_of], intr[cam_of], sol.points[pt_of])
        err = np.where(depth > 0, np.linalg.norm(all_uv - uv, axis=1), np.inf)
        bad = _outliers(err, cam_of, outlier_px)
        if np.array_equal(~bad, keep):
            break
        keep = ~bad
        for ci, c in enumerate(names):  # enough left to place every camera
            sel = keep & (cam_of == ci)
            if sel.sum() < MIN_POINTS:
                good = [point_names[i] for i in pt_of[sel]]
                return c, (
                    f"camera {c}: {int(sel.sum())} good point(s) left ({', '.join(good) or 'none'})"
                    f" after leaving out the clicks that disagree; at least {MIN_POINTS} are "
                    "needed"
                )
        if passes == 3:
            break
    return _Adjusted(names, cam_of, pt_of, uv, err, keep, sol)


def _result(
    a: _Adjusted,
    cams: dict[str, Camera],
    survey: Survey,
    point_names: list[str],
    world: np.ndarray,
    unplaced: dict[str, str],
    survey_sigma_m: float,
) -> PointsResult:
    """The PointsResult of an adjustment: residuals, clicks left out, warnings."""
    names, cam_of, pt_of, err, keep, sol = a.names, a.cam_of, a.pt_of, a.err, a.keep, a.sol
    residuals: dict[str, dict[str, float]] = {c: {} for c in names}
    left_out = []
    for k in range(len(cam_of)):
        c, p = names[cam_of[k]], point_names[pt_of[k]]
        residuals[c][p] = float(err[k])
        if not keep[k]:
            left_out.append((c, p, float(err[k])))
    rms = {
        c: float(math.sqrt(np.mean(err[keep & (cam_of == ci)] ** 2))) for ci, c in enumerate(names)
    }
    warnings = [f"camera {c} not placed: {why}" for c, why in unplaced.items()]
    warnings += [
        f"camera {c}: reprojection error {e:.2f} px is high" for c, e in rms.items() if e > 3
    ]
    moved = np.linalg.norm(sol.points - world, axis=1)
    for i in np.flatnonzero(moved > 3 * survey_sigma_m):
        warnings.append(
            f"point {point_names[i]}: the cameras put it {moved[i]:.3f} m from its surveyed "
            "position; check its coordinates"
        )
    rig = Rig(tuple(camera_with_pose(cams[c], sol.poses[ci]) for ci, c in enumerate(names)))
    return PointsResult(
        rig,
        rms,
        residuals,
        sorted(left_out, key=lambda x: -x[2]),
        {p: sol.points[i] for i, p in enumerate(point_names)},
        warnings,
        unplaced,
    )
