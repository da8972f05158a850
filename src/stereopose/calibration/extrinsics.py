"""A multi-camera rig in one world frame from a checkerboard seen at many positions.

1. Per camera and board position: the board's pose (PnP, planar IPPE), for both corner orders
   the detector could have given (a board turned by a half turn looks the same).
2. A pose graph: cameras are placed one at a time, each through the board positions it shares
   with cameras already placed; the corner order of each of its views is the one on which most
   shared positions agree.
3. One bundle adjustment of every camera pose and board pose (intrinsics held or refined) over
   every corner seen: scipy's least_squares with the sparse Jacobian structure and a robust
   (Huber) loss.
4. The world frame: a board laid on the floor (a named position) gives z up with the floor at
   z = 0, the origin at its first corner (shifted by `origin_m`) and x along its first row
   (turned by `yaw_deg`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative, group_columns
from scipy.sparse import coo_matrix, csr_matrix, sparray, spmatrix

from stereopose.calibration.board import Board
from stereopose.errors import CalibrationError
from stereopose.types import Camera, Rig

if TYPE_CHECKING:
    from scipy.optimize import OptimizeResult

logger = logging.getLogger(__name__)


def rodrigues(rvecs: np.ndarray) -> np.ndarray:
    """(M, 3) rotation vectors -> (M, 3, 3) matrices."""
    theta = np.linalg.norm(rvecs, axis=-1)[:, None, None]
    small = theta < 1e-12
    k = rvecs[:, :, None] / np.where(small, 1.0, theta)
    K = np.zeros((rvecs.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2, 0], k[:, 1, 0], -k[:, 0, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2, 0], -k[:, 1, 0], k[:, 0, 0]
    eye = np.eye(3)[None]
    R = eye + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)
    return np.where(small, eye, R)


def _transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.ravel(t)
    return T


def _rt(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3].copy()


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


@dataclass
class ExtrinsicsResult:
    rig: Rig
    rms_px: float
    camera_rms_px: dict[str, float]
    view_rms_px: dict[str, float]  # board position -> RMS over the cameras seeing it
    residuals_px: np.ndarray  # every corner's reprojection error
    board_poses: dict[str, np.ndarray]  # position -> (4, 4) board -> world
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)


def _pnp(obj: np.ndarray, pts: np.ndarray, cam: Camera) -> np.ndarray:
    ok, r, t = cv2.solvePnP(obj, pts, cam.matrix, cam.distortions, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        ok, r, t = cv2.solvePnP(obj, pts, cam.matrix, cam.distortions)
    if not ok:
        raise CalibrationError(f"camera {cam.name}: no board pose could be estimated")
    return _transform(cv2.Rodrigues(r)[0], t)


def _place_cameras(
    cams: list[str],
    views: dict[str, list[str]],
    poses: dict[tuple[str, str], np.ndarray],
    flipped: dict[tuple[str, str], np.ndarray],
) -> tuple[str, dict[str, np.ndarray], dict[tuple[str, str], bool], dict[str, np.ndarray]]:
    """Pose graph: camera -> world (4, 4) with the reference camera's frame as world; per
    (camera, view) whether its corner order is turned; board -> world per view."""
    order = sorted(cams, key=lambda c: -len(views[c]))
    ref = order[0]
    cam_T = {ref: np.eye(4)}  # world -> camera
    flip = {(ref, v): False for v in views[ref]}
    board_T = {v: poses[(ref, v)] for v in views[ref]}  # board -> world (= ref camera)
    todo = set(order[1:])
    while todo:
        best = max(todo, key=lambda c: (len(set(views[c]) & set(board_T)), c))
        shared = sorted(set(views[best]) & set(board_T))
        if not shared:
            placed = ", ".join(sorted(cam_T))
            raise CalibrationError(
                f"camera {best}: it shares no board position with the cameras placed so far "
                f"({placed}); show the board to it together with one of them"
            )
        # candidates world -> camera from each shared view, with either corner order
        cand = []
        for v in shared:
            for f in (False, True):
                board_in_cam = flipped[(best, v)] if f else poses[(best, v)]
                cand.append((v, f, board_in_cam @ np.linalg.inv(board_T[v])))

        def gap(Ta: np.ndarray, Tb: np.ndarray) -> float:
            """Rotation (degrees) plus translation (per cent of the distance) apart."""
            scale = max(float(np.linalg.norm(Ta[:3, 3])), 0.1)
            move = 100.0 * float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3])) / scale
            return _angle_deg(Ta[:3, :3], Tb[:3, :3]) + move

        # the candidate most shared views agree with (as detected preferred on ties)
        support = [(len({u for u, _, T2 in cand if gap(T, T2) < 10.0}), not f) for _, f, T in cand]
        T_best = cand[max(range(len(cand)), key=lambda i: support[i])][2]
        cam_T[best] = T_best
        for v in shared:
            flip[(best, v)] = min(
                ((gap(T, T_best), f) for u, f, T in cand if u == v), key=lambda x: x[0]
            )[1]
        for v in views[best]:
            if v not in board_T:
                flip[(best, v)] = False
                board_T[v] = np.linalg.inv(T_best) @ poses[(best, v)]
        todo.remove(best)
    return ref, cam_T, flip, board_T


@dataclass(frozen=True)
class Adjusted:
    """A bundle adjustment's result: camera poses (world -> camera) and board poses (board ->
    world) by name, the intrinsics (C, 8) in `names`' order, the residuals per corner seen
    (N, 2) with each one's camera and view index (N,) into `names` and `view_names`."""

    camera_poses: dict[str, np.ndarray]
    board_poses: dict[str, np.ndarray]
    intr: np.ndarray
    res: np.ndarray
    cam_idx: np.ndarray
    view_idx: np.ndarray
    names: list[str]
    view_names: list[str]


