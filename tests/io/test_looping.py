"""Recorded cameras looped forward then backward, detect_fps on files and streams, substreams,
and live frames grabbed without decoding."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stereopose.io import looping
from stereopose.io.cameraset import CameraSet
from stereopose.io.looping import PingPong
from stereopose.io.stream import LiveStream
from stereopose.io.video import VideoError, VideoFile
from streams import free_port, serve, stop, wait_serving, write_video
from waiting import wait_until


def _level(image: np.ndarray) -> int:
    return round(float(image.mean()) / 10)


def _bounce(i: int, n: int) -> int:
    """Where index i plays in a clip of n frames played forward then backward."""
    if n == 1:
        return 0
    p = i % (2 * (n - 1))
    return p if p < n else 2 * (n - 1) - p


@given(st.integers(1, 12), st.integers(0, 60))
def test_ping_pong_positions_bounce_between_the_ends(n, steps):
    play = PingPong(n)
    seen = []
    for _ in range(steps + 1):
        seen.append(play.pos)
        play.advance()
    assert seen == [_bounce(i, n) for i in range(steps + 1)]
    assert all(abs(a - b) <= 1 for a, b in itertools.pairwise(seen))  # never a jump


def test_looped_cameras_play_forward_then_backward_in_step(tmp_path, monkeypatch):
    a = write_video(tmp_path / "a.mp4", 6, 20.0)
    b = write_video(tmp_path / "b.mp4", 9, 20.0)  # longer: played over a's 6 frames
    one = np.zeros((64, 96, 3), np.uint8).nbytes
    monkeypatch.setattr(looping, "BACKWARD_BUFFER_BYTES", 2 * one)  # backward in chunks of 2
    with CameraSet([a, b], ["a", "b"], loop=True) as cams:
        assert cams.count is None
        steps = [s for _, s in zip(range(25), cams, strict=False)]
    assert [s.index for s in steps] == list(range(25))
    assert [s.t for s in steps] == pytest.approx([i / 20 for i in range(25)])
    for s in steps:
        assert _level(s.images["a"]) == _bounce(s.index, 6)
        assert _level(s.images["b"]) == _bounce(s.index, 6)
        assert s.source_frames == {"a": s.index, "b": s.index}


def test_a_looped_file_that_decodes_fewer_frames_turns_back_where_it_ends(tmp_path):
    v = VideoFile(write_video(tmp_path / "a.mp4", 5, 10.0), loop=True)
    v._play.n = 8  # as a file whose header announces more frames than it holds
    levels = [_level(v.read()[2]) for _ in range(14)]
    assert max(levels) == 4 and levels[:5] == [0, 1, 2, 3, 4]
    assert all(abs(x - y) <= 1 for x, y in itertools.pairwise(levels))
    v.close()


def test_detect_fps_on_files_passes_over_frames_without_decoding(tmp_path):
    a = write_video(tmp_path / "a.mp4", 30, 30.0)
    with CameraSet([a], ["a"], detect_fps=10.0) as cams:
        assert cams.count == 10
        steps = list(cams)
        stats = cams.stats()["a"]
    assert [s.index for s in steps] == list(range(0, 30, 3))
    gaps = np.diff([s.t for s in steps])
    assert gaps.min() >= 0.1 - 1e-9
    assert stats.skipped == 20 and stats.decoded == 10 and stats.frames == 10


def test_detect_fps_with_time_alignment_and_loop(tmp_path):
    a = write_video(tmp_path / "a.mp4", 8, 20.0)
    with CameraSet([a], ["a"], sync="time", loop=True, detect_fps=5.0) as cams:
        steps = [s for _, s in zip(range(8), cams, strict=False)]
    assert np.diff([s.t for s in steps]) == pytest.approx([0.2] * 7)
    assert [_level(s.images["a"]) for s in steps] == [_bounce(4 * i, 8) for i in range(8)]


def test_substream_frames_come_with_the_cameras_own(tmp_path):
    full = write_video(tmp_path / "full.mp4", 5, 10.0, size=(96, 64))
    small = write_video(tmp_path / "small.mp4", 5, 10.0, size=(48, 32))
    with CameraSet([full], ["cam"], detect=[small]) as cams:
        steps = list(cams)
    assert len(steps) == 5
    assert all(s.images["cam"].shape == (64, 96, 3) for s in steps)
    assert all(s.detect["cam"].shape == (32, 48, 3) for s in steps)


def test_loop_on_a_live_stream_is_refused():
    with pytest.raises(VideoError, match="loop is for recorded files"):
        CameraSet(
            [f"http://127.0.0.1:{free_port()}/x.ts"],
            ["cam"],
            loop=True,
            open_timeout_s=0.5,
            first_frame_timeout_s=1.0,
        )


@pytest.mark.slow
def test_a_live_camera_decodes_only_the_frames_asked_for(tmp_path):
    port = free_port()
    server = serve(write_video(tmp_path / "v.mp4", 50, 25.0), port)
    wait_serving([server], [port])
    stream = LiveStream(f"http://127.0.0.1:{port}/live.ts", "cam")
    try:
        wait_until(lambda: stream.stats.grabbed >= 15, "15 frames grabbed")
        assert stream.stats.decoded == 1  # the first one only: nobody asked
        first = stream.latest()
        assert first is not None and stream.latest() is None
        stream.request()
        wait_until(lambda: stream.stats.decoded == 2, "the frame asked for decoded")
        got = stream.latest()
        assert got is not None and got[0] > first[0] and got[1] > first[1]
        assert stream.stats.grabbed - stream.stats.decoded == stream.stats.dropped
    finally:
        stream.close()
        stop([server])


@pytest.mark.slow
def test_detect_fps_caps_live_steps_on_their_frame_times(tmp_path):
    port = free_port()
    server = serve(write_video(tmp_path / "v.mp4", 50, 25.0), port)
    wait_serving([server], [port])
    try:
        with CameraSet([f"http://127.0.0.1:{port}/live.ts"], ["cam"], detect_fps=5.0) as cams:
            times = [s.t for _, s in zip(range(8), cams, strict=False)]
            stats = cams.stats()["cam"]
    finally:
        stop([server])
    # 8 steps span at least 7 gaps of 1/5 s, less at most one frame of the stream each
    rate = (len(times) - 1) / (times[-1] - times[0])
    assert rate <= 5.0 * 1.25, times
    assert stats.decoded <= len(times) + 1 < stats.grabbed
    assert math.isfinite(rate)
