"""Per-person limb lengths: a running estimate, and joints moved to keep them.

A person's upper arms, forearms, thighs and shins do not change length, but joints
triangulated independently in each frame make them wobble. Each tracked person keeps a running
mean of each limb's measured length (outliers ignored); the smoothed joints are then moved
along each limb, from the trunk outwards, to that length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereopose.arrays import checked, checked_rows
from stereopose.skeleton import NUM_JOINTS, joint_index
from stereopose.tracking._kernels import bones_apply, bones_observe

# parent -> child, trunk outwards: the upper limbs first, then the ones hanging from them
_LIMBS = [
    ("left_shoulder", "left_elbow"),
    ("right_shoulder", "right_elbow"),
    ("left_hip", "left_knee"),
    ("right_hip", "right_knee"),
    ("left_elbow", "left_wrist"),
    ("right_elbow", "right_wrist"),
    ("left_knee", "left_ankle"),
    ("right_knee", "right_ankle"),
]
PARENT = np.array([joint_index(a) for a, _ in _LIMBS])
CHILD = np.array([joint_index(b) for _, b in _LIMBS])


@dataclass
class BoneLengths:
    """Running limb lengths of T people: length (T, 8) metres (NaN: unknown), count (T, 8).

    window: the running mean becomes an exponential one over about this many samples.
    min_samples: lengths are enforced once this many samples were averaged.
    outlier: a sample this far from the estimate (fraction of it) is ignored.
    """

    length: np.ndarray
    count: np.ndarray
    window: int = 50
    min_samples: int = 10
    outlier: float = 0.2

    @classmethod
    def empty(cls) -> BoneLengths:
        return cls(np.zeros((0, len(_LIMBS))), np.zeros((0, len(_LIMBS)), dtype=np.int64))

    def append(self, n: int) -> None:
        self.length = np.concatenate([self.length, np.full((n, len(_LIMBS)), np.nan)])
        self.count = np.concatenate([self.count, np.zeros((n, len(_LIMBS)), np.int64)])

    def keep(self, mask: np.ndarray) -> None:
        self.length, self.count = self.length[mask], self.count[mask]

    def reset(self, rows: np.ndarray) -> None:
        self.length[rows] = np.nan
        self.count[rows] = 0

    def observe(self, rows: np.ndarray, joints: np.ndarray) -> None:
        """Add the limb lengths of measured joints (n, 17, 3) of people `rows`."""
        rows = checked_rows(rows, len(self.length))
        bones_observe(
            self.length,
            self.count,
            rows,
            checked(joints, "joints", (rows.size, NUM_JOINTS, 3)),
            PARENT,
            CHILD,
            self.window,
            self.min_samples,
            self.outlier,
        )

    def apply(self, rows: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Copy of joints (n, 17, 3) with each known limb set to its estimated length."""
        rows = checked_rows(rows, len(self.length))
        X = checked(joints, "joints", (rows.size, NUM_JOINTS, 3)).copy()
        bones_apply(
            X,
            self.length,
            self.count,
            rows,
            PARENT,
            CHILD,
            self.min_samples,
        )
        return X
