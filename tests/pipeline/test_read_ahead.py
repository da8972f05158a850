"""Recorded cameras read ahead (io.cameraset's read_ahead, as `run` and `detect` open them):
the same steps in their order, and no reader left once the set is closed, the iteration
finished, stopped early, or ended by an error in the consumer."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from test_pipelined import CentreDetector, _rig

from stereopose.io.cameraset import CameraSet
from stereopose.pipeline.detect import READ_AHEAD
from stereopose.pipeline.pipelined import PipelinedCameras
from stereopose.pipeline.sources import Cameras
from streams import write_video

NAMES = ["cam01", "cam02"]


def _levels(images) -> dict[str, float]:
    return {n: float(np.mean(im)) for n, im in images.items()}


def _readers() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name == "camera-read-ahead"]


def test_recorded_steps_come_read_ahead_in_their_order(tmp_path):
    videos = [write_video(tmp_path / f"{n}.mp4", 12, 25.0) for n in NAMES]
    with CameraSet(videos, NAMES) as cams:
        direct = [(s.index, s.t, _levels(s.images)) for s in cams]
    with CameraSet(videos, NAMES, read_ahead=READ_AHEAD) as cams:
        got = []
        for step in cams:
            if not got:  # (by the last steps, it may have read them all)
                assert _readers(), "the next steps are read on their own thread"
            got.append((step.index, step.t, _levels(step.images)))
    assert got == direct and len(got) == 12
    assert not _readers()


def test_a_set_closed_early_leaves_no_reader(tmp_path):
    videos = [write_video(tmp_path / f"{n}.mp4", 30, 25.0) for n in NAMES]
    with CameraSet(videos, NAMES, read_ahead=READ_AHEAD) as cams:
        steps = iter(cams)
        first = [next(steps).index for _ in range(3)]
    assert first == [0, 1, 2]
    assert not _readers()


def test_an_error_in_the_consumer_closes_the_set_with_its_reader(tmp_path):
    """Detection fails mid-run in the pipelined cameras' thread: the error reaches the loop,
    and closing the set stops the reader before the files are released."""
    a = write_video(tmp_path / "a.mp4", 30, 20.0)
    with CameraSet([a], ["a"], read_ahead=READ_AHEAD) as cams:
        source = PipelinedCameras(Cameras(cams, _rig(["a"]), CentreDetector(fail_at=3)))
        with pytest.raises(ValueError, match="the detector broke"):
            list(source)
    assert not _readers()
