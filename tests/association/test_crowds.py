"""Association on simulated crowds: pure groups, one detection per camera, few ghosts."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.association import Detections, epipolar_costs, epipolar_distances, group_detections
from stereopose.geometry.epipolar import essential_matrices
from stereopose.sim import simulate


@pytest.mark.parametrize(("cameras", "people"), [(4, 6), (6, 10), (10, 12)])
def test_groups_are_pure_on_crowds(cameras: int, people: int) -> None:
    scene = simulate(
        num_cameras=cameras, num_people=people, num_frames=25, seed=3, difficulty="mid"
    )
    E = essential_matrices(scene.rig)
    pure = total = 0
    for t, dets in enumerate(scene.detections):
        people2d = [dets.get(n) for n in scene.rig.names]
        det = Detections.from_people(scene.rig, people2d, min_conf=0.3)
        cost = epipolar_costs(det, epipolar_distances(det, E), 0.3, 4)
        for g in group_detections(cost, det.camera, max_cost=0.12):
            cams = det.camera[g]
            assert len(set(cams.tolist())) == len(cams)  # one detection per camera
            owners = {
                int(scene.detection_truth[t][scene.rig.names[c]][i])
                for c, i in zip(cams, det.index[g], strict=True)
            }
            total += 1
            pure += len(owners) == 1 and -1 not in owners
    assert total > 0
    assert pure / total >= 0.98


def test_near_and_far_people_cost_alike() -> None:
    """The normalised cost of a true match does not grow with the distance to the cameras."""
    scene = simulate(num_cameras=4, num_people=6, num_frames=40, seed=8, difficulty="easy")
    E = essential_matrices(scene.rig)
    costs, sizes = [], []
    for t, dets in enumerate(scene.detections):
        det = Detections.from_people(scene.rig, [dets.get(n) for n in scene.rig.names], 0.3)
        cost = epipolar_costs(det, epipolar_distances(det, E), 0.3, 4)
        owner = np.array(
            [
                scene.detection_truth[t][scene.rig.names[c]][i]
                for c, i in zip(det.camera, det.index, strict=True)
            ]
        )
        n, m = np.nonzero((owner[:, None] == owner[None, :]) & np.isfinite(cost))
        costs.extend(cost[n, m].tolist())
        sizes.extend(np.minimum(det.size_px[n], det.size_px[m]).tolist())
    costs, sizes = np.array(costs), np.array(sizes)
    small = costs[sizes < np.median(sizes)]
    large = costs[sizes >= np.median(sizes)]
    assert np.median(small) < 2.0 * np.median(large) + 0.01
    assert np.percentile(costs, 95) < 0.12  # true matches pass the default threshold
