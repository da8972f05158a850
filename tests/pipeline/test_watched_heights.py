"""How small the smallest worker that matters looks in each camera (the regions' scans plan
their tiles on it), on the real demo's calibration and site."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest

from stereopose.calibration.formats import load_calibration
from stereopose.detection.models import demo_videos
from stereopose.fence import Zone, load_site
from stereopose.pipeline.track_regions import WORKER_M, watched_heights, watched_shares
from stereopose.sim.distant import Distant

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def rig():
    videos = demo_videos()
    if not videos:
        pytest.skip("the demo is not in the cache")
    return load_calibration(videos[0].parents[1] / "calibration" / "Calib.qca.txt")


def test_the_demo_workers_look_as_tall_as_the_rooms_depth_allows(rig):
    site = load_site(str(resources.files("stereopose") / "data" / "demo_site.toml"))
    heights = watched_heights(rig, site.zones)
    assert set(heights) == set(rig.names)
    for cam in rig:
        # at most as far as the room's far wall (the zones within 3 m of the origin, grown by
        # their margin and a metre): 1.6 m tall at ~4-8 m from a 1680 px focal length
        assert cam.focal * WORKER_M / 8.0 < heights[cam.name] < cam.focal * WORKER_M / 2.0
    # the same site from a camera whose picture is shrunk to a fifth: a fifth as tall
    far = watched_heights(Distant(0.2).rig(rig), site.zones)
    for name in rig.names:
        assert far[name] == pytest.approx(0.2 * heights[name], rel=0.02)


def _square(name: str, x: float, y: float) -> Zone:
    polygon = np.array([[x, y], [x + 1, y], [x + 1, y + 1], [x, y + 1]], float)
    return Zone(name, "energized", polygon, (0.0, 2.0))


def test_a_farther_zone_makes_the_smallest_worker_smaller_and_no_zones_say_nothing(rig):
    cam = rig["cam01"]
    ahead = cam.R.T @ np.array([0.0, 0.0, 1.0])  # its optical axis, on the floor
    ahead = ahead[:2] / np.linalg.norm(ahead[:2])
    near = _square("near", *(cam.center[:2] + 3.0 * ahead - 0.5))
    far = _square("far", *(cam.center[:2] + 12.0 * ahead - 0.5))
    alone, both = watched_heights(rig, (near,)), watched_heights(rig, (near, far))
    assert all(both[n] <= alone[n] for n in rig.names)
    assert both["cam01"] < 0.5 * alone["cam01"]  # 12 m (and a metre more) against 3 m
    assert watched_heights(rig, ()) == {}


def test_shares_judge_a_substreams_frames_at_their_own_size(rig):
    """The regions' scans compare a worker's height with the frame they are given: a share of
    the frame's height is the same on a quarter-size substream as on the main stream."""
    site = load_site(str(resources.files("stereopose") / "data" / "demo_site.toml"))
    heights, shares = watched_heights(rig, site.zones), watched_shares(rig, site.zones)
    for cam in rig:
        assert shares[cam.name] == pytest.approx(heights[cam.name] / cam.size[1])
        assert 0.0 < shares[cam.name] < 1.0
    assert watched_shares(rig, ()) == {}
