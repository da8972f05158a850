"""Cross-camera affinity of 2D people from the epipolar constraint.

The reference criterion is the mean distance of a person's joints to the epipolar lines of the
candidate's joints. Here it is symmetric and divided by the person's size in each image, so a
near person (large in the image) and a far one (small) are judged on the same scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stereopose.geometry.camera import homogeneous, undistort_normalized
from stereopose.skeleton import NUM_JOINTS, SWAP
from stereopose.types import People2D, Rig


@dataclass(frozen=True, eq=False)
class Detections:
    """All 2D people of one frame, flattened over cameras (N detections in all).

    camera: (N,) rig camera index; index: (N,) index within that camera's list.
    pixels: (N, 17, 2) distorted pixels; xy: (N, 17, 2) ideal normalised coordinates.
    conf: (N, 17); size: (N,) diagonal of the confident joints' box in normalised units;
    size_px: (N,) the same in pixels.
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
        cams, idx, px, xy = [], [], [], []
        for c, p in enumerate(people):
            if p is None or len(p) == 0:
                continue
            kp = p.keypoints
            cams.append(np.full(len(p), c))
            idx.append(np.arange(len(p)))
            px.append(kp)
            xy.append(undistort_normalized(kp[..., :2], rig[c]))
        if not cams:
            z = np.zeros((0, NUM_JOINTS))
            return cls(
                np.zeros(0, int), np.zeros(0, int), np.zeros((0, NUM_JOINTS, 2)),
                np.zeros((0, NUM_JOINTS, 2)), z, np.zeros(0), np.zeros(0),
            )  # fmt: skip
        kp = np.concatenate(px)
        conf = kp[..., 2]
        xyn = np.concatenate(xy)
        return cls(
            np.concatenate(cams),
            np.concatenate(idx),
            kp[..., :2],
            xyn,
            conf,
            _box_diagonal(xyn, conf >= min_conf),
            _box_diagonal(kp[..., :2], conf >= min_conf),
        )


def _box_diagonal(xy: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N, 17, 2), (N, 17) -> (N,) diagonal of the box around the masked joints (NaN if < 2)."""
    with np.errstate(invalid="ignore"):
        lo = np.where(mask[..., None], xy, np.inf).min(axis=1)
        hi = np.where(mask[..., None], xy, -np.inf).max(axis=1)
        d = np.hypot(*(hi - lo).T)
    return np.where(mask.sum(axis=1) >= 2, d, np.nan)


def epipolar_costs(
    det: Detections, E: np.ndarray, min_conf: float, min_common_joints: int
) -> np.ndarray:
    """(N, N) symmetric matching cost between all detections of one frame.

    E: (C, C, 3, 3) essential matrices of the rig (E[a, b] maps normalised points of camera a to
    lines in camera b). Cost = mean over joints confident (>= min_conf) in both detections of the
    symmetric epipolar distance, each side divided by that detection's size, the lower of that
    and the same with one side's left/right labels exchanged. Pairs in the same
    camera, or with fewer than `min_common_joints` shared joints, cost inf.
    """
    N = len(det)
    if N == 0:
        return np.zeros((0, 0))
    Enm = E[det.camera[:, None], det.camera[None, :]]  # (N, N, 3, 3)
    h = homogeneous(np.nan_to_num(det.xy))
    # lines in m's image of n's joints: l[n, m, j] = E[n, m] @ h[n, j]; the numerator
    # |h_m^T E h_n| is the same seen from either image, only the line norms differ.
    lines = np.matmul(h[:, None], Enm.swapaxes(-1, -2))  # (N, N, 17, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv_m = 1.0 / np.hypot(lines[..., 0], lines[..., 1])
    inv_n = inv_m.transpose(1, 0, 2)
    s = np.where(det.size > 0, det.size, np.nan)
    inv_sm, inv_sn = 1.0 / s[None, :, None], 1.0 / s[:, None, None]
    ok = det.conf >= min_conf
    cost = None
    # Joint j of n against joint j of m, and against its mirror: detectors swap left and
    # right, and a swapped detection is still the same person.
    for perm in (None, SWAP):
        hm = h if perm is None else h[:, perm]
        num = np.abs((lines * hm[None]).sum(-1))
        both = ok[:, None, :] & (ok if perm is None else ok[:, perm])[None, :, :]
        with np.errstate(invalid="ignore", divide="ignore"):
            d = (
                0.5
                * num
                * (inv_m * inv_sm + (inv_n if perm is None else inv_n[:, :, perm]) * inv_sn)
            )
            count = both.sum(axis=-1)
            c = np.where(both, d, 0.0).sum(axis=-1) / count
        c[(count < min_common_joints) | ~np.isfinite(c)] = np.inf
        cost = c if cost is None else np.minimum(cost, c)
    cost[det.camera[:, None] == det.camera[None, :]] = np.inf
    return cost
