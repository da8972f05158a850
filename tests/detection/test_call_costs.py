"""The detector's call prices and the cheapest calls of a step: prices measured with the real
detector and kept per machine, and a step of regions and whole frames made one model call
where a call's fixed part is most of its price, two where crops are cheap."""

from __future__ import annotations

import pytest

from demo_frames import demo_step
from stereopose.detection import make_detector
from stereopose.detection.call_costs import COST_FILE, CallCosts, cheapest
from stereopose.detection.regional import RegionDetector, RegionSettings
from stereopose.sim.distant import Distant

CAMS = ("cam01", "cam02", "cam03", "cam04")
WHOLE = (640, 384)  # a portrait full-HD frame letterboxed at 640
CROP = (320, 320)
# measured on a 2-core Intel Xeon with AMX (bf16): a call's fixed part is large
INTEL = {WHOLE: [40.0, 62.0, 100.0, 108.0], CROP: [16.0, 19.5, 32.0, 44.0, 56.0, 68.0, 80.0, 92.0]}
# a call's fixed part is nearly all of it (a GPU, or a CPU whose cores wait on each call)
FLAT = {WHOLE: [60.0, 62.0, 64.0, 66.0], CROP: [30.0, 33.0, 36.0, 39.0, 42.0]}
# crops far cheaper than a whole frame, and no fixed part to speak of
CHEAP_CROPS = {WHOLE: [36.0, 60.0, 117.0, 119.0], CROP: [4.0, 7.0, 10.0, 13.0, 16.0, 19.0, 22.0]}


def _priced(prices) -> CallCosts:
    costs = CallCosts(object())
    for shape, ms in prices.items():
        costs.set(shape, ms)
    return costs


def test_a_camera_goes_whole_where_its_crops_cost_more_than_a_larger_batch():
    # three cameras whole anyway (scans), one with a region: on Intel its crop call (16 ms)
    # costs more than a fourth frame in the whole frames' batch (8 ms)
    assert cheapest(_priced(INTEL), [WHOLE] * 3, CROP, [("cam04", WHOLE, 1)]) == {"cam04"}
    # with cheap crops the region stays
    assert cheapest(_priced(CHEAP_CROPS), [WHOLE] * 3, CROP, [("cam04", WHOLE, 1)]) == set()


def test_a_tie_keeps_the_regions_and_nothing_priced_keeps_them_too():
    tie = {WHOLE: [20.0, 40.0], CROP: [20.0, 40.0]}
    assert cheapest(_priced(tie), [], CROP, [("cam01", WHOLE, 1)]) == set()
    assert cheapest(CallCosts(object()), [], CROP, [("cam01", WHOLE, 1)]) == set()
    assert cheapest(_priced(INTEL), [WHOLE], CROP, []) == set()


def test_the_cameras_with_most_regions_go_whole_first():
    costs = _priced({WHOLE: [30.0, 45.0, 60.0], CROP: [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]})
    # cam02's four crops (40 ms) against its whole frame (30 ms); cam01's one crop stays
    got = cheapest(costs, [], CROP, [("cam01", WHOLE, 1), ("cam02", WHOLE, 4)])
    assert got == {"cam02"}


def test_prices_beyond_the_measured_batches_follow_the_last_step_and_calls_move_them_all():
    costs = _priced({WHOLE: [10.0, 18.0], CROP: [5.0, 8.0]})
    assert costs.price(WHOLE, 0) == 0.0
    assert costs.price(WHOLE, 4) == pytest.approx(34.0)
    assert costs.price((64, 64), 1) == float("inf")
    choice = cheapest(costs, [WHOLE], CROP, [("cam01", WHOLE, 2)])
    for _ in range(20):  # the crops' calls take twice their price: the machine is busy
        costs.observe(CROP, 2, 16.0)
    assert costs.load == pytest.approx(2.0, rel=0.05)
    # every price follows, the whole frames' too, so the choice stays what it was
    assert costs.price(WHOLE, 2) == pytest.approx(2 * 18.0, rel=0.05)
    assert cheapest(costs, [WHOLE], CROP, [("cam01", WHOLE, 2)]) == choice
    costs.observe(WHOLE, 9, 1000.0)  # a batch never measured: nothing to follow
    costs.observe(WHOLE, 1, float("nan"))
    assert costs.load == pytest.approx(2.0, rel=0.05)
    assert costs.table() == {"640x384": [10.0, 18.0], "320x320": [5.0, 8.0]}
    with pytest.raises(ValueError, match="positive"):
        costs.set(WHOLE, [0.0])


def test_a_batch_is_split_only_where_two_calls_cost_less_than_one():
    # as on a 2-core AMD with OpenVINO bf16: three whole frames in one call cost more than
    # four do, and more than two and one
    amd = _priced({WHOLE: [18.9, 31.9, 73.8, 63.0]})
    assert amd.split(WHOLE, 3) == [2, 1]
    assert amd.price(WHOLE, 3) == pytest.approx(18.9 + 31.9)
    assert amd.split(WHOLE, 4) == [4]  # 2 + 2 costs more
    assert _priced({WHOLE: [10.0, 20.0, 30.0, 39.0]}).split(WHOLE, 4) == [4]  # a tie: one
    assert amd.split(WHOLE, 0) == [] and amd.price(WHOLE, 0) == 0.0
    # Intel's AMX: a call's fixed part is large, whole frames in one call; yet four crops
    # in one call (44 ms) cost more than two calls of two (19.5 ms each)
    intel = _priced(INTEL)
    assert all(intel.split(WHOLE, n) == [n] for n in range(1, 5))
    assert intel.split(CROP, 2) == [2] and intel.split(CROP, 4) == [2, 2]
    # beyond the measured batches: one call on the last measures' line, or the measured
    # batch that costs least per image
    odd = _priced({CROP: [10.0, 12.0, 40.0]})
    assert odd.split(CROP, 4) == [2, 2] and odd.price(CROP, 4) == pytest.approx(24.0)
    assert CallCosts(object()).split(CROP, 3) == [3]  # unpriced: one call
    amd.set(WHOLE, [18.9, 31.9, 40.0, 73.8])  # prices known anew: the splits too
    assert amd.split(WHOLE, 3) == [3]


