"""Online (causal) smoothing of 3D joints: a constant-velocity Kalman filter per joint.

Every joint of every tracked person is filtered at once. The model is isotropic (the same
noise along x, y and z), so each joint's covariance is one symmetric 2x2 matrix (position,
velocity) shared by its three axes: states are (T, 17, 3) positions and velocities, covariances
three (T, 17) arrays p00, p01, p11.

A measured joint farther from its prediction than the gate (a detector's jump, a joint given
to the wrong person) is not believed, unless it stays there for `gate_reset_frames` frames in a
row: then the joint restarts from the measurement. Nothing here looks at future frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereopose.arrays import checked, checked_rows
from stereopose.skeleton import NUM_JOINTS
from stereopose.tracking._kernels import kalman_predict, kalman_update

_INITIAL_SPEED_MPS = 1.0  # prior standard deviation of a new joint's velocity


@dataclass
class JointFilters:
    """Kalman states of T people x 17 joints; NaN position where a joint was never seen.

    rejected: (T, 17) consecutive frames each joint's measurement was gated out.
    """

    x: np.ndarray
    v: np.ndarray
    p00: np.ndarray
    p01: np.ndarray
    p11: np.ndarray
    rejected: np.ndarray

    @classmethod
    def empty(cls) -> JointFilters:
        z3 = np.zeros((0, NUM_JOINTS, 3))
        z = np.zeros((0, NUM_JOINTS))
        return cls(z3, z3.copy(), z, z.copy(), z.copy(), z.astype(np.int64))

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def append(self, joints: np.ndarray, noise_m: float) -> None:
        """Add people starting at `joints` (n, 17, 3) (NaN: not seen yet), at rest."""
        n = joints.shape[0]
        seen = np.asarray(np.isfinite(joints).all(-1))
        self.x = np.concatenate([self.x, np.where(seen[..., None], joints, np.nan)])
        self.v = np.concatenate([self.v, np.zeros((n, NUM_JOINTS, 3))])
        self.p00 = np.concatenate([self.p00, np.full((n, NUM_JOINTS), noise_m**2)])
        self.p01 = np.concatenate([self.p01, np.zeros((n, NUM_JOINTS))])
        self.p11 = np.concatenate([self.p11, np.full((n, NUM_JOINTS), _INITIAL_SPEED_MPS**2)])
        self.rejected = np.concatenate([self.rejected, np.zeros((n, NUM_JOINTS), np.int64)])

    def keep(self, mask: np.ndarray) -> None:
        """Keep only the people where mask (T,) is true."""
        for name in ("x", "v", "p00", "p01", "p11", "rejected"):
            setattr(self, name, getattr(self, name)[mask])

    def predict(
        self, dt: np.ndarray | float, q: np.ndarray | float, moving: np.ndarray | None = None
    ) -> None:
        """Advance every state by dt seconds (scalar or (T,)).

        q: acceleration spectral density (m^2/s^3) of the white-noise acceleration model,
        scalar or per joint (17,).
        moving: (T,) false for people whose velocity is no longer trusted (unseen too long):
        they are held where they were, with the uncertainty still growing.
        """
        T = len(self)
        dt = np.array(np.broadcast_to(np.asarray(dt, dtype=np.float64), (T,)))  # writable
        q = np.ascontiguousarray(np.broadcast_to(np.asarray(q, dtype=np.float64), (NUM_JOINTS,)))
        moving = np.ones(T, dtype=bool) if moving is None else np.asarray(moving, dtype=bool)
        kalman_predict(self.x, self.v, self.p00, self.p01, self.p11, dt, q, moving)

    def update(
        self,
        rows: np.ndarray,
        z: np.ndarray,
        noise_m: np.ndarray | float,
        gate_m: float,
        gate_sigmas: float,
        reset_frames: int,
    ) -> np.ndarray:
        """Correct people `rows` (n,) with measured joints z (n, 17, 3) (NaN: not measured).

        noise_m: measurement standard deviation, scalar or (n, 17). Returns (n, 17) int8, what
        became of each joint's measurement: 0 not used (missing or gated out), 1 accepted,
        2 restarted the joint (true where used).
        """
        rows = checked_rows(rows, len(self))
        z = checked(z, "z", (rows.size, NUM_JOINTS, 3))
        r2 = np.ascontiguousarray(
            np.broadcast_to(np.asarray(noise_m, dtype=np.float64) ** 2, (rows.size, NUM_JOINTS))
        )
        return kalman_update(
            self.x,
            self.v,
            self.p00,
            self.p01,
            self.p11,
            self.rejected,
            rows,
            z,
            r2,
            float(gate_m),
            float(gate_sigmas),
            int(reset_frames),
            _INITIAL_SPEED_MPS**2,
        )

    def reset(self, rows: np.ndarray, z: np.ndarray, noise_m: float) -> None:
        """Restart people `rows` at the measured joints z (n, 17, 3), at rest."""
        seen = np.asarray(np.isfinite(z).all(-1))
        self.x[rows] = np.where(seen[..., None], z, np.nan)
        self.v[rows] = 0.0
        self.p00[rows] = noise_m**2
        self.p01[rows] = 0.0
        self.p11[rows] = _INITIAL_SPEED_MPS**2
        self.rejected[rows] = 0