@dataclass(frozen=True)
class _Seen:
    """The board corners seen: per observation its camera, board view and corner (indices);
    the corners on the board (obj); the reference camera (fixed); the cameras' intrinsics
    (fx, fy, cx, cy, k1, k2, p1, p2 per camera) and whether they are refined."""

    n_cams: int
    n_views: int
    cam_idx: np.ndarray
    view_idx: np.ndarray
    obj_idx: np.ndarray
    obj: np.ndarray
    fixed: int
    intr: np.ndarray
    refine: bool


def _project(params: np.ndarray, seen: _Seen) -> np.ndarray:
    """Reprojection of every observation. params: cameras' rvec, tvec (6 each, the reference
    camera excluded), then boards' (6 each), then intrinsics (8 per camera) when refined."""
    n_cams, n_views, fixed, intr = seen.n_cams, seen.n_views, seen.fixed, seen.intr
    cam_idx, view_idx, obj_idx, obj = seen.cam_idx, seen.view_idx, seen.obj_idx, seen.obj
    cam_p = np.zeros((n_cams, 6))
    free = [c for c in range(n_cams) if c != fixed]
    cam_p[free] = params[: 6 * (n_cams - 1)].reshape(-1, 6)
    off = 6 * (n_cams - 1)
    board_p = params[off : off + 6 * n_views].reshape(-1, 6)
    off += 6 * n_views
    if seen.refine:
        intr = params[off : off + 8 * n_cams].reshape(-1, 8)
    Rc, tc = rodrigues(cam_p[:, :3]), cam_p[:, 3:]
    Rb, tb = rodrigues(board_p[:, :3]), board_p[:, 3:]
    Xw = np.einsum("nij,nj->ni", Rb[view_idx], obj[obj_idx]) + tb[view_idx]
    Xc = np.einsum("nij,nj->ni", Rc[cam_idx], Xw) + tc[cam_idx]
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    fx, fy, cx, cy, k1, k2, p1, p2 = intr[cam_idx].T
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * k2)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], axis=1)


def _jacobian_sparsity(
    M: int,
    C: int,
    V: int,
    cam_idx: np.ndarray,
    view_idx: np.ndarray,
    fixed: int,
    refine_intrinsics: bool,
) -> coo_matrix:
    """Which parameters each of the 2 M residuals depends on: its camera's pose (none for the
    fixed reference camera), its board pose and, when refined, its camera's intrinsics."""
    free_col = np.cumsum([c != fixed for c in range(C)]) - 1  # column block of each camera
    has = cam_idx != fixed
    r_list, c_list = [], []
    for d in range(2):
        r = 2 * np.arange(M) + d
        for j in range(6):
            r_list += [r[has], r]
            c_list += [6 * free_col[cam_idx[has]] + j, 6 * (C - 1) + 6 * view_idx + j]
        if refine_intrinsics:
            for j in range(8):
                r_list.append(r)
                c_list.append(6 * (C - 1) + 6 * V + 8 * cam_idx + j)
    rr, cc = np.concatenate(r_list), np.concatenate(c_list)
    n = 6 * (C - 1) + 6 * V + (8 * C if refine_intrinsics else 0)
    return coo_matrix((np.ones(rr.size, dtype=np.int8), (rr, cc)), shape=(2 * M, n))


