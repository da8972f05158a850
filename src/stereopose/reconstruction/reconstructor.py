"""One frame's 2D people of every camera -> that frame's 3D people."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from stereopose.association.affinity import (
    Detections,
    PairDistances,
    epipolar_costs,
    epipolar_distances,
)
from stereopose.association.grouping import group_detections, upper_pairs
from stereopose.config import ReconstructionConfig
from stereopose.errors import CalibrationError
from stereopose.geometry.camera import project_to_cameras
from stereopose.geometry.epipolar import essential_matrices
from stereopose.geometry.triangulation import dlt_blocks
from stereopose.reconstruction.triangulate import (
    pair_views,
    reprojection_errors,
    triangulate_pair,
    triangulate_robust,
    triangulate_weighted,
)
from stereopose.skeleton import NUM_JOINTS, PCP_LIMBS
from stereopose.types import People2D, People3D, Rig

_LIMB_A = np.array([a for a, _ in PCP_LIMBS])
_LIMB_B = np.array([b for _, b in PCP_LIMBS])


def _group_pair_distances(members: np.ndarray, dist: PairDistances):
    """Per group and camera pair (a < b), the per-joint epipolar distances of its detections.

    members: (G, C) detection index per camera (-1: none). Returns same, cross (G, 17, K) with
    NaN where the group lacks either camera; cross pairs joint j in a with SWAP[j] in b.
    """
    C = members.shape[1]
    ka, kb = upper_pairs(C)
    na, nb = members[:, ka], members[:, kb]  # (G, K)
    row = np.where((na >= 0) & (nb >= 0), dist.row[na, nb], -1)
    pad = np.full((1, NUM_JOINTS), np.nan)  # row -1 picks this
    same = np.concatenate([dist.same, pad])[row].transpose(0, 2, 1)
    cross = np.concatenate([dist.cross, pad])[row].transpose(0, 2, 1)
    return same, cross


class Reconstructor:
    """Associates and triangulates the people of one frame; one call per frame.

    The rig's cameras and the options are fixed at construction; everything that depends only on
    them (essential matrices, camera matrices) is computed once here.
    """

    def __init__(self, rig: Rig, config: ReconstructionConfig | None = None) -> None:
        fisheye = [c.name for c in rig if c.fisheye]
        if fisheye:
            raise CalibrationError(
                f"camera(s) {', '.join(fisheye)}: fisheye lens models are not supported; "
                "calibrate with the pinhole model (k1 k2 p1 p2)"
            )
        self.rig = rig
        self.config = config or ReconstructionConfig()
        self.P = np.stack([c.P for c in rig])
        self.E = essential_matrices(rig)
        self.focal = np.array([c.focal for c in rig])
        self.blocks = dlt_blocks(self.P)
        # image bounds in normalised coordinates, (C, 2) each
        size = np.array([c.size for c in rig])
        K = np.stack([c.matrix for c in rig])
        centre, f = K[:, :2, 2], np.stack([K[:, 0, 0], K[:, 1, 1]], axis=-1)
        self.bounds = (-centre / f, (size - centre) / f)
        self.pair_blocks = dlt_blocks(self.P[pair_views(len(rig))])

    def __call__(
        self, frame: int, people: Mapping[str, People2D] | Sequence[People2D | None]
    ) -> People3D:
        """3D people of one frame.

        people: per camera name (missing cameras: no frame) or a sequence in rig order.
        """
        if isinstance(people, Mapping):
            people = [people.get(name) for name in self.rig.names]
        if len(people) != len(self.rig):
            raise ValueError(f"expected people for {len(self.rig)} cameras, got {len(people)}")
        ac = self.config.association
        det = Detections.from_people(self.rig, people, ac.min_conf)
        if len(det) < 2:
            return People3D.empty(frame, len(self.rig))
        dist = epipolar_distances(det, self.E)
        cost = epipolar_costs(det, dist, ac.min_conf, ac.min_common_joints)
        groups = group_detections(cost, det.camera, ac.max_cost)
        if not groups:
            return People3D.empty(frame, len(self.rig))
        tri = self._triangulate(det, groups, dist)
        grown = self._reassign(det, groups, tri[0]) if ac.reassign_leftovers else []
        if grown:
            redo = self._triangulate(det, [groups[i] for i in grown], dist)
            for full, part in zip(tri, redo, strict=True):
                full[grown] = part
        X, used, conf, err, members = tri
        delivered = np.array([p is not None for p in people])
        return self._assemble(frame, det, members, delivered, X, used, conf, err)

    # -- steps ---------------------------------------------------------------------------------

    def _gather(self, det: Detections, groups: list[np.ndarray]):
        G, C = len(groups), len(self.rig)
        gi = np.concatenate([np.full(len(g), i) for i, g in enumerate(groups)])
        di = np.concatenate(groups)
        ci = det.camera[di]
        xy = np.full((G, C, NUM_JOINTS, 2), np.nan)
        conf = np.zeros((G, C, NUM_JOINTS))
        size_px = np.full((G, C), np.nan)
        members = np.full((G, C), -1, dtype=np.int64)
        xy[gi, ci] = det.xy[di]
        conf[gi, ci] = det.conf[di]
        size_px[gi, ci] = det.size_px[di]
        members[gi, ci] = di
        # to (G, 17, C, ...) as the triangulation functions expect
        return xy.transpose(0, 2, 1, 3), conf.transpose(0, 2, 1), size_px, members

    def _triangulate(self, det: Detections, groups: list[np.ndarray], dist: PairDistances):
        tc = self.config.triangulation
        xy, conf, size_px, members = self._gather(det, groups)
        w = np.where(conf >= tc.min_conf, conf, 0.0)
        err = None
        if tc.mode == "pair":
            X, used = triangulate_pair(
                xy,
                w,
                conf,
                self.P,
                self.E,
                self.focal,
                tc.pair_a,
                tc.pair_b,
                self.config.association.min_common_joints,
            )
        elif tc.mode == "weighted":
            X, used = triangulate_weighted(xy, w, self.P)
        else:
            X, used, xy, w, err = triangulate_robust(
                xy,
                w,
                self.P,
                self.focal,
                size_px,
                tc.inlier_px,
                tc.inlier_rel,
                tc.fix_swaps,
                pair_distances=_group_pair_distances(members, dist),
                blocks=self.blocks,
                pair_blocks=self.pair_blocks,
            )
        out_conf = np.where(used, w, 0.0).sum(-1) / np.maximum(used.sum(-1), 1)
        if err is None:
            err = np.where(used, reprojection_errors(X, xy, self.P, self.focal), np.nan)
        return X, used, out_conf, err, members

    def _reassign(self, det: Detections, groups: list[np.ndarray], X: np.ndarray) -> list[int]:
        """Give detections left out of every group to a reconstructed person they fit.

        Grows `groups` in place; returns the indices of the groups that grew.
        """
        in_group = np.zeros(len(det), dtype=bool)
        in_group[np.concatenate(groups)] = True
        left = np.flatnonzero(~in_group)
        if left.size == 0:
            return []
        ac = self.config.association
        has = np.zeros((len(groups), len(self.rig)), dtype=bool)
        for i, g in enumerate(groups):
            has[i, det.camera[g]] = True
        grown: list[int] = []
        for c in np.unique(det.camera[left]):
            cand = left[det.camera[left] == c]
            open_g = np.flatnonzero(~has[:, c])
            if open_g.size == 0:
                continue
            proj = project_to_cameras(X[open_g], self.P[c : c + 1])[..., 0, :]  # (g, 17, 2)
            d = np.hypot(*np.moveaxis(det.xy[cand][:, None] - proj[None], -1, 0))  # (n, g, 17)
            ok = (det.conf[cand] >= ac.min_conf)[:, None, :] & np.isfinite(d)
            n_ok = ok.sum(-1)
            with np.errstate(invalid="ignore", divide="ignore"):
                cost = np.where(ok, d, 0.0).sum(-1) / n_ok / det.size[cand][:, None]
            cost[(n_ok < ac.min_common_joints) | ~np.isfinite(cost)] = np.inf
            if not np.isfinite(cost).any():
                continue
            r, k = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
            for ri, ki in zip(r, k, strict=True):
                if cost[ri, ki] <= 2.0 * ac.max_cost:
                    gi = open_g[ki]
                    groups[gi] = np.append(groups[gi], cand[ri])
                    has[gi, c] = True
                    grown.append(int(gi))
        return sorted(set(grown))

    def _in_view(self, X: np.ndarray, min_joints: int = 5) -> np.ndarray:
        """(G, C) whether >= min_joints of each person's joints (G, 17, 3) fall inside each
        camera's image, in front of it (distortion ignored: this is a coarse test)."""
        xy = project_to_cameras(X, self.P)  # (G, 17, C, 2)
        lo, hi = self.bounds
        inside = ((xy >= lo) & (xy <= hi)).all(-1)  # NaN (behind, missing) compares False
        return inside.sum(1) >= min_joints

    def _assemble(self, frame, det, members, delivered, X, used, conf, err) -> People3D:
        """Plausible people only, as People3D; members: (G, C) detection per camera or -1."""
        pc = self.config.plausibility
        G, C = members.shape
        X = X.copy()
        # The outer joint of an implausibly long limb is dropped.
        limb = np.linalg.norm(X[:, _LIMB_A] - X[:, _LIMB_B], axis=-1)
        bad = limb > pc.max_limb_m  # NaN compares False
        if bad.any():
            drop = np.zeros((G, NUM_JOINTS), dtype=bool)
            np.logical_or.at(drop, (np.nonzero(bad)[0], _LIMB_B[np.nonzero(bad)[1]]), True)
            X[drop] = np.nan
        valid = np.isfinite(X).all(-1)
        used = used & valid[..., None]
        z = X[..., 2]
        zmin = np.where(valid, z, np.inf).min(axis=1)
        zmax = np.where(valid, z, -np.inf).max(axis=1)
        views = members >= 0
        # A person that cameras with a frame should see but (almost) none detected is a
        # coincidence of false detections that happen to agree, not a person.
        expected = (self._in_view(X) | views) & delivered
        keep = (
            (valid.sum(1) >= pc.min_joints)
            & (zmin >= -pc.floor_tolerance_m)
            & (zmax - zmin <= pc.max_height_m)
            & (views.sum(1) >= pc.min_view_fraction * expected.sum(1))
        )
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            return People3D.empty(frame, C)
        X, used, conf, valid = X[idx], used[idx], conf[idx], valid[idx]
        err = np.where(used, err[idx], np.nan)
        detections = np.where(views[idx], det.index[members[idx]], -1)
        n_used = used.sum(-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            reproj = np.where(used, err, 0.0).sum(-1) / n_used  # NaN where no view
        conf = np.where(valid, conf, 0.0)
        return People3D(
            frame=frame,
            joints=X,
            conf=conf,
            ids=np.arange(idx.size),
            reprojection_px=reproj,
            views=n_used,
            detections=detections,
        )
