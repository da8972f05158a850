"""Recorded files played as live cameras (CameraSet wall_clock, as `serve` plays them): a step's
t is when its frames were read on the set's clock, strictly increasing, so clock.start_epoch + t
is the wall time it was read; without it (a run on files) t stays frame / fps."""

from __future__ import annotations

import time

import numpy as np
import pytest

from stereopose.io.cameraset import CameraSet
from streams import write_video


def test_a_looped_file_on_the_wall_clock_is_stamped_when_read(tmp_path):
    video = write_video(tmp_path / "a.mp4", 6, 250.0)  # 250 fps: frame / fps would lag far
    with CameraSet([video, video], ["a", "b"], loop=True, wall_clock=True) as cams:
        steps = []
        for _, step in zip(range(12), cams, strict=False):
            steps.append((step, time.monotonic(), time.time()))
        assert cams.delivering("a", 1.0) and not cams.delivering("zz", 1.0)
    ts = [s.t for s, _, _ in steps]
    assert np.all(np.diff(ts) > 0)
    for step, mono, wall in steps:
        assert cams.clock.start + step.t == pytest.approx(mono, abs=0.05)
        assert cams.clock.start_epoch + step.t == pytest.approx(wall, abs=0.05)
    assert [s.index for s, _, _ in steps] == list(range(12))  # the frames stay the files'
    assert steps[-1][0].source_frames["a"] == 11


def test_without_the_wall_clock_files_keep_frame_over_fps(tmp_path):
    video = write_video(tmp_path / "a.mp4", 6, 250.0)
    with CameraSet([video], ["a"], loop=True) as cams:
        ts = [s.t for _, s in zip(range(8), cams, strict=False)]
    assert ts == pytest.approx([i / 250 for i in range(8)])


def test_an_ended_file_no_longer_delivers(tmp_path):
    video = write_video(tmp_path / "a.mp4", 3, 25.0)
    looped = write_video(tmp_path / "b.mp4", 3, 25.0)
    with CameraSet([video, looped], ["a", "b"], loop=[False, True], wall_clock=True) as cams:
        steps = [s for _, s in zip(range(6), cams, strict=False)]
        assert steps[-1].images["a"] is None
        assert not cams.delivering("a", 10.0) and cams.delivering("b", 10.0)
