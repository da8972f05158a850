"""Compiled loops of the 3D stage (numba): undistortion, claims, the robust triangulation.

The robust mode's choice of views is a small search per joint (every two-view solution scored
by the views that agree with it); written as NumPy over all joints at once it costs many array
operations per frame. These loops do the same arithmetic joint by joint, compiled once per
machine (cached beside the module). Division follows NumPy (x / 0 is inf or NaN, never an
error), so the loops give what the array code gives; tests/test_kernels.py checks them against
the NumPy forms kept in the package (e.g. triangulate.select_views_numpy).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy", nogil=True)
def _dlt(xy, w, use, P, out):
    """Weighted DLT of one point from the views where use; writes out (3,), NaN when singular
    (fewer than two views). Same normal equations and singularity test as triangulate_dlt."""
    N = np.zeros((4, 4))
    C = xy.shape[0]
    for c in range(C):
        if not use[c]:
            continue
        wc = w[c]
        if not (wc > 0.0):
            continue
        x, y = xy[c, 0], xy[c, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        w2 = wc * wc
        for i in range(4):
            r1i = x * P[c, 2, i] - P[c, 0, i]
            r2i = y * P[c, 2, i] - P[c, 1, i]
            for k in range(4):
                r1k = x * P[c, 2, k] - P[c, 0, k]
                r2k = y * P[c, 2, k] - P[c, 1, k]
                N[i, k] += w2 * (r1i * r1k + r2i * r2k)
    a, b, cc, r0 = N[0, 0], N[0, 1], N[0, 2], N[0, 3]
    d, f, r1 = N[1, 1], N[1, 2], N[1, 3]
    g, r2 = N[2, 2], N[2, 3]
    A = d * g - f * f
    B = cc * f - b * g
    Cc = b * f - cc * d
    D = a * g - cc * cc
    E = b * cc - a * f
    F = a * d - b * b
    det = a * A + b * B + cc * Cc
    tr = abs(a + d + g)
    if not (abs(det) > 1e-12 * tr * tr * tr):
        out[0] = out[1] = out[2] = np.nan
        return
    inv = -1.0 / det
    out[0] = (A * r0 + B * r1 + Cc * r2) * inv
    out[1] = (B * r0 + D * r1 + E * r2) * inv
    out[2] = (Cc * r0 + E * r1 + F * r2) * inv


@njit(cache=True, error_model="numpy", nogil=True)
def _errors(X, xy, P, focal, out):
    """Pixel distance (C,) between X (3,) reprojected and each view (NaN where either is
    missing or X is behind the camera)."""
    C = xy.shape[0]
    for c in range(C):
        zc = P[c, 2, 0] * X[0] + P[c, 2, 1] * X[1] + P[c, 2, 2] * X[2] + P[c, 2, 3]
        if not (zc > 1e-3):
            out[c] = np.nan
            continue
        u = (P[c, 0, 0] * X[0] + P[c, 0, 1] * X[1] + P[c, 0, 2] * X[2] + P[c, 0, 3]) / zc
        v = (P[c, 1, 0] * X[0] + P[c, 1, 1] * X[1] + P[c, 1, 2] * X[2] + P[c, 1, 3]) / zc
        du, dv = u - xy[c, 0], v - xy[c, 1]
        out[c] = np.sqrt(du * du + dv * dv) * focal[c]


@njit(cache=True, error_model="numpy", nogil=True)
def select_views(xy, w, P, focal, thr, X_all):
    """Per joint, the views that agree and the point they give.

    xy: (G, J, C, 2); w: (G, J, C) weights (0: unused); P: (C, 3, 4); focal: (C,);
    thr: (G, C) agreement threshold in pixels; X_all: (G, J, 3) weighted DLT over all views.
    Where every view of a joint agrees with X_all (or it has two views or fewer), X_all stands.
    Otherwise every two-view solution is scored by the confidence of the views agreeing with it
    (ties to the tighter fit), and the point is the weighted DLT over the best one's agreeing
    views, which are kept where within 1.5 thr of it. Where fewer than two views are kept, all
    views and X_all are used. Returns X (G, J, 3), used (G, J, C) and the errors of every view
    (G, J, C) in pixels.
    """
    G, J, C = w.shape
    X = X_all.copy()
    used = np.zeros((G, J, C), dtype=np.bool_)
    err = np.full((G, J, C), np.nan)
    e_all = np.empty(C)
    e = np.empty(C)
    Xk = np.empty(3)
    Xr = np.empty(3)
    has = np.empty(C, dtype=np.bool_)
    inl = np.empty(C, dtype=np.bool_)
    best_inl = np.empty(C, dtype=np.bool_)
    for g in range(G):
        for j in range(J):
            seen = 0
            for c in range(C):
                has[c] = w[g, j, c] > 0.0
                seen += has[c]
            _errors(X_all[g, j], xy[g, j], P, focal, e_all)
            n_used = 0
            for c in range(C):
                u = has[c] and e_all[c] < thr[g, c]
                used[g, j, c] = u
                n_used += u
                err[g, j, c] = e_all[c]
            finite = np.isfinite(X_all[g, j, 0])
            if seen > 2 and (n_used < seen or not finite):
                best = -np.inf
                found = False
                for a in range(C):
                    if not has[a]:
                        continue
                    for b in range(a + 1, C):
                        if not has[b]:
                            continue
                        for c in range(C):
                            inl[c] = (c - a) * (c - b) == 0  # the pair itself
                        _dlt(xy[g, j], w[g, j], inl, P, Xk)
                        if not np.isfinite(Xk[0]):
                            continue
                        _errors(Xk, xy[g, j], P, focal, e)
                        score = 0.0
                        for c in range(C):
                            inl[c] = has[c] and e[c] < thr[g, c]
                            if inl[c]:
                                score += w[g, j, c] - 1e-3 * e[c] / thr[g, c]
                        if not found or score > best:
                            best = score
                            found = True
                            for c in range(C):
                                best_inl[c] = inl[c]
                if found:
                    _dlt(xy[g, j], w[g, j], best_inl, P, Xr)
                    _errors(Xr, xy[g, j], P, focal, e)
                    n_used = 0
                    for c in range(C):
                        u = best_inl[c] and e[c] < 1.5 * thr[g, c]
                        used[g, j, c] = u
                        n_used += u
                        err[g, j, c] = e[c]
                    X[g, j, 0], X[g, j, 1], X[g, j, 2] = Xr[0], Xr[1], Xr[2]
                else:
                    n_used = 0
                    for c in range(C):
                        used[g, j, c] = False
                    X[g, j, 0] = X[g, j, 1] = X[g, j, 2] = np.nan
            if n_used < 2:
                X[g, j, 0], X[g, j, 1], X[g, j, 2] = X_all[g, j, 0], X_all[g, j, 1], X_all[g, j, 2]
                for c in range(C):
                    used[g, j, c] = has[c]
                    err[g, j, c] = e_all[c]
    return X, used, err


@njit(cache=True, error_model="numpy", nogil=True)
def project_all(X, P):
    """Points (T, J, 3) projected into every camera (C, 3, 4): (T, J, C, 2) ideal
    coordinates, NaN behind a camera (see geometry.camera.project_to_cameras)."""
    T, J, C = X.shape[0], X.shape[1], P.shape[0]
    out = np.full((T, J, C, 2), np.nan)
    for t in range(T):
        for j in range(J):
            x0, x1, x2 = X[t, j, 0], X[t, j, 1], X[t, j, 2]
            for c in range(C):
                zc = P[c, 2, 0] * x0 + P[c, 2, 1] * x1 + P[c, 2, 2] * x2 + P[c, 2, 3]
                if zc > 1e-3:
                    out[t, j, c, 0] = (
                        P[c, 0, 0] * x0 + P[c, 0, 1] * x1 + P[c, 0, 2] * x2 + P[c, 0, 3]
                    ) / zc
                    out[t, j, c, 1] = (
                        P[c, 1, 0] * x0 + P[c, 1, 1] * x1 + P[c, 1, 2] * x2 + P[c, 1, 3]
                    ) / zc
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def claim_costs(xy, ok, size, camera, proj, swap, parts, min_common):
    """Cost of every detection against every predicted pose, labels as detected or exchanged.

    xy: (N, 17, 2) detections' ideal coordinates; ok: (N, 17) confident joints; size: (N,);
    camera: (N,) camera of each detection; proj: (T, 17, C, 2) predicted poses reprojected
    (NaN where unknown); swap: (17,) mirror joint; parts: (17, 2) joint-to-part weights;
    min_common: joints needed. Returns best (N, T), the mean distance over shared joints
    divided by the detection's size, the lower of the two labelings (inf with fewer than
    min_common joints), and per labeling (2, N, T, 2) the mean distance per body part (NaN
    where the part shares no joint).
    """
    N, J = ok.shape
    T = proj.shape[0]
    P = parts.shape[1]
    best = np.full((N, T), np.inf)
    part = np.full((2, N, T, P), np.nan)
    psum = np.empty(P)
    pcnt = np.empty(P)
    for n in range(N):
        c = camera[n]
        for t in range(T):
            for lab in range(2):
                total = 0.0
                count = 0
                for p in range(P):
                    psum[p] = 0.0
                    pcnt[p] = 0.0
                for j in range(J):
                    k = swap[j] if lab == 1 else j
                    if not ok[n, k]:
                        continue
                    dx = xy[n, k, 0] - proj[t, j, c, 0]
                    dy = xy[n, k, 1] - proj[t, j, c, 1]
                    d = np.sqrt(dx * dx + dy * dy)
                    if d != d:
                        continue
                    total += d
                    count += 1
                    for p in range(P):
                        if parts[j, p] != 0.0:
                            psum[p] += d * parts[j, p]
                            pcnt[p] += parts[j, p]
                for p in range(P):
                    if pcnt[p] > 0.0:
                        part[lab, n, t, p] = psum[p] / pcnt[p]
                if count >= min_common and count > 0:
                    cost = total / (count * size[n])
                    if cost == cost and cost < best[n, t]:
                        best[n, t] = cost
    return best, part


@njit(cache=True, error_model="numpy", nogil=True)
def _dist3(X, g, a, b):
    dx = X[g, a, 0] - X[g, b, 0]
    dy = X[g, a, 1] - X[g, b, 1]
    dz = X[g, a, 2] - X[g, b, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, error_model="numpy", nogil=True)
def _lead(lx, ly, rx, ry):
    """How far the horizontal offset (lx, ly) reaches ahead, ahead being up x (rx, ry)."""
    return (ly * rx - lx * ry) / np.sqrt(rx * rx + ry * ry)


@njit(cache=True, error_model="numpy", nogil=True)
def body_orientation(X, face_margin_m, thigh_margin_m, head_radius_m, head_width_m):
    """Per person (G, 17, 3): whether the labels are mirrored as a whole (the face behind the
    shoulders and the nose behind the ears, with z up) and whether the legs are (each knee
    nearer the other side's hip). See triangulate.body_orientation_numpy, of which this is the
    compiled form."""
    G = X.shape[0]
    flip_upper = np.zeros(G, dtype=np.bool_)
    flip_legs = np.zeros(G, dtype=np.bool_)
    for g in range(G):
        # the head's sides: the ears, or the eyes without them
        hl, hr = (3, 4) if np.isfinite(X[g, 3, 0]) and np.isfinite(X[g, 4, 0]) else (1, 2)
        mx = 0.5 * (X[g, hl, 0] + X[g, hr, 0])
        my = 0.5 * (X[g, hl, 1] + X[g, hr, 1])
        mz = 0.5 * (X[g, hl, 2] + X[g, hr, 2])
        off = np.sqrt((X[g, 0, 0] - mx) ** 2 + (X[g, 0, 1] - my) ** 2 + (X[g, 0, 2] - mz) ** 2)
        stray = off >= head_radius_m or _dist3(X, g, hl, hr) >= head_width_m  # NaN: False
        # the body's left-to-right axis: shoulders plus hips, whichever are known
        rx = ry = 0.0
        axes = 0
        for left, right in ((5, 6), (11, 12)):
            dx = X[g, right, 0] - X[g, left, 0]
            dy = X[g, right, 1] - X[g, left, 1]
            if np.isfinite(dx) and np.isfinite(dy):
                rx += dx
                ry += dy
                axes += 1
        if axes == 0:
            rx = ry = np.nan
        fx = fy = 0.0
        k = 0
        for j in range(3):
            if np.isfinite(X[g, j, 0]) and not (j == 0 and stray):
                fx += X[g, j, 0]
                fy += X[g, j, 1]
                k += 1
        ahead = 0.0
        if k > 0:
            lx = fx / k - 0.5 * (X[g, 5, 0] + X[g, 6, 0])
            ly = fy / k - 0.5 * (X[g, 5, 1] + X[g, 6, 1])
            shoulders = _lead(lx, ly, rx, ry)
            if np.isfinite(shoulders):
                ahead += shoulders
        if not stray:
            lx, ly = X[g, 0, 0] - mx, X[g, 0, 1] - my
            head = _lead(lx, ly, rx, ry)
            if not np.isfinite(head):  # no body axis: the head's own
                head = _lead(lx, ly, X[g, hr, 0] - X[g, hl, 0], X[g, hr, 1] - X[g, hl, 1])
            if np.isfinite(head):
                ahead += head
        flip_upper[g] = ahead < -face_margin_m
        h0, h1 = (12, 11) if flip_upper[g] else (11, 12)
        d00 = _dist3(X, g, h0, 13)
        d01 = _dist3(X, g, h0, 14)
        d10 = _dist3(X, g, h1, 13)
        d11 = _dist3(X, g, h1, 14)
        flip_legs[g] = d01 + d10 < d00 + d11 - thigh_margin_m
    return flip_upper, flip_legs


@njit(cache=True, error_model="numpy", nogil=True)
def dlt_all(xy, w, P):
    """Weighted DLT (G, J, 3) of every joint from all its views (xy (G, J, C, 2), w (G, J, C));
    NaN with fewer than two views. The compiled form of triangulate_dlt."""
    G, J, C = w.shape
    X = np.empty((G, J, 3))
    use = np.ones(C, dtype=np.bool_)
    for g in range(G):
        for j in range(J):
            _dlt(xy[g, j], w[g, j], use, P, X[g, j])
    return X


@njit(cache=True, error_model="numpy", nogil=True)
def chain_flips(X, chains, margin_m):
    """(G, K) whether the child pair of each chain row (parent left, parent right, child left,
    child right) of `chains` (K, 4) hangs from the other side: the cross distances to the
    parents shorter than the direct ones by more than margin_m (NaN: no)."""
    G = X.shape[0]
    K = chains.shape[0]
    out = np.zeros((G, K), dtype=np.bool_)
    for g in range(G):
        for k in range(K):
            pl, pr, cl, cr = chains[k, 0], chains[k, 1], chains[k, 2], chains[k, 3]
            same = _dist3(X, g, pl, cl) + _dist3(X, g, pr, cr)
            cross = _dist3(X, g, pl, cr) + _dist3(X, g, pr, cl)
            out[g, k] = cross < same - margin_m
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def undistort(uv, camera, intrinsics, dist, eps_px, max_iter):
    """Distorted pixels (M, 2) of the cameras `camera` (M,) -> ideal normalised coordinates
    (M, 2), NaN staying NaN: OpenCV's iterative undistortPoints (the same fixed-point
    iteration, stopped once the point reprojects within eps_px or after max_iter steps).
    intrinsics: (C, 4) fx, fy, cx, cy; dist: (C, 5) k1 k2 p1 p2 k3."""
    M = uv.shape[0]
    out = np.empty((M, 2))
    for m in range(M):
        u, v = uv[m, 0], uv[m, 1]
        if not (np.isfinite(u) and np.isfinite(v)):
            out[m, 0] = out[m, 1] = np.nan
            continue
        c = camera[m]
        fx, fy, cx, cy = intrinsics[c, 0], intrinsics[c, 1], intrinsics[c, 2], intrinsics[c, 3]
        k1, k2, p1, p2, k3 = dist[c, 0], dist[c, 1], dist[c, 2], dist[c, 3], dist[c, 4]
        x0 = (u - cx) / fx
        y0 = (v - cy) / fy
        x, y = x0, y0
        for _ in range(max_iter):
            r2 = x * x + y * y
            icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
            if icdist < 0.0:
                x, y = x0, y0
                break
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x = (x0 - dx) * icdist
            y = (y0 - dy) * icdist
            r2 = x * x + y * y
            cdist = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2
            xd = x * cdist + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = y * cdist + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            ex = xd * fx + cx - u
            ey = yd * fy + cy - v
            if np.sqrt(ex * ex + ey * ey) < eps_px:
                break
        out[m, 0], out[m, 1] = x, y
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def kalman_update(
    x, v, p00, p01, p11, rejected, rows, z, r2, gate_m, gate_sigmas, reset_frames, initial_var
):
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
            s = a00 + q
            spread = np.sqrt(a00 + min(q, gate_m * gate_m / 16.0))
            inside = dist <= max(gate_m, gate_sigmas * spread)
            accept = measured and not new and inside
            rej = rejected[r, j] + 1 if (measured and not accept and not new) else 0
            restart = new or rej >= reset_frames
            if accept:
                k0, k1 = a00 / s, a01 / s
                x[r, j, 0] += k0 * yx
                x[r, j, 1] += k0 * yy
                x[r, j, 2] += k0 * yz
                v[r, j, 0] += k1 * yx
                v[r, j, 1] += k1 * yy
                v[r, j, 2] += k1 * yz
                p00[r, j] = (1.0 - k0) * a00
                p01[r, j] = (1.0 - k0) * a01
                p11[r, j] = a11 - k1 * a01
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


@njit(cache=True, error_model="numpy", nogil=True)
def bones_observe(length, count, rows, joints, parent, child, window, min_samples, outlier):
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


@njit(cache=True, error_model="numpy", nogil=True)
def bones_apply(X, length, count, rows, parent, child, min_samples):
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


@njit(cache=True, error_model="numpy", nogil=True)
def implausibility(X, bones_left, bones_right, bones, max_m):
    """(G,) how far each skeleton X (G, 17, 3) is from a possible body: the sum of
    |left - right| bone lengths over the sum of their means, over the bones (B, 2) whose both
    sides are known (0 where none is), plus, for each bone of `bones` (K, 2), its length's
    excess over max_m (K,) as a fraction of max_m."""
    G, B, K = X.shape[0], bones_left.shape[0], bones.shape[0]
    out = np.empty(G)
    for g in range(G):
        num = den = 0.0
        for b in range(B):
            lo = _dist3(X, g, bones_left[b, 0], bones_left[b, 1])
            hi = _dist3(X, g, bones_right[b, 0], bones_right[b, 1])
            if np.isfinite(lo) and np.isfinite(hi):
                num += abs(lo - hi)
                den += 0.5 * (lo + hi)
        score = num / den if den > 0.0 else 0.0
        for k in range(K):
            length = _dist3(X, g, bones[k, 0], bones[k, 1])
            if length > max_m[k]:  # NaN compares False
                score += length / max_m[k] - 1.0
        out[g] = score
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def place_single_views(X, used, xy, w, centers, R, anchors):
    """Joints (NaN in X (G, J, 3)) that views report (w (G, J, C) > 0) placed on the ray of
    their strongest view, at the point nearest the first reconstructed joint of their row of
    anchors (J, A) (-1: none); two passes, so a joint can hang from one placed in the first.
    X and used (G, J, C) are updated in place; returns (G, J) the joints placed."""
    G, J, C = w.shape
    A = anchors.shape[1]
    placed = np.zeros((G, J), dtype=np.bool_)
    for _ in range(2):
        for j in range(J):
            for g in range(G):
                if np.isfinite(X[g, j, 0]) or placed[g, j]:
                    continue
                c = -1
                best = 0.0
                for k in range(C):
                    if w[g, j, k] > best:
                        best = w[g, j, k]
                        c = k
                if c < 0:
                    continue
                a = -1
                for i in range(A):
                    cand = anchors[j, i]
                    if cand >= 0 and np.isfinite(X[g, cand, 0]):
                        a = cand
                        break
                if a < 0:
                    continue
                x, y = xy[g, j, c, 0], xy[g, j, c, 1]
                # ray direction in the world: R^T (x, y, 1), normalised
                dx = R[c, 0, 0] * x + R[c, 1, 0] * y + R[c, 2, 0]
                dy = R[c, 0, 1] * x + R[c, 1, 1] * y + R[c, 2, 1]
                dz = R[c, 0, 2] * x + R[c, 1, 2] * y + R[c, 2, 2]
                norm = np.sqrt(dx * dx + dy * dy + dz * dz)
                dx, dy, dz = dx / norm, dy / norm, dz / norm
                depth = (
                    (X[g, a, 0] - centers[c, 0]) * dx
                    + (X[g, a, 1] - centers[c, 1]) * dy
                    + (X[g, a, 2] - centers[c, 2]) * dz
                )
                if not (depth > 0.0):
                    continue
                X[g, j, 0] = centers[c, 0] + depth * dx
                X[g, j, 1] = centers[c, 1] + depth * dy
                X[g, j, 2] = centers[c, 2] + depth * dz
                used[g, j, c] = True
                placed[g, j] = True
    return placed


@njit(cache=True, error_model="numpy", nogil=True)
def in_view(X, P, lo, hi, min_joints):
    """(G, C) whether >= min_joints joints of each person (G, J, 3) project inside each
    camera's image bounds lo, hi (C, 2) (ideal normalised coordinates), in front of it."""
    G, J = X.shape[0], X.shape[1]
    C = P.shape[0]
    out = np.zeros((G, C), dtype=np.bool_)
    for g in range(G):
        for c in range(C):
            n = 0
            for j in range(J):
                x0, x1, x2 = X[g, j, 0], X[g, j, 1], X[g, j, 2]
                zc = P[c, 2, 0] * x0 + P[c, 2, 1] * x1 + P[c, 2, 2] * x2 + P[c, 2, 3]
                if not (zc > 1e-3):
                    continue
                u = (P[c, 0, 0] * x0 + P[c, 0, 1] * x1 + P[c, 0, 2] * x2 + P[c, 0, 3]) / zc
                v = (P[c, 1, 0] * x0 + P[c, 1, 1] * x1 + P[c, 1, 2] * x2 + P[c, 1, 3]) / zc
                if lo[c, 0] <= u <= hi[c, 0] and lo[c, 1] <= v <= hi[c, 1]:
                    n += 1
            out[g, c] = n >= min_joints
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def epipolar_pair_distances(xy, size, camera, E, first, second, swap):
    """Per-joint normalised symmetric epipolar distances of detection pairs.

    xy: (N, 17, 2) ideal coordinates, finite (missing joints as 0: they never vote);
    size: (N,); camera: (N,); E: (C, C, 3, 3); first, second: (M,) detection pairs. Returns
    same (M, 17), the distance of joint j of `first` to joint j of `second`, each side's
    point-to-line distance divided by its detection's size, and cross (M, 17), the same
    against the mirror joint swap[j] of `second` (see association.affinity.epipolar_distances).
    """
    M, J = first.shape[0], xy.shape[1]
    same = np.empty((M, J))
    cross = np.empty((M, J))
    lm = np.empty((J, 3))  # lines of first's joints in second's image
    wm = np.empty(J)
    wn = np.empty(J)
    for k in range(M):
        n, m = first[k], second[k]
        ca, cb = camera[n], camera[m]
        for j in range(J):
            xn, yn = xy[n, j, 0], xy[n, j, 1]
            xm, ym = xy[m, j, 0], xy[m, j, 1]
            for r in range(3):
                lm[j, r] = E[ca, cb, r, 0] * xn + E[ca, cb, r, 1] * yn + E[ca, cb, r, 2]
            a = E[cb, ca, 0, 0] * xm + E[cb, ca, 0, 1] * ym + E[cb, ca, 0, 2]
            b = E[cb, ca, 1, 0] * xm + E[cb, ca, 1, 1] * ym + E[cb, ca, 1, 2]
            wm[j] = 0.5 / np.sqrt(lm[j, 0] * lm[j, 0] + lm[j, 1] * lm[j, 1]) / size[m]
            wn[j] = 0.5 / np.sqrt(a * a + b * b) / size[n]
        for j in range(J):
            s = swap[j]
            xm, ym = xy[m, j, 0], xy[m, j, 1]
            xs, ys = xy[m, s, 0], xy[m, s, 1]
            same[k, j] = abs(lm[j, 0] * xm + lm[j, 1] * ym + lm[j, 2]) * (wm[j] + wn[j])
            cross[k, j] = abs(lm[j, 0] * xs + lm[j, 1] * ys + lm[j, 2]) * (wm[j] + wn[s])
    return same, cross


