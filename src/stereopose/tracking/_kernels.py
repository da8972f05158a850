"""Compiled loops of the tracking (numba): the Kalman step of joints, running limb lengths;
called through tracking.filter, tracking.bones and tracking.offline.

Division follows NumPy (x / 0 is inf or NaN, never an error). Compiled once per machine,
cached beside this module.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_JIT = {"cache": True, "error_model": "numpy", "nogil": True}


@njit(**_JIT)
def predict_cov(
    p00: float, p01: float, p11: float, dt: float, q: float
) -> tuple[float, float, float]:
    """One constant-velocity prediction of a joint's covariance (position, velocity) over dt
    seconds, white-noise acceleration of spectral density q (m^2/s^3)."""
    return (
        p00 + 2.0 * dt * p01 + dt * dt * p11 + q * dt**3 / 3.0,
        p01 + dt * p11 + q * dt * dt / 2.0,
        p11 + q * dt,
    )


@njit(**_JIT)
def correct(
    x: np.ndarray,
    v: np.ndarray,
    yx: float,
    yy: float,
    yz: float,
    a00: float,
    a01: float,
    a11: float,
    r2: float,
) -> tuple[float, float, float]:
    """One Kalman correction of a joint by the innovation (yx, yy, yz) with measurement
    variance r2: x (3,) and v (3,) in place; returns the new covariance terms."""
    s = a00 + r2
    k0, k1 = a00 / s, a01 / s
    x[0] += k0 * yx
    x[1] += k0 * yy
    x[2] += k0 * yz
    v[0] += k1 * yx
    v[1] += k1 * yy
    v[2] += k1 * yz
    return (1.0 - k0) * a00, (1.0 - k0) * a01, a11 - k1 * a01


@njit(**_JIT)
def kalman_predict(
    x: np.ndarray,
    v: np.ndarray,
    p00: np.ndarray,
    p01: np.ndarray,
    p11: np.ndarray,
    dt: np.ndarray,
    q: np.ndarray,
    moving: np.ndarray,
) -> None:
    """Every joint advanced by dt (T,) seconds, in place: x, v (T, 17, 3), p00, p01, p11
    (T, 17); q (17,) per joint; moving (T,) false: velocity zeroed first (held in place)."""
    T, J = p00.shape
    for r in range(T):
        for j in range(J):
            for d in range(3):
                if not moving[r]:
                    v[r, j, d] = 0.0
                x[r, j, d] = x[r, j, d] + v[r, j, d] * dt[r]
            p00[r, j], p01[r, j], p11[r, j] = predict_cov(
                p00[r, j], p01[r, j], p11[r, j], dt[r], q[j]
            )


@njit(**_JIT)
def kalman_update(
    x: np.ndarray,
    v: np.ndarray,
    p00: np.ndarray,
    p01: np.ndarray,
    p11: np.ndarray,
    rejected: np.ndarray,
    rows: np.ndarray,
    z: np.ndarray,
    r2: np.ndarray,
    gate_m: float,
    gate_sigmas: float,
    reset_frames: int,
    initial_var: float,
) -> np.ndarray:
    """Gated constant-velocity Kalman correction of joints, in place (see
    tracking.filter.JointFilters.update, whose arithmetic this is, joint by joint).

    x, v: (T, 17, 3); p00, p01, p11: (T, 17) covariance terms; rejected: (T, 17) frames gated
    out in a row; rows: (n,) tracks corrected by z (n, 17, 3) with noise variance r2 (n, 17).
    Returns (n, 17) what became of each measurement: 0 not used (missing or gated out),
    1 accepted, 2 restarted the joint (a new joint, or one gated out reset_frames in a row).
    """
    n, J = z.shape[0], z.shape[1]
    used = np.zeros((n, J), dtype=np.int8)
    for i in range(n):
        r = rows[i]
        for j in range(J):
            zx, zy, zz = z[i, j, 0], z[i, j, 1], z[i, j, 2]
            measured = np.isfinite(zx) and np.isfinite(zy) and np.isfinite(zz)
            known = np.isfinite(x[r, j, 0]) and np.isfinite(x[r, j, 1]) and np.isfinite(x[r, j, 2])
            new = measured and not known
            yx, yy, yz = zx - x[r, j, 0], zy - x[r, j, 1], zz - x[r, j, 2]
            dist = np.sqrt(yx * yx + yy * yy + yz * yz)
            a00, a01, a11, q = p00[r, j], p01[r, j], p11[r, j], r2[i, j]
            spread = np.sqrt(a00 + min(q, gate_m * gate_m / 16.0))
            inside = dist <= max(gate_m, gate_sigmas * spread)
            accept = measured and not new and inside
            rej = rejected[r, j] + 1 if (measured and not accept and not new) else 0
            restart = new or rej >= reset_frames
            if accept:
                p00[r, j], p01[r, j], p11[r, j] = correct(
                    x[r, j], v[r, j], yx, yy, yz, a00, a01, a11, q
                )
            if restart:
                x[r, j, 0], x[r, j, 1], x[r, j, 2] = zx, zy, zz
                v[r, j, 0] = v[r, j, 1] = v[r, j, 2] = 0.0
                p00[r, j] = q
                p01[r, j] = 0.0
                p11[r, j] = initial_var
                rej = 0
            rejected[r, j] = rej
            used[i, j] = 2 if restart else (1 if accept else 0)
    return used


@njit(**_JIT)
def kalman_replay(
    z: np.ndarray,
    code: np.ndarray,
    r2: np.ndarray,
    t: np.ndarray,
    q: np.ndarray,
    initial_var: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The online filter run again over one track's measurements as it took them: z (K, 17, 3)
    at times t (K,), code (K, 17) 0 not used, 1 accepted, 2 restarted; r2 (K, 17) their
    variances; q (17,). Returns per step the filtered x, v (K, 17, 3) and covariance
    P (K, 3, 17), the predicted xp, vp, Pp, and where a joint restarted (K, 17)."""
    K, J = code.shape
    x = np.full((K, J, 3), np.nan)
    v = np.zeros((K, J, 3))
    P = np.zeros((K, 3, J))
    xp = np.full((K, J, 3), np.nan)
    vp = np.zeros((K, J, 3))
    Pp = np.zeros((K, 3, J))
    start = np.zeros((K, J), dtype=np.bool_)
    cx = np.full((J, 3), np.nan)
    cv = np.zeros((J, 3))
    c = np.zeros((3, J))
    c[2] = initial_var
    for k in range(K):
        dt = t[k] - t[k - 1] if k else 0.0
        for j in range(J):
            for d in range(3):
                cx[j, d] = cx[j, d] + cv[j, d] * dt
            c[0, j], c[1, j], c[2, j] = predict_cov(c[0, j], c[1, j], c[2, j], dt, q[j])
            xp[k, j], vp[k, j], Pp[k, :, j] = cx[j], cv[j], c[:, j]
            known = np.isfinite(cx[j, 0])
            if code[k, j] == 1 and known:
                y0, y1, y2 = z[k, j, 0] - cx[j, 0], z[k, j, 1] - cx[j, 1], z[k, j, 2] - cx[j, 2]
                c[0, j], c[1, j], c[2, j] = correct(
                    cx[j], cv[j], y0, y1, y2, c[0, j], c[1, j], c[2, j], r2[k, j]
                )
            elif code[k, j] == 2 or code[k, j] == 1:  # restarted, or accepted while unknown
                cx[j] = z[k, j]
                cv[j] = 0.0
                c[0, j], c[1, j], c[2, j] = r2[k, j], 0.0, initial_var
                start[k, j] = True
            x[k, j], v[k, j], P[k, :, j] = cx[j], cv[j], c[:, j]
    return x, v, P, xp, vp, Pp, start


