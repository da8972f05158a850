"""Left/right labels: making the views of a person agree, and the skeleton's handedness.

Detectors swap a person's left and right (the whole body, or the legs alone), most often in
views of the person's back. The labels of all views are made consistent from the epipolar
distances (consistent_labels); in 3D, a skeleton whose face is behind its shoulders is mirrored
as a whole (body_orientation), and a limb hanging from the other side's joint is exchanged
(mirrored_pairs).
"""

from __future__ import annotations

import functools

import numpy as np

from stereopose.arrays import checked
from stereopose.association.grouping import upper_pairs
from stereopose.reconstruction._kernels import body_orientation as _body_orientation_loop
from stereopose.reconstruction._kernels import chain_flips
from stereopose.skeleton import JOINT_PARTS, LEFT, LR_PAIRS, PART_OF_PAIR, RIGHT, SWAP, joint_table

# Limb joints and the trunk joints they hang from, as (parent left, parent right, child left,
# child right) rows: shoulders-elbows, hips-knees, then elbows-wrists, knees-ankles.
_CHAINS = joint_table(
    ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow"),
    ("left_hip", "right_hip", "left_knee", "right_knee"),
    ("left_elbow", "right_elbow", "left_wrist", "right_wrist"),
    ("left_knee", "right_knee", "left_ankle", "right_ankle"),
)
_PAIR_OFLEFT = np.zeros(len(SWAP), dtype=np.int64)  # pair index of LR_PAIRS, by its left joint
_PAIR_OFLEFT[LEFT] = np.arange(len(LR_PAIRS))


def mirrored_pairs(X: np.ndarray, margin_m: float = 0.05) -> np.ndarray:
    """(G, 8) left/right pairs of LR_PAIRS whose 3D points are exchanged: the whole body
    (or the legs) by its handedness (see _body_orientation), then each limb joint by which
    parent joint it hangs from (each child is nearer its own parent than the other side's),
    the trunk first, so a corrected elbow is what its wrist is checked against."""
    flip_upper, flip_legs = body_orientation(X)
    swap = np.where(PART_OF_PAIR == 0, flip_upper[:, None], flip_legs[:, None])
    if swap.any():
        X = exchange_joints(X, swap)
    for level in (_CHAINS[:2], _CHAINS[2:]):
        flip = chain_flips(X, level, margin_m)  # (G, 2)
        if flip.any():
            pairs = np.zeros_like(swap)
            pairs[:, _PAIR_OFLEFT[level[:, 2]]] = flip
            X = exchange_joints(X, pairs)
            swap ^= pairs
    return swap


def exchange_joints(a: np.ndarray, swap: np.ndarray) -> np.ndarray:
    """Copy of a (G, 17, ...) with the pairs of LR_PAIRS exchanged where swap (G, 8)."""
    a = a.copy()
    m = swap.reshape(*swap.shape, *([1] * (a.ndim - 2)))
    al, ar = a[:, LEFT], a[:, RIGHT]
    a[:, LEFT], a[:, RIGHT] = np.where(m, ar, al), np.where(m, al, ar)
    return a


@functools.lru_cache(maxsize=16)
def _labelings(C: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z (2^C, C): every assignment of 'swapped' (1) or 'as detected' (0) to C views; and per
    camera pair (a < b), (K, 2^C) whether a labeling keeps (same labels) or crosses the pair."""
    Z = (np.arange(2**C)[:, None] >> np.arange(C)[None, :]) & 1
    ka, kb = upper_pairs(C)
    rel = (Z[:, ka] ^ Z[:, kb]).astype(np.float64)
    return Z, np.ascontiguousarray((1.0 - rel).T), np.ascontiguousarray(rel.T)


def consistent_labels(
    xy: np.ndarray, w: np.ndarray, d_same: np.ndarray, d_cross: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Exchange left/right labels of views so that all views of a person agree.

    d_same, d_cross: (G, 17, K) epipolar distances of joint j in camera a to joint j (same) or
    to its mirror (cross) in camera b, for the camera pairs (a < b). For every body part, the
    labeling of all views that minimises the total distance wins; of a labeling and its mirror
    (equal cost), the one exchanging the views with the fainter face (a back view, where
    detectors swap sides). This needs no 3D point; _body_orientation settles the mirror in 3D.
    """
    C = xy.shape[2]
    ka, kb = upper_pairs(C)
    Z, keep_T, rel_T = _labelings(C)
    ok = w > 0
    both = ok[:, :, ka] & ok[:, :, kb] & ok[:, SWAP][:, :, kb]  # (G, 17, K)
    both &= np.isfinite(d_same) & np.isfinite(d_cross)  # pairs not measured do not vote
    # per body part p: total distance of all its joints, (G, 2, K)
    same = np.einsum("gjk,jp->gpk", np.where(both, d_same, 0.0), JOINT_PARTS)
    cross = np.einsum("gjk,jp->gpk", np.where(both, d_cross, 0.0), JOINT_PARTS)
    cost = same @ keep_T + cross @ rel_T  # (G, 2, L)
    present = np.einsum("gjc,jp->gpc", ok.astype(np.float64), JOINT_PARTS) > 0  # (G, 2, C)
    # A labeling and its mirror cost the same: prefer exchanging the views that see the
    # person's back (faint face), where detectors swap sides, and then fewer views.
    face = w[:, :3].mean(1)  # (G, C) nose and eyes
    cost += 1e-6 * ((present * (face + 0.01)[:, None]) @ Z.T)
    swap = Z[np.argmin(cost, axis=-1)].astype(bool) & present  # (G, 2, C)
    return exchange(xy, w, swap[:, PART_OF_PAIR])


def exchange(xy: np.ndarray, w: np.ndarray, swap: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Copies of xy (G, J, C, 2), w (G, J, C) with each left/right pair of LR_PAIRS exchanged
    in the views where swap (G, 8, C) is true."""
    if not swap.any():
        return xy, w
    xy, w = xy.copy(), w.copy()
    xl, xr, wl, wr = xy[:, LEFT], xy[:, RIGHT], w[:, LEFT], w[:, RIGHT]
    m = swap[..., None]
    xy[:, LEFT] = np.where(m, xr, xl)
    xy[:, RIGHT] = np.where(m, xl, xr)
    w[:, LEFT] = np.where(swap, wr, wl)
    w[:, RIGHT] = np.where(swap, wl, wr)
    return xy, w


# A nose this far from the midpoint of the ears (or eyes), or ears this far apart, is a joint
# triangulated from a misplaced view, not a head: it is left out of the orientation test.
_HEAD_RADIUS_M = 0.25
_HEAD_WIDTH_M = 0.3


def body_orientation(
    X: np.ndarray, face_margin_m: float = 0.03, thigh_margin_m: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """Which people's labels are mirrored as a whole (G,) each: flip_upper, flip_legs.

    Views alone cannot tell a labeling from its mirror when as many views are swapped as not.
    In 3D they can: with z up and front = up x right, right being the body's left-to-right
    axis (right shoulder - left shoulder plus right hip - left hip), the face lies in front of
    the shoulders and the nose in front of the ears (or eyes). The two leads are added, so a
    head and shoulders seen from two close views, whose depth is noisy, are judged together;
    a nose away from the head (see _HEAD_RADIUS_M) takes part in neither, and without
    shoulders or hips the head's own axis (right ear - left ear) gives front. Each knee is
    nearer its own hip. X: (G, 17, 3).
    """
    X = checked(X, "X", (None, len(SWAP), 3))
    return _body_orientation_loop(X, face_margin_m, thigh_margin_m, _HEAD_RADIUS_M, _HEAD_WIDTH_M)