@pytest.mark.realdata
@pytest.mark.slow
def test_a_step_splits_its_crops_where_their_prices_say_so(detector):
    far = Distant(0.4)
    images = dict(zip(CAMS, [far.frame(im) for im in demo_step(0)], strict=True))
    counted = Counted(detector)
    wide = (384, 640)
    # three crops cost more than two and one; every frame is far, so the scan finds them all
    costs = _priced({wide: [30.0, 60.0, 90.0, 120.0], CROP: [10.0, 12.0, 40.0, 44.0, 60.0, 64.0]})
    regions = RegionDetector(counted, RegionSettings(full_scan_s=60.0), costs)
    regions.watch(dict.fromkeys(CAMS, 400.0 / 1080))
    regions.detect(images, 0.0)
    counted.calls.clear()
    found = regions.detect(images, 0.1)
    crops = [n for n, imgsz in counted.calls if imgsz == 320]
    assert sum(crops) == sum(len(regions.regions(c)) for c in CAMS) > 0
    assert crops == costs.split(CROP, sum(crops)) and len(crops) > 1  # split: cheaper
    assert all(len(found[c]) for c in CAMS)


@pytest.fixture(scope="module")
def detector():
    return make_detector("onnx", threads=2)


class Counted:
    """The real detector, its calls counted."""

    def __init__(self, detector) -> None:
        self.inner, self.calls = detector, []
        self.name, self.imgsz, self.iou = detector.name, detector.imgsz, detector.iou
        self.model, self.precision = detector.model, detector.precision
        self.threads = detector.threads

    def detect(self, images, imgsz=None):
        self.calls.append((len(images), imgsz))
        return self.inner.detect(images, imgsz=imgsz)


@pytest.mark.realdata
@pytest.mark.slow
def test_prices_are_measured_once_per_machine_and_kept(detector, tmp_path):
    store = tmp_path / COST_FILE
    counted = Counted(detector)
    costs = CallCosts(counted, store)
    costs.ensure({WHOLE: 3, CROP: 2})
    assert counted.calls  # measured with the real detector
    table = costs.table()
    assert set(table) == {"640x384", "320x320"}
    for ms in table.values():
        assert all(m > 0 for m in ms)
    assert len(table["640x384"]) == 3 and len(table["320x320"]) == 2
    # a whole frame costs more than a region's crop
    assert costs.price(WHOLE, 1) > costs.price(CROP, 1)
    again = Counted(detector)
    kept = CallCosts(again, store)
    kept.ensure({WHOLE: 3, CROP: 2})
    assert again.calls == [] and kept.table() == table
    other = CallCosts(Counted(make_detector("onnx", threads=1)), store)
    assert not other.priced(WHOLE)  # another set-up is measured anew
    store.write_text("not json")
    assert not CallCosts(again, store).priced(WHOLE)  # a spoilt file: measured again


@pytest.mark.realdata
@pytest.mark.slow
def test_a_step_of_regions_and_whole_frames_makes_one_model_call_where_calls_cost_most(detector):
    # the demo's people seen from further (a wide 1920x1080 camera): 250-400 px tall, each in
    # a region of his own, and each found in the whole frame too (the site says so)
    far = Distant(0.4)
    steps = [[far.frame(im) for im in demo_step(i)] for i in (0, 6, 12)]
    wide = (384, 640)  # the wide frame letterboxed at 640
    heights = dict.fromkeys(CAMS, 400.0 / 1080)
    calls = {}
    for name, prices in (("flat", FLAT), ("cheap crops", CHEAP_CROPS)):
        counted = Counted(detector)
        costs = _priced({wide: prices[WHOLE], CROP: prices[CROP]})
        regions = RegionDetector(counted, RegionSettings(full_scan_s=1.0), costs)
        regions.watch(heights)
        regions.detect(dict(zip(CAMS, steps[0], strict=True)), 0.0)  # every camera's scan
        regions.detect(dict(zip(CAMS, steps[1], strict=True)), 0.1)
        counted.calls.clear()
        # cam01's second scan is due at 0.25 s (staggered): it is whole, the others have
        # their people's regions
        found = regions.detect(dict(zip(CAMS, steps[2], strict=True)), 0.3)
        calls[name] = list(counted.calls)
        whole = [regions.whole(c) for c in CAMS]
        assert whole[0], name
        assert all(len(found[c]) for c in CAMS), (name, found)
        if name == "flat":
            assert all(whole), name
        else:
            assert not any(whole[1:]), name
    assert calls["flat"] == [(4, None)]  # one call: the four whole frames
    assert len(calls["cheap crops"]) == 2  # the crops, then cam01's whole frame
    assert calls["cheap crops"][1] == (1, None)
