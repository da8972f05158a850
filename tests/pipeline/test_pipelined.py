"""Detection on its own thread: bounded hand-over, newest steps, drops counted, clean close;
people found on a substream scaled to the camera's calibrated size."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from stereopose.detection.base import Poses
from stereopose.io.cameraset import CameraSet
from stereopose.io.summary import CAMERA_STAGES, RunSummary
from stereopose.pipeline.pipelined import Handover, PipelinedCameras
from stereopose.pipeline.sources import Cameras, scale_people
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import Camera, People2D, Rig
from streams import free_port, serve, stop, wait_serving, write_video
from waiting import wait_until


class CentreDetector:
    """One person whose every joint is at the image's centre; counts its calls."""

    name, imgsz, iou = "centre", 640, 0.7

    def __init__(self, fail_at: int | None = None) -> None:
        self.calls, self.fail_at = 0, fail_at
        self.shapes: list[tuple[int, ...]] = []

    def detect(self, images):
        self.calls += 1
        if self.calls == self.fail_at:
            raise ValueError("the detector broke")
        out = []
        for im in images:
            self.shapes.append(im.shape)
            h, w = im.shape[:2]
            kp = np.tile([w / 2, h / 2, 0.9], (1, NUM_JOINTS, 1))
            out.append(Poses(kp, np.array([[0, 0, w, h]], float), np.array([0.9])))
        return out


def _rig(names, size=(96, 64)) -> Rig:
    def cam(name, x):
        k = np.array([[100.0, 0, size[0] / 2], [0, 100.0, size[1] / 2], [0, 0, 1]])
        return Camera(name, size, k, np.zeros(4), np.zeros(3), np.array([x, 0.0, 3.0]))

    return Rig(tuple(cam(n, i * 0.5) for i, n in enumerate(names)))


def test_handover_newest_wins_and_counts_what_it_drops():
    h = Handover(1, drop=True)
    for i in range(5):
        assert h.put(i)
    assert h.get(0.01) == 4 and h.dropped == 4 and h.get(0.01) is None
    h.close()
    assert not h.put(9) and h.get(1.0) is None


def test_handover_without_drops_waits_for_room():
    h = Handover(1, drop=False)
    h.put(1)
    t = threading.Thread(target=h.put, args=(2,))
    t.start()
    wait_until(lambda: h.get(0.01) == 1, "the first item")
    t.join(5)
    assert h.get(0.01) == 2 and h.dropped == 0


def test_recorded_cameras_pipelined_keep_every_step_in_order(tmp_path):
    a = write_video(tmp_path / "a.mp4", 12, 20.0)
    b = write_video(tmp_path / "b.mp4", 12, 20.0)
    det = CentreDetector()
    with CameraSet([a, b], ["a", "b"]) as cams:
        source = PipelinedCameras(Cameras(cams, _rig(["a", "b"]), det))
        steps = list(source)
    assert [s.frame for s in steps] == list(range(12))
    assert all(set(s.people2d) == {"a", "b"} for s in steps)
    assert source.stats.dropped == 0 and source.stats.detected == 12 == det.calls
    assert len(source.stats.latency_s) == 12


def test_substream_people_are_scaled_to_the_calibrated_size(tmp_path):
    full = write_video(tmp_path / "full.mp4", 4, 10.0, size=(96, 64))
    small = write_video(tmp_path / "small.mp4", 4, 10.0, size=(48, 32))
    det = CentreDetector()
    with CameraSet([full], ["cam"], detect=[small]) as cams:
        src = Cameras(cams, _rig(["cam"]), det)
        steps = [(s, src.detect(s)) for s in src]
    assert det.shapes == [(32, 48, 3)] * 4  # detected on the substream
    for step, people in steps:
        assert step.images["cam"].shape == (64, 96, 3)  # the full frame goes on
        kp = people["cam"].keypoints[0]
        assert kp[:, :2] == pytest.approx(np.tile([48.0, 32.0], (NUM_JOINTS, 1)))
        assert people["cam"].boxes[0] == pytest.approx([0, 0, 96, 64])


def test_scale_people_keeps_missing_joints_missing():
    kp = np.full((1, NUM_JOINTS, 3), [10.0, 20.0, 0.8])
    kp[0, 3] = (np.nan, np.nan, 0.0)
    out = scale_people(People2D("c", 0, kp), (1920.0, 1080.0), (270, 480, 3))
    assert out.keypoints[0, 0] == pytest.approx([40.0, 80.0, 0.8])
    assert np.isnan(out.keypoints[0, 3, :2]).all()


def test_a_detection_error_is_raised_in_the_loops_thread(tmp_path):
    a = write_video(tmp_path / "a.mp4", 10, 20.0)
    with CameraSet([a], ["a"]) as cams:
        source = PipelinedCameras(Cameras(cams, _rig(["a"]), CentreDetector(fail_at=3)))
        with pytest.raises(ValueError, match="the detector broke"):
            list(source)
        wait_until(lambda: not source._thread.is_alive(), "detection's thread ended", 5)


@pytest.mark.slow
def test_live_pipeline_with_a_slow_loop_gives_the_newest_steps_and_closes(tmp_path):
    port = free_port()
    server = serve(write_video(tmp_path / "v.mp4", 50, 25.0), port)
    wait_serving([server], [port])
    try:
        with CameraSet([f"http://127.0.0.1:{port}/live.ts"], ["cam"]) as cams:
            source = PipelinedCameras(Cameras(cams, _rig(["cam"]), CentreDetector()))
            assert source.handover.drop
            it = iter(source)
            got = []
            for _ in range(4):
                step = next(it)
                got.append((step.frame, source.stats.detected))
                # a loop slower than detection: three more steps detected meanwhile
                seen = source.stats.detected
                wait_until(lambda s=seen: source.stats.detected >= s + 3, "3 steps detected")
            summary = RunSummary(("cam",), CAMERA_STAGES, "", False, live=True)
            source.finish(summary)  # closes: detection's thread ends within the deadline
            assert not source._thread.is_alive()
    finally:
        stop([server])
    frames = [f for f, _ in got]
    assert frames == sorted(set(frames))  # increasing, none twice
    for frame, detected in got[1:]:
        assert frame >= detected - 2  # the newest detected step (one more may be under way)
    assert source.stats.dropped >= 4 and len(source.handover) <= 1
    assert summary.seconds["detect"] > 0 and summary.sources["cam"]["decoded"] >= 4
