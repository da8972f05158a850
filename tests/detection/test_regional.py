"""Detection in regions with the real detector on real demo frames: distant workers found in
every camera, a worker who stands still kept, a newcomer found by the scan, one person each
from regions at a frame's edge or overlapping, empty cameras that cost nothing, and near
workers (as the site shows them) that cost what whole frames cost."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest

from demo_frames import demo_step
from stereopose.calibration.formats import load_calibration
from stereopose.detection import make_detector
from stereopose.detection.models import demo_videos
from stereopose.detection.regional import FOUND_WHOLE_PX, RegionDetector, RegionSettings
from stereopose.fence import load_site
from stereopose.pipeline.track_regions import watched_shares
from stereopose.sim.distant import Distant

pytestmark = [pytest.mark.realdata, pytest.mark.slow]
CAMS = ("cam01", "cam02", "cam03", "cam04")
STEP_S = 0.1


@pytest.fixture(scope="module")
def detector():
    return make_detector("onnx", threads=2)


@pytest.fixture(scope="module")
def steps() -> list[list[np.ndarray]]:
    return [demo_step(i) for i in (0, 6, 12, 18, 24)]


def _step(images) -> dict[str, np.ndarray]:
    return dict(zip(CAMS, images, strict=True))


def test_distant_workers_are_found_in_every_camera(detector, steps):
    far = Distant(0.2)  # people 120-200 px tall in a 1920x1080 view
    whole = make_detector("onnx", threads=2, imgsz=1280)  # what sees them whole: the reference
    regions = RegionDetector(detector)
    missed_at_640 = 0
    for k, images in enumerate(steps):
        frames = [far.frame(im) for im in images]
        found = regions.detect(_step(frames), k * STEP_S)
        reference = whole.detect(frames)
        at_640 = detector.detect(frames)
        missed_at_640 += sum(len(p) for p in reference) - sum(len(p) for p in at_640)
        for cam, ref in zip(CAMS, reference, strict=True):
            assert len(found[cam]) >= min(len(ref), 2), (k, cam)  # the two workers at least
            assert len(found[cam]) <= len(ref) + 1, (k, cam)  # no person twice
            # the two workers (the tallest: a bystander farther off may come and go) found
            # where the 1280 reference finds them, in the canvas's pixels
            tallest = np.argsort(ref.boxes[:, 1] - ref.boxes[:, 3])[:2]
            for box in ref.boxes[tallest]:
                d = np.abs(found[cam].boxes - box).max(axis=1)
                assert d.min() < 0.1 * (box[3] - box[1]) + 4, (k, cam, box)
    assert missed_at_640 > 0  # whole frames at 640 lose some of them: what regions are for
    report = regions.report()
    assert all(c["full_scans"] == 1 and c["steps"] == len(steps) for c in report.values())
    # after the first step's scan, regions cost less than whole frames at 640
    later = [c["input_px"] / c["whole_input_px"] for c in report.values()]
    assert max(later) < 1.5  # the first step's scan included


def test_a_worker_who_stands_still_is_kept(detector, steps):
    far = Distant(0.3)
    still = _step([far.frame(im) for im in steps[0]])
    regions = RegionDetector(detector, RegionSettings(full_scan_s=60.0))
    first = regions.detect(still, 0.0)
    counts = [len(first[c]) for c in CAMS]
    assert min(counts) >= 2
    for k in range(1, 25):  # 2.4 s standing still: no motion, no scan, his region kept
        found = regions.detect(still, k * STEP_S)
        assert [len(found[c]) for c in CAMS] == counts, k
        assert all(
            regions.regions(c) and all(r.why & {"seen"} for r in regions.regions(c)) for c in CAMS
        )
    report = regions.report()
    assert all(c["full_scans"] == 1 for c in report.values())
    # standing still costs regions, never the whole frame again
    assert all(c["whole_frames"] == 1 for c in report.values())


def test_a_newcomer_who_stands_still_is_found_by_the_scan(detector, steps):
    far = Distant(0.45, at=(800, 100))  # 270-450 px tall: the scan's whole frame sees them
    empty = far.empty()
    settings = RegionSettings(full_scan_s=1.0, motion_threshold=255)  # no motion: the scan alone
    regions = RegionDetector(detector, settings)
    t = 0.0
    for _ in range(5):  # nobody: the first step's scan, then nothing to look at
        assert all(len(p) == 0 for p in regions.detect(_step([empty] * 4), t).values())
        t += STEP_S
    idle = regions.report()["cam01"]
    # a scan at the start, the next staggered a quarter period on (the first of 4 cameras)
    assert (idle["full_scans"], idle["idle_steps"]) == (2, 3)
    arrived = t
    there = _step([far.frame(im) for im in steps[0]])
    found_at = {}
    while t < arrived + settings.full_scan_s + 2 * STEP_S and len(found_at) < 4:
        for cam, poses in regions.detect(there, t).items():
            if len(poses) and cam not in found_at:
                found_at[cam] = t
        t += STEP_S
    assert set(found_at) == set(CAMS)
    assert max(found_at.values()) - arrived <= settings.full_scan_s + STEP_S + 1e-9
    assert sum(c["found_by_scan"] for c in regions.report().values()) >= 4


def test_an_empty_camera_costs_no_inference(detector):
    rng = np.random.default_rng(0)
    far = Distant(0.2)
    calls = []
    inner_detect = detector.detect

    class Counting:
        name, imgsz, iou = detector.name, detector.imgsz, detector.iou

        def detect(self, images, imgsz=None):
            calls.append(len(images))
            return inner_detect(images, imgsz=imgsz)

    regions = RegionDetector(Counting())
    for k in range(10):
        noisy = np.clip(far.empty() + rng.normal(0, 2, far.empty().shape), 0, 255)
        regions.detect({"cam01": noisy.astype(np.uint8)}, k * STEP_S)
    assert len(calls) == 2  # the first step's scan: the whole frame, and its tiles
    assert regions.report()["cam01"]["idle_steps"] == 9


def test_a_person_at_the_frames_edge_and_in_overlapping_regions_is_found_once(detector, steps):
    # the workers pasted against the canvas's left side, and three overlapping track regions
    edge = Distant(0.3, at=(0, 200))
    frames = _step([edge.frame(im) for im in steps[1]])
    reference = dict(
        zip(
            CAMS,
            make_detector("onnx", threads=2, imgsz=1280).detect(list(frames.values())),
            strict=True,
        )
    )
    regions = RegionDetector(detector, RegionSettings(full_scan_s=60.0))
    regions.detect(frames, 0.0)  # the scan
    hints = {}
    for cam, ref in reference.items():
        boxes = []
        for x1, y1, x2, y2 in ref.boxes:
            h = y2 - y1
            boxes += [
                (x1, y1, x2, y2),
                (x1 + 5, y1 + 3, x2 + 5, y2 + 3),  # the same person
                (x1, y1, x2, y1 + 0.45 * h),
            ]  # his upper half: a region that cuts him
        hints[cam] = np.array(boxes)
    regions._state["cam01"].held = []  # the tracks alone say where to look
    found = regions.detect(frames, STEP_S, hints)
    for cam, ref in reference.items():
        assert len(found[cam]) == len(ref), cam
        for box in ref.boxes:
            assert np.abs(found[cam].boxes - box).max(axis=1).min() < 0.15 * (box[3] - box[1])


def test_settings_are_checked():
    with pytest.raises(ValueError, match="multiple of 32"):
        RegionSettings(imgsz=300)
    with pytest.raises(ValueError, match="full_scan_s"):
        RegionSettings(full_scan_s=0.0)
    with pytest.raises(ValueError, match="detail"):
        RegionSettings(detail=0.0)


def _demo_site_heights(rig) -> dict[str, float]:
    site = load_site(str(resources.files("stereopose") / "data" / "demo_site.toml"))
    return watched_shares(rig, site.zones)


def test_near_workers_cost_what_whole_frames_cost_and_are_found_the_same(detector, steps):
    """The real demo's workers are near (600-1000 px tall): the site shows that even the
    farthest one the zones care about is found in the whole frame, so the scans take no tiles
    and regions cost no more model input than whole frames, with the same people found. The
    same frames with nothing known of the site tile the whole frame at the first scan."""
    rig = load_calibration(demo_videos()[0].parents[1] / "calibration" / "Calib.qca.txt")
    heights = _demo_site_heights(rig)
    assert min(heights.values()) * detector.imgsz >= FOUND_WHOLE_PX
    watched = RegionDetector(detector, RegionSettings(full_scan_s=0.2))  # a scan every 2 steps
    watched.watch(heights)
    blind = RegionDetector(detector, RegionSettings(full_scan_s=0.2))
    for k, images in enumerate(steps):
        found = watched.detect(_step(images), k * STEP_S)
        blind.detect(_step(images), k * STEP_S)
        for cam, whole in zip(CAMS, detector.detect(images), strict=True):
            assert len(found[cam]) == len(whole), (k, cam)
            for box in whole.boxes:  # each person where the whole frame finds him
                assert np.abs(found[cam].boxes - box).max(axis=1).min() < 0.02 * box[3], (k, cam)
    report = watched.report()
    # a near worker too large for a region makes each step whole whatever moves: motion
    # looks at no frame of the watched cameras after their first step
    assert all(c["motion_frames"] <= 1 for c in report.values()), report
    assert all(c["full_scans"] >= 2 for c in report.values())
    assert all(c["input_px"] <= c["whole_input_px"] for c in report.values()), report
    assert all(c["input_px"] > c["whole_input_px"] for c in blind.report().values())


def test_far_workers_keep_their_tiles(detector, steps):
    """The same site seen from far (the frames a fifth of their size in a wide view): its
    farthest worker is too small for the whole frame, so the first scan still tiles it."""
    far = Distant(0.2)
    rig = load_calibration(demo_videos()[0].parents[1] / "calibration" / "Calib.qca.txt")
    regions = RegionDetector(detector)
    regions.watch(_demo_site_heights(far.rig(rig)))
    regions.detect(_step([far.frame(im) for im in steps[0]]), 0.0)
    assert all(c["regions"] > 1 and c["whole_frames"] == 1 for c in regions.report().values())
