"""One frame's 2D people of every camera -> that frame's 3D people."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from stereopose.association.affinity import (
    Detections,
    PairDistances,
    epipolar_costs,
    epipolar_distances,
)
from stereopose.association.assignment import linear_sum_assignment
from stereopose.association.claims import (
    check_groups,
    claim,
    claimed_groups,
    exchanged,
    pairs_within,
)
from stereopose.association.grouping import group_detections, upper_pairs
from stereopose.config import ReconstructionConfig
from stereopose.errors import CalibrationError
from stereopose.geometry.camera import project_to_cameras
from stereopose.geometry.epipolar import essential_matrices
from stereopose.reconstruction._kernels import plausible
from stereopose.reconstruction.triangulate import (
    PairScore,
    Robust,
    reprojection_errors,
    triangulate_pair,
    triangulate_robust,
    triangulate_weighted,
)
from stereopose.skeleton import NUM_JOINTS, PCP_LIMBS
from stereopose.types import People2D, People3D, Rig

_LIMB_A = np.array([a for a, _ in PCP_LIMBS])
_LIMB_B = np.array([b for _, b in PCP_LIMBS])


def _group_pair_distances(
    members: np.ndarray, dist: PairDistances
) -> tuple[np.ndarray, np.ndarray]:
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


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """One frame's 3D people and, per person, the index of the predicted pose that seeded
    them (-1: associated from scratch)."""

    people: People3D
    seeds: np.ndarray


class Reconstructor:
    """Associates and triangulates the people of one frame; holds nothing between frames.

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
        # image bounds in normalised coordinates, (C, 2) each
        size = np.array([c.size for c in rig])
        K = np.stack([c.matrix for c in rig])
        centre, f = K[:, :2, 2], np.stack([K[:, 0, 0], K[:, 1, 1]], axis=-1)
        self.bounds = (-centre / f, (size - centre) / f)
        self.R = self.P[:, :, :3]
        self.centers = np.stack([c.center for c in rig])

    def __call__(
        self,
        frame: int,
        people: Mapping[str, People2D] | Sequence[People2D | None],
        prior: np.ndarray | None = None,
    ) -> People3D:
        """3D people of one frame, ids 0..P-1 (see reconstruct)."""
        return self.reconstruct(frame, people, prior).people

    def reconstruct(
        self,
        frame: int,
        people: Mapping[str, People2D] | Sequence[People2D | None],
        prior: np.ndarray | None = None,
    ) -> Reconstruction:
        """3D people of one frame, seeded by the poses expected in it. Stateless: the same
        frame and prior give the same people.

        people: per camera name (missing cameras: no frame) or a sequence in rig order.
        prior: (T, 17, 3) poses expected at this frame (NaN where unknown), from the memory of
        past frames (tracking.memory). Each camera's
        detections are first matched to these poses reprojected into it; the detections a pose
        claims in two cameras or more, checked against each other with the epipolar
        constraint, form that person. Only the detections left over are associated across
        cameras from scratch. The result tells, per person, which predicted pose seeded it.
        """
        if isinstance(people, Mapping):
            people = [people.get(name) for name in self.rig.names]
        if len(people) != len(self.rig):
            raise ValueError(f"expected people for {len(self.rig)} cameras, got {len(people)}")
        C = len(self.rig)
        ac = self.config.association
        det = Detections.from_people(self.rig, people, ac.min_conf)
        if len(det) < 2:
            return Reconstruction(People3D.empty(frame, C), np.zeros(0, dtype=np.int64))
        seeded: list[np.ndarray] = []
        seeds: list[int] = []
        if prior is not None and len(prior):
            claims, swap = claim(
                det, prior, self.P, ac.min_conf, ac.min_common_joints, ac.track_max_cost
            )
            seeded, seeds = claimed_groups(claims)
            # the labels of a claimed detection follow the predicted pose's: a detector's
            # left/right swap is undone before anything else looks at it
            det = exchanged(det, swap & (claims >= 0)[:, None])
        # epipolar distances only where they are needed: inside seeded groups, and between
        # the detections no seed claimed
        free = np.ones(len(det), dtype=bool)
        for g in seeded:
            free[g] = False
        dist = epipolar_distances(det, self.E, pairs_within(seeded, np.flatnonzero(free)))
        cost = epipolar_costs(det, dist, ac.min_conf, ac.min_common_joints)
        if seeded:
            seeded, seeds, dropped = check_groups(seeded, seeds, cost, ac.max_cost)
            if dropped.size:  # back with the free detections, which need their distances
                free[dropped] = True
                pairs = pairs_within(seeded, np.flatnonzero(free))
                dist = epipolar_distances(det, self.E, pairs)
                cost = epipolar_costs(det, dist, ac.min_conf, ac.min_common_joints)
        left = np.flatnonzero(free)
        found = group_detections(cost[np.ix_(left, left)], det.camera[left], ac.max_cost)
        new = [left[g] for g in found]
        groups = seeded + new
        seed_of = np.array(seeds + [-1] * len(new), dtype=np.int64)
        if not groups:
            return Reconstruction(People3D.empty(frame, C), np.zeros(0, dtype=np.int64))
        # seeded groups alone have their labels settled; new people need them made consistent
        tri = self._triangulate(det, groups, dist, labels_known=not new)
        grown = self._reassign(det, groups, tri[0]) if ac.reassign_leftovers else []
        if grown:
            redo = self._triangulate(det, [groups[i] for i in grown], dist)
            for full, part in zip(tri, redo, strict=True):
                full[grown] = part
        X, used, conf, err, members = tri
        delivered = np.array([p is not None for p in people])
        out, idx = self._assemble(frame, det, members, delivered, X, used, conf, err)
        return Reconstruction(out, seed_of[idx])

    # -- steps ---------------------------------------------------------------------------------

    def _gather(
        self, det: Detections, groups: list[np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The groups' detections as the triangulation takes them (C-contiguous):
        xy (G, 17, C, 2), conf (G, 17, C), size_px (G, C) and members (G, C)."""
        G, C = len(groups), len(self.rig)
        sizes = [len(g) for g in groups]
        gi = np.repeat(np.arange(G), sizes)
        di = np.concatenate(groups)
        ci = det.camera[di]
        xy = np.full((G, NUM_JOINTS, C, 2), np.nan)
        conf = np.zeros((G, NUM_JOINTS, C))
        size_px = np.full((G, C), np.nan)
        members = np.full((G, C), -1, dtype=np.int64)
        xy[gi, :, ci] = det.xy[di]
        conf[gi, :, ci] = det.conf[di]
        size_px[gi, ci] = det.size_px[di]
        members[gi, ci] = di
        return xy, conf, size_px, members

    def _triangulate(
        self,
        det: Detections,
        groups: list[np.ndarray],
        dist: PairDistances,
        labels_known: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Triangulate groups; labels_known: their left/right labels are consistent already
        (robust mode then skips making them so)."""
        tc = self.config.triangulation
        xy, conf, size_px, members = self._gather(det, groups)
        w = np.where(conf >= tc.min_conf, conf, 0.0)
        err = single = None
        if tc.mode == "pair":
            X, used = triangulate_pair(
                xy,
                w,
                conf,
                self.P,
                self.E,
                self.focal,
                PairScore(tc.pair_a, tc.pair_b, self.config.association.min_common_joints),
            )
        elif tc.mode == "weighted":
            X, used = triangulate_weighted(xy, w, self.P)
        else:
            X, used, xy, w, err, single = triangulate_robust(
                xy,
                w,
                self.P,
                self.focal,
                size_px,
                Robust(tc.inlier_px, tc.inlier_rel, tc.fix_swaps),
                pair_distances=None if labels_known else _group_pair_distances(members, dist),
                rays=(self.centers, self.R) if tc.single_view else None,
            )
        out_conf = np.where(used, w, 0.0).sum(-1) / np.maximum(used.sum(-1), 1)
        if single is not None:
            out_conf = np.where(single, 0.5 * out_conf, out_conf)  # no depth of its own
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

    def _assemble(
        self,
        frame: int,
        det: Detections,
        members: np.ndarray,
        delivered: np.ndarray,
        X: np.ndarray,
        used: np.ndarray,
        conf: np.ndarray,
        err: np.ndarray,
    ) -> tuple[People3D, np.ndarray]:
        """Plausible people only, as People3D, and the indices of their groups; members:
        (G, C) detection per camera or -1."""
        pc = self.config.plausibility
        C = members.shape[1]
        X, used = np.array(X, dtype=np.float64), np.array(used, dtype=bool)  # contiguous copies
        # a person that cameras with a frame should see but (almost) none detected is a
        # coincidence of false detections that happen to agree, not a person; joints placed
        # from one view do not count: they lean on the others
        keep: np.ndarray = plausible(
            X,
            used,
            np.ascontiguousarray(members),
            np.ascontiguousarray(delivered),
            self.P,
            *self.bounds,
            _LIMB_A,
            _LIMB_B,
            pc.max_limb_m,
            pc.min_joints,
            pc.floor_tolerance_m,
            pc.max_height_m,
            pc.min_view_fraction,
            5,
        )
        valid = np.asarray(np.isfinite(X).all(-1))
        views = members >= 0
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            return People3D.empty(frame, C), idx
        X, used, conf, valid = X[idx], used[idx], conf[idx], valid[idx]
        err = np.where(used, err[idx], np.nan)
        detections = np.where(views[idx], det.index[members[idx]], -1)
        n_used = used.sum(-1)
        # NaN where no view
        total = np.where(used, err, 0.0).sum(-1)
        reproj = np.divide(total, n_used, out=np.full(total.shape, np.nan), where=n_used > 0)
        conf = np.where(valid, conf, 0.0)
        people = People3D(
            frame=frame,
            joints=X,
            conf=conf,
            ids=np.arange(idx.size),
            reprojection_px=reproj,
            views=n_used,
            detections=detections,
        )
        return people, idx
