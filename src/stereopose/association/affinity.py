"""Cross-camera affinity of 2D people from the epipolar constraint.

The reference criterion is the mean distance of a person's joints to the epipolar lines of the
candidate's joints. Here it is symmetric and divided by the person's size in each image, so a
near person (large in the image) and a far one (small) are judged on the same scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stereopose.association._kernels import box_diagonals, epipolar_pair_distances, pair_costs
from stereopose.association.grouping import upper_pairs
from stereopose.geometry._kernels import undistort
from stereopose.geometry.camera import UNDISTORT_STOP
from stereopose.skeleton import NUM_JOINTS, SWAP
from stereopose.types import People2D, Rig


@dataclass(frozen=True, eq=False)
class Detections:
    """All 2D people of one frame, flattened over cameras (N detections in all).

    camera: (N,) rig camera index; index: (N,) index within that camera's list.
    pixels: (N, 17, 2) distorted pixels; xy: (N, 17, 2) ideal normalised coordinates.
    conf: (N, 17); size: (N,) diagonal of the confident joints' box in normalised units;
    size_px: (N,) the same in pixels of the undistorted image.
    """

    camera: np.ndarray
    index: np.ndarray
    pixels: np.ndarray
    xy: np.ndarray
    conf: np.ndarray
    size: np.ndarray
    size_px: np.ndarray

    def __len__(self) -> int:
        return int(self.camera.shape[0])

    @classmethod
    def from_people(
        cls, rig: Rig, people: Sequence[People2D | None], min_conf: float
    ) -> Detections:
        """Gather one frame; people[c] belongs to rig camera c (None or empty: no detection)."""
        present = [(c, p) for c, p in enumerate(people) if p is not None and p.keypoints.shape[0]]
        cams = [c for c, _ in present]
        if not cams:
            z = np.zeros((0, NUM_JOINTS))
            e = np.zeros((0, NUM_JOINTS, 2))
            return cls(np.zeros(0, int), np.zeros(0, int), e, e, z, np.zeros(0), np.zeros(0))
        blocks = [p.keypoints for _, p in present]
        counts = [b.shape[0] for b in blocks]
        kp = np.concatenate(blocks)
        # a frame's few detections: their camera and index within it, in plain Python
        camera = np.array([c for c, n in zip(cams, counts, strict=True) for _ in range(n)])
        index = np.array([i for n in counts for i in range(n)])
        fxy, dist, focal = rig.lenses
        uv = np.ascontiguousarray(kp[..., :2]).reshape(-1, 2)
        xyn = undistort(uv, np.repeat(camera, NUM_JOINTS), fxy, dist, *UNDISTORT_STOP)
        xyn = xyn.reshape(kp.shape[0], NUM_JOINTS, 2)
        conf = kp[..., 2]
        size = _box_diagonal(xyn, conf >= min_conf)
        # pixels of the undistorted image: close enough for thresholds scaled by person size
        return cls(camera, index, kp[..., :2], xyn, conf, size, size * focal[camera])


def _box_diagonal(xy: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N, 17, 2), (N, 17) -> (N,) diagonal of the box around the masked joints (NaN if < 2)."""
    return box_diagonals(np.ascontiguousarray(xy), np.ascontiguousarray(mask))


@dataclass(frozen=True, eq=False)
class PairDistances:
    """Per-joint epipolar distances of every pair of detections in different cameras.

    first, second: (M,) detection indices (first < second); row: (N, N) index into the M pairs
    (-1 for none), symmetric. same: (M, 17) symmetric epipolar distance of joint j of `first` to
    joint j of `second`, each side divided by its detection's size; cross: (M, 17) the same
    against the mirror joint SWAP[j] of `second`.
    """

    first: np.ndarray
    second: np.ndarray
    row: np.ndarray
    same: np.ndarray
    cross: np.ndarray


def epipolar_distances(
    det: Detections, E: np.ndarray, pairs: tuple[np.ndarray, np.ndarray] | None = None
) -> PairDistances:
    """Per-joint normalised epipolar distances of all cross-camera detection pairs.

    E: (C, C, 3, 3) essential matrices of the rig (E[a, b] maps normalised points of camera a to
    lines in camera b). pairs: only these detection pairs (n < m), when not all are needed.
    """
    N = len(det)
    n, m = upper_pairs(N) if pairs is None else pairs
    keep = det.camera[n] != det.camera[m]
    n, m = n[keep], m[keep]
    row = np.full((N, N), -1, dtype=np.int64)
    row[n, m] = row[m, n] = np.arange(n.size)
    xy = np.where(np.isfinite(det.xy), det.xy, 0.0)  # missing joints never vote
    same, cross = epipolar_pair_distances(
        xy, det.size, det.camera, E, n.astype(np.int64), m.astype(np.int64), SWAP
    )
    return PairDistances(n, m, row, same, cross)


def epipolar_costs(
    det: Detections, dist: PairDistances, min_conf: float, min_common_joints: int
) -> np.ndarray:
    """(N, N) symmetric matching cost between all detections of one frame.

    Cost = mean over joints confident (>= min_conf) in both detections of the normalised
    symmetric epipolar distance (see epipolar_distances), the lower of that and the same with
    one side's left/right labels exchanged: detectors swap left and right, and a swapped
    detection is still the same person. Pairs in the same camera, or with fewer than
    `min_common_joints` shared joints, cost inf.
    """
    return pair_costs(
        len(det),
        dist.first,
        dist.second,
        dist.same,
        dist.cross,
        np.ascontiguousarray(det.conf >= min_conf),
        SWAP,
        min_common_joints,
    )