def warm_up() -> None:
    """Compile every loop above (once per machine: the results are cached beside this module)
    by running a small simulated scene through the tracker, so a first real run does not
    wait for the compiler. `make install` calls it."""
    import dataclasses

    from stereopose.config import Config
    from stereopose.sim import simulate
    from stereopose.tracking import Tracker

    scene = simulate(num_cameras=4, num_people=3, num_frames=30, seed=1, difficulty="hard")
    tracker = Tracker(scene.rig, dataclasses.replace(Config(), fps=scene.fps), record=True)
    people = [
        tracker.update(t, [d[n] for n in scene.rig.names]) for t, d in enumerate(scene.detections)
    ]
    tracker.two_way(people)


@njit(cache=True, error_model="numpy", nogil=True)
def pair_costs(N, first, second, same, cross, ok, swap, min_common):
    """(N, N) symmetric cost of detection pairs: the mean over joints confident (ok (N, 17)) in
    both of the distances same (M, 17), or of cross with the second's labels exchanged, the
    lower of the two; inf with fewer than min_common shared joints, and for pairs not listed
    (see association.affinity.epipolar_costs)."""
    cost = np.full((N, N), np.inf)
    J = ok.shape[1]
    for k in range(first.shape[0]):
        n, m = first[k], second[k]
        best = np.inf
        for lab in range(2):
            total = 0.0
            count = 0
            for j in range(J):
                jm = swap[j] if lab == 1 else j
                if ok[n, j] and ok[m, jm]:
                    total += same[k, j] if lab == 0 else cross[k, j]
                    count += 1
            if count >= min_common and count > 0:
                c = total / count
                if np.isfinite(c) and c < best:
                    best = c
        cost[n, m] = cost[m, n] = best
    return cost


