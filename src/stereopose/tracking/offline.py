"""Offline two-way smoothing of tracked joints, for analysis exports.

The online filter (tracking.filter) may only use the past: an alarm cannot wait for the future.
Analysis can: a Rauch-Tung-Striebel smoother runs the same constant-velocity model forward over
a track's measurements and then backward, so each joint's estimate at a frame uses the frames
after it too. It has no lag, and less noise than the online filter. The measurements are the
ones the online filter took (after its gate: a joint it did not believe is not used here either,
and a joint it restarted starts a new segment that is not smoothed across).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from stereopose.skeleton import NUM_JOINTS
from stereopose.tracking._kernels import kalman_replay

if TYPE_CHECKING:
    from stereopose.types import People3D

# what the online filter did with a joint's measurement
NOT_USED, ACCEPTED, RESTARTED = 0, 1, 2


@dataclass
class TrackLog:
    """One track's measurements as the online filter took them, frame by frame.

    frames: frame numbers (increasing); z: (17, 3) measured joints (NaN: none); used: (17,)
    NOT_USED, ACCEPTED or RESTARTED; noise: (17,) measurement standard deviations (m).
    """

    frames: list[int] = field(default_factory=list)
    z: list[np.ndarray] = field(default_factory=list)
    used: list[np.ndarray] = field(default_factory=list)
    noise: list[np.ndarray] = field(default_factory=list)

    def add(self, frame: int, z: np.ndarray, used: np.ndarray, noise: np.ndarray) -> None:
        self.frames.append(int(frame))
        self.z.append(np.asarray(z, dtype=np.float64))
        self.used.append(np.asarray(used, dtype=np.int8))
        self.noise.append(np.asarray(noise, dtype=np.float64))


def smooth_track(
    log: TrackLog, fps: float, q: np.ndarray, initial_speed_mps: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Two-way smoothed joints of one track.

    q: (17,) acceleration spectral density per joint (m^2/s^3), as the online filter's.
    Returns (frames (K,), joints (K, 17, 3)), NaN before a joint's first measurement and after
    its last (the smoother does not extrapolate beyond the data).
    """
    K = len(log.frames)
    frames = np.asarray(log.frames, dtype=np.int64)
    if K == 0:
        return frames, np.zeros((0, NUM_JOINTS, 3))
    t = frames / float(fps)
    z = np.stack(log.z)
    code = np.stack(log.used)
    r2 = np.stack(log.noise) ** 2
    q = np.broadcast_to(np.asarray(q, dtype=np.float64), (NUM_JOINTS,))
    v0 = initial_speed_mps**2
    # forward pass: the online filter's steps again, filtered and predicted states kept
    x, v, P, xp, vp, Pp, start = kalman_replay(
        np.ascontiguousarray(z),
        np.ascontiguousarray(code),
        np.ascontiguousarray(r2),
        t,
        np.ascontiguousarray(q),
        v0,
    )
    # the last measurement of each joint: beyond it there is nothing to smooth towards
    measured = code > NOT_USED
    last = np.where(measured.any(0), K - 1 - np.argmax(measured[::-1], axis=0), -1)
    first = np.where(measured.any(0), np.argmax(measured, axis=0), K)
    # backward pass (Rauch-Tung-Striebel), positions and velocities
    xs, vs = x.copy(), v.copy()
    for k in range(K - 2, -1, -1):
        dt = t[k + 1] - t[k]
        f00, f01, f11 = P[k]
        p00, p01, p11 = Pp[k + 1]
        # C = P_f F^T Pp^-1 with F = [[1, dt], [0, 1]]
        a00, a01 = f00 + dt * f01, f01
        a10, a11 = f01 + dt * f11, f11
        det = p00 * p11 - p01 * p01
        with np.errstate(invalid="ignore", divide="ignore"):
            i00, i01, i11 = p11 / det, -p01 / det, p00 / det
        C00, C01 = a00 * i00 + a01 * i01, a00 * i01 + a01 * i11
        C10, C11 = a10 * i00 + a11 * i01, a10 * i01 + a11 * i11
        dx = xs[k + 1] - xp[k + 1]
        dv = vs[k + 1] - vp[k + 1]
        ok = ~start[k + 1] & np.isfinite(x[k, :, 0]) & np.isfinite(dx[:, 0]) & (det > 0)
        o = ok[:, None]
        xs[k] = np.where(o, x[k] + C00[:, None] * dx + C01[:, None] * dv, x[k])
        vs[k] = np.where(o, v[k] + C10[:, None] * dx + C11[:, None] * dv, v[k])
    steps = np.arange(K)[:, None]
    outside = (steps < first[None]) | (steps > last[None])  # (K, 17)
    xs[outside] = np.nan
    return frames, xs


def smooth_people(
    people_frames: Sequence[People3D], logs: dict[int, TrackLog], fps: float, q: np.ndarray
) -> list[People3D]:
    """The tracked people of every frame with their joints two-way smoothed.

    people_frames: the online output (People3D per frame, ids persistent); logs: per id, the
    measurements its track took. A joint the online output left out (NaN) stays out; people
    without a log keep their online joints. Returns new People3D objects.
    """
    smoothed: dict[int, dict[int, np.ndarray]] = {}
    for i, log in logs.items():
        frames, joints = smooth_track(log, fps, q)
        smoothed[i] = {int(f): joints[k] for k, f in enumerate(frames)}
    out = []
    for people in people_frames:
        X = people.joints.copy()
        for p in range(len(people)):
            s = smoothed.get(int(people.ids[p]), {}).get(int(people.frame))
            if s is not None:
                keep = np.isfinite(X[p]).all(-1) & np.isfinite(s).all(-1)
                X[p] = np.where(keep[:, None], s, X[p])
        out.append(dataclasses.replace(people, joints=X))
    return out