def _unpack(
    p: np.ndarray,
    names: list[str],
    view_names: list[str],
    ref: str,
    intr: np.ndarray,
    refine_intrinsics: bool,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
    """The solution vector back as camera poses, board poses and intrinsics (C, 8)."""
    C, V = len(names), len(view_names)
    out_cam, out_board = {}, {}
    k = 0
    for c in names:
        if c == ref:
            out_cam[c] = np.eye(4)
            continue
        out_cam[c] = _transform(cv2.Rodrigues(p[6 * k : 6 * k + 3])[0], p[6 * k + 3 : 6 * k + 6])
        k += 1
    off = 6 * (C - 1)
    for j, v in enumerate(view_names):
        q = p[off + 6 * j : off + 6 * j + 6]
        out_board[v] = _transform(cv2.Rodrigues(q[:3])[0], q[3:])
    if refine_intrinsics:
        intr = p[off + 6 * V :].reshape(-1, 8)
    return out_cam, out_board, intr


def bundle_adjust(
    cameras: dict[str, Camera],
    observations: dict[tuple[str, str], np.ndarray],
    board: Board,
    cam_T: dict[str, np.ndarray],
    board_T: dict[str, np.ndarray],
    ref: str,
    refine_intrinsics: bool = False,
) -> Adjusted:
    """Refine camera poses (world -> camera), board poses (board -> world) and optionally the
    intrinsics over every corner seen."""
    names = sorted(cameras)
    view_names = sorted(board_T)
    ci = {c: i for i, c in enumerate(names)}
    vi = {v: i for i, v in enumerate(view_names)}
    obj = board.object_points()
    keys = sorted(observations)
    cam_idx = np.concatenate([np.full(board.count, ci[c]) for c, _ in keys])
    view_idx = np.concatenate([np.full(board.count, vi[v]) for _, v in keys])
    obj_idx = np.tile(np.arange(board.count), len(keys))
    observed = np.concatenate([observations[k] for k in keys])
    fixed = ci[ref]
    intr = np.array(
        [
            [
                cameras[c].matrix[0, 0],
                cameras[c].matrix[1, 1],
                cameras[c].matrix[0, 2],
                cameras[c].matrix[1, 2],
                *np.pad(cameras[c].distortions[:4], (0, 4 - len(cameras[c].distortions[:4]))),
            ]
            for c in names
        ]
    )
    C, V = len(names), len(view_names)
    x0 = [np.concatenate(_rt(cam_T[c])) for c in names if c != ref]
    x0 += [np.concatenate(_rt(board_T[v])) for v in view_names]
    if refine_intrinsics:
        x0.append(intr.ravel())
    x0 = np.concatenate(x0)
    S = csr_matrix(
        _jacobian_sparsity(observed.shape[0], C, V, cam_idx, view_idx, fixed, refine_intrinsics)
    )
    rows, cols = S.get_shape()

    seen = _Seen(C, V, cam_idx, view_idx, obj_idx, obj, fixed, intr, refine_intrinsics)

    def residuals(p: np.ndarray) -> np.ndarray:
        proj = _project(p, seen)
        return (proj - observed).ravel()

    groups = group_columns(S)
    dense = rows * cols <= 4e7  # small enough for exact trust-region steps

    def jac(p: np.ndarray) -> np.ndarray:
        J = approx_derivative(residuals, p, sparsity=(S, groups))
        assert isinstance(J, (sparray, spmatrix))  # with a sparsity, a sparse Jacobian
        return J.toarray()

    def solve(
        start: np.ndarray, loss: str = "linear", max_nfev: int | None = None
    ) -> OptimizeResult:
        if dense:
            # scipy leaves jac unannotated: its default, a str, is taken for its type
            return least_squares(
                residuals,
                start,
                jac=jac,  # pyright: ignore[reportArgumentType]
                tr_solver="exact",
                x_scale="jac",
                method="trf",
                loss=loss,
                max_nfev=max_nfev,
            )
        return least_squares(
            residuals,
            start,
            jac_sparsity=S,
            x_scale="jac",
            method="trf",
            loss=loss,
            max_nfev=max_nfev,
        )

    # plain least squares converges in a few steps from the pose graph; a robust (Huber)
    # pass follows only where some corners stand out (a misdetected corner, a moved board)
    sol = solve(x0)
    err = np.linalg.norm(sol.fun.reshape(-1, 2), axis=-1)
    if err.max() > 3.0 * max(np.median(err), 0.3):
        sol = solve(sol.x, loss="huber", max_nfev=100)
    p = sol.x
    out_cam, out_board, intr = _unpack(p, names, view_names, ref, intr, refine_intrinsics)
    res = residuals(p).reshape(-1, 2)
    return Adjusted(out_cam, out_board, intr, res, cam_idx, view_idx, names, view_names)


def world_from_floor(
    board_T: np.ndarray,
    cam_T: dict[str, np.ndarray],
    origin_m: tuple[float, float] = (0.0, 0.0),
    yaw_deg: float = 0.0,
) -> np.ndarray:
    """(4, 4) old world -> new world: the floor board's plane is z = 0, z points to the side
    the cameras are on, the origin is its first corner shifted by origin_m (along its rows and
    columns) and x runs along its first row turned by yaw_deg about z."""
    B = board_T.copy()  # board -> old world
    centres = [np.linalg.inv(T)[:3, 3] for T in cam_T.values()]
    in_board = [(np.linalg.inv(B) @ np.append(c, 1.0))[2] for c in centres]
    if np.mean(in_board) < 0:  # cameras on the board's -z side: turn it over (about x)
        B = B @ np.diag([1.0, -1.0, -1.0, 1.0])
    shift = np.eye(4)
    shift[:2, 3] = origin_m
    a = np.radians(yaw_deg)
    turn = np.eye(4)
    turn[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    new_to_old = B @ shift @ turn
    return np.linalg.inv(new_to_old)


def calibrate_extrinsics(
    cameras: dict[str, Camera],
    corners: dict[str, dict[str, np.ndarray]],
    board: Board,
    floor: str | None = None,
    origin_m: tuple[float, float] = (0.0, 0.0),
    yaw_deg: float = 0.0,
    refine_intrinsics: bool = False,
) -> ExtrinsicsResult:
    """corners[camera][position] = (cols * rows, 2) pixels (canonical order) -> the rig.

    floor: the board position lying on the floor (default: the first position by name, with
    a warning).
    """
    t0 = time.perf_counter()
    missing = sorted(set(corners) - set(cameras))
    if missing:
        raise CalibrationError(f"no intrinsics for camera(s) {', '.join(missing)}")
    cams = sorted(c for c in corners if corners[c])
    if len(cams) < 2:
        raise CalibrationError(
            f"the board was found by {len(cams)} camera(s); at least 2 are needed"
        )
    obj = board.object_points()
    views = {c: sorted(corners[c]) for c in cams}
    poses, flipped, obs = {}, {}, {}
    for c in cams:
        for v in views[c]:
            pts = np.asarray(corners[c][v], dtype=np.float64)
            poses[(c, v)] = _pnp(obj, pts, cameras[c])
            flipped[(c, v)] = _pnp(obj, pts[::-1].copy(), cameras[c])
    ref, cam_T, flip, board_T = _place_cameras(cams, views, poses, flipped)
    for (c, v), f in flip.items():
        pts = np.asarray(corners[c][v], dtype=np.float64)
        obs[(c, v)] = pts[::-1].copy() if f else pts
    sub = {c: cameras[c] for c in cams}
    adjusted = bundle_adjust(sub, obs, board, cam_T, board_T, ref, refine_intrinsics)
    cam_T, board_T = adjusted.camera_poses, adjusted.board_poses
    intr, res = adjusted.intr, adjusted.res
    cam_idx, view_idx = adjusted.cam_idx, adjusted.view_idx
    names, view_names = adjusted.names, adjusted.view_names
    warnings = []
    if floor is None:
        floor = sorted(board_T)[0]
        warnings.append(
            f"no floor position named: the board at position {floor!r} defines the floor "
            "(z = 0); name the position where it lay on the floor with --floor"
        )
    if floor not in board_T:
        raise CalibrationError(
            f"floor position {floor!r}: no camera saw the board there (positions: "
            f"{', '.join(sorted(board_T))})"
        )
    W = world_from_floor(board_T[floor], cam_T, origin_m, yaw_deg)  # old world -> world
    W_inv = np.linalg.inv(W)
    out = []
    for i, c in enumerate(names):
        T = cam_T[c] @ W_inv  # world -> camera
        K = np.array([[intr[i, 0], 0, intr[i, 2]], [0, intr[i, 1], intr[i, 3]], [0, 0, 1.0]])
        dist = intr[i, 4:8] if refine_intrinsics else cameras[c].distortions
        r, t = _rt(T)
        out.append(Camera(c, cameras[c].size, K, dist, r, t))
    err = np.linalg.norm(res, axis=-1)
    cam_rms = {c: float(np.sqrt(np.mean(err[cam_idx == i] ** 2))) for i, c in enumerate(names)}
    view_rms = {
        v: float(np.sqrt(np.mean(err[view_idx == j] ** 2))) for j, v in enumerate(view_names)
    }
    for c, e in cam_rms.items():
        if e > 1.5:
            warnings.append(f"camera {c}: high reprojection error ({e:.2f} px)")
    return ExtrinsicsResult(
        Rig(tuple(out)),
        float(np.sqrt(np.mean(err**2))),
        cam_rms,
        view_rms,
        err,
        {v: W @ T for v, T in board_T.items()},
        time.perf_counter() - t0,
        warnings,
    )