@njit(cache=True, error_model="numpy", nogil=True)
def box_diagonals(xy, mask):
    """(N,) diagonal of the box around the masked joints of each detection (N, 17, 2); NaN
    with fewer than two."""
    N, J = mask.shape
    out = np.full(N, np.nan)
    for n in range(N):
        x0 = y0 = np.inf
        x1 = y1 = -np.inf
        k = 0
        for j in range(J):
            if mask[n, j]:
                x, y = xy[n, j, 0], xy[n, j, 1]
                x0, x1 = min(x0, x), max(x1, x)
                y0, y1 = min(y0, y), max(y1, y)
                k += 1
        if k >= 2:
            out[n] = np.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def floor_points(X, left_hip, right_hip):
    """(P, 2) floor point of people (P, J, 3): the mid-hip x-y, or the mean x-y of the joints
    known (NaN when none is); see tracking.positioning.floor_position."""
    P, J = X.shape[0], X.shape[1]
    out = np.full((P, 2), np.nan)
    for p in range(P):
        mx = 0.5 * (X[p, left_hip, 0] + X[p, right_hip, 0])
        my = 0.5 * (X[p, left_hip, 1] + X[p, right_hip, 1])
        if np.isfinite(mx) and np.isfinite(my):
            out[p, 0], out[p, 1] = mx, my
            continue
        sx = sy = 0.0
        k = 0
        for j in range(J):
            if np.isfinite(X[p, j, 0]) and np.isfinite(X[p, j, 1]):
                sx += X[p, j, 0]
                sy += X[p, j, 1]
                k += 1
        if k:
            out[p, 0], out[p, 1] = sx / k, sy / k
    return out