@njit(**_JIT)
def bones_observe(
    length: np.ndarray,
    count: np.ndarray,
    rows: np.ndarray,
    joints: np.ndarray,
    parent: np.ndarray,
    child: np.ndarray,
    window: int,
    min_samples: int,
    outlier: float,
) -> None:
    """Add the limb lengths of measured joints (n, 17, 3) of tracks `rows` to their running
    means length, count (T, L), in place (see tracking.bones.BoneLengths.observe)."""
    n, L = rows.shape[0], parent.shape[0]
    for i in range(n):
        r = rows[i]
        for k in range(L):
            a, b = parent[k], child[k]
            dx = joints[i, b, 0] - joints[i, a, 0]
            dy = joints[i, b, 1] - joints[i, a, 1]
            dz = joints[i, b, 2] - joints[i, a, 2]
            sample = np.sqrt(dx * dx + dy * dy + dz * dz)
            est, cnt = length[r, k], count[r, k]
            far = cnt >= min_samples and abs(sample - est) > outlier * est
            use = np.isfinite(sample) and not far
            if use:
                cnt += 1
                alpha = 1.0 / max(min(cnt, window), 1)
                est = est + alpha * (sample - est) if np.isfinite(est) else sample
            elif not np.isfinite(est):
                est = sample
            length[r, k], count[r, k] = est, cnt


@njit(**_JIT)
def bones_apply(
    X: np.ndarray,
    length: np.ndarray,
    count: np.ndarray,
    rows: np.ndarray,
    parent: np.ndarray,
    child: np.ndarray,
    min_samples: int,
) -> None:
    """X (n, 17, 3) with each limb of tracks `rows` set to its running length where that is
    known from min_samples samples, the trunk outwards (parents before children), in place
    (see tracking.bones.BoneLengths.apply)."""
    n, L = rows.shape[0], parent.shape[0]
    for i in range(n):
        r = rows[i]
        for k in range(L):
            if count[r, k] < min_samples:
                continue
            a, b = parent[k], child[k]
            dx = X[i, b, 0] - X[i, a, 0]
            dy = X[i, b, 1] - X[i, a, 1]
            dz = X[i, b, 2] - X[i, a, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            scale = length[r, k] / d
            if np.isfinite(scale) and d > 1e-6:
                X[i, b, 0] = X[i, a, 0] + dx * scale
                X[i, b, 1] = X[i, a, 1] + dy * scale
                X[i, b, 2] = X[i, a, 2] + dz * scale
