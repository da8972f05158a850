"""Camera sources: files, image folders, live HTTP streams that drop out and come back."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.io.cameraset import CameraSet
from stereopose.io.stream import LiveStream
from stereopose.io.video import (
    ImageFolder,
    VideoError,
    VideoFile,
    source_name,
)
from streams import free_port as _free_port
from streams import serve as _serve
from streams import wait_serving as _wait_serving
from streams import write_video
from waiting import wait_until


def _level(image: np.ndarray) -> int:
    """The grey level a synthetic frame was written with (encoding blurs it a little)."""
    return round(float(image.mean()) / 10)


def test_video_file_frames_with_times(tmp_path):
    v = VideoFile(write_video(tmp_path / "a.mp4", 6, 20.0))
    assert (v.name, v.count, v.fps, v.shape) == ("a", 6, 20.0, (64, 96))
    items = []
    while (item := v.read()) is not None:
        items.append(item)
    assert [i for i, _, _ in items] == list(range(6))
    assert [t for _, t, _ in items] == pytest.approx([i / 20 for i in range(6)])
    assert [_level(im) for _, _, im in items] == list(range(6))


def test_cameras_aligned_by_index_go_on_after_one_ends(tmp_path):
    a = write_video(tmp_path / "a.mp4", 5, 25.0)
    b = write_video(tmp_path / "b.mp4", 3, 25.0)
    with CameraSet([a, b]) as cams:
        assert cams.names == ["a", "b"] and cams.count == 5
        steps = list(cams)
    assert len(steps) == 5
    assert [s.images["b"] is None for s in steps] == [False] * 3 + [True] * 2
    assert [_level(s.images["a"]) for s in steps] == list(range(5))
    assert steps[4].source_frames == {"a": 4}


def test_cameras_aligned_by_time_at_different_rates(tmp_path):
    fast = write_video(tmp_path / "fast.mp4", 10, 20.0)
    slow = write_video(tmp_path / "slow.mp4", 5, 10.0)
    with CameraSet([fast, slow], sync="time") as cams:
        assert cams.fps == 20.0
        steps = list(cams)
    assert len(steps) == 10
    assert [s.source_frames.get("slow") for s in steps] == [
        0,
        None,
        1,
        None,
        2,
        None,
        3,
        None,
        4,
        None,
    ]
    assert [s.source_frames["fast"] for s in steps] == list(range(10))
    assert steps[4].times == pytest.approx({"fast": 0.2, "slow": 0.2})


def test_image_folder_in_natural_order(tmp_path):
    for i in (10, 2, 1):
        cv2.imwrite(str(tmp_path / f"img_{i}.png"), np.full((8, 8, 3), 10 * i, np.uint8))
    (tmp_path / "notes.txt").write_text("not an image")
    folder = ImageFolder(tmp_path, fps=5)
    got = [folder.read() for _ in range(4)]
    assert [_level(g[2]) for g in got[:3]] == [1, 2, 10] and got[3] is None
    assert got[1][1] == pytest.approx(0.2)


def test_bad_sources_are_clear_errors(tmp_path):
    with pytest.raises(VideoError, match=r"missing\.mp4: video file not found"):
        VideoFile(tmp_path / "missing.mp4")
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(np.random.default_rng(0).bytes(4000))
    with pytest.raises(VideoError, match=r"junk\.mp4: cannot open"):
        VideoFile(junk)
    with pytest.raises(VideoError, match="no images"):
        ImageFolder(tmp_path)
    a = write_video(tmp_path / "a.mp4", 2, 25.0)
    with pytest.raises(VideoError, match="unique"):
        CameraSet([a, a])
    with pytest.raises(VideoError, match="2 camera names for 1 sources"):
        CameraSet([a], names=["x", "y"])
    with pytest.raises(VideoError, match="no camera sources"):
        CameraSet([])
    with pytest.raises(VideoError, match=r"junk\.mp4"):
        CameraSet([a, junk])


def test_truncated_video_ends_early_with_a_warning(tmp_path, caplog):
    full = write_video(tmp_path / "full.mp4", 40, 25.0, size=(320, 240))
    data = full.read_bytes()
    # mp4v files from OpenCV keep the index at the end: cut the middle of the frame data out
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[:2000] + data[len(data) // 2 :])
    try:
        v = VideoFile(cut)
    except VideoError as e:
        assert "cut.mp4" in str(e)
        return
    with caplog.at_level(logging.WARNING):
        n = 0
        while v.read() is not None:
            n += 1
    assert n < 40
    assert "cut.mp4" in caplog.text and "truncated or corrupt" in caplog.text


def test_stream_names():
    assert source_name("rtsp://10.0.0.5:554/Streaming/Channels/101") == "101"
    assert source_name("http://cam-north.local/live.mjpg?res=hd") == "live"
    assert source_name("/data/cam03.mp4") == "cam03"


# --- live streams: an HTTP MPEG-TS stream served by ffmpeg on localhost (tests/streams.py) ---


@pytest.fixture
def loop_video(tmp_path) -> Path:
    return write_video(tmp_path / "loop.mp4", 50, 25.0, size=(160, 120))


@pytest.mark.slow
def test_live_stream_drops_out_and_comes_back_while_another_goes_on(loop_video, caplog):
    port_a, port_b = _free_port(), _free_port()
    servers = [_serve(loop_video, port_a), _serve(loop_video, port_b)]
    _wait_serving(servers, [port_a, port_b])
    cams = CameraSet(
        [f"http://127.0.0.1:{port_a}/live.ts", f"http://127.0.0.1:{port_b}/live.ts"],
        names=["north", "south"],
    )
    for s in cams.sources:
        s.backoff_s = 0.2
    seen: dict[str, list[float]] = {"north": [], "south": []}
    outage = (0.0, 0.0)
    try:
        with caplog.at_level(logging.WARNING):
            start = time.monotonic()
            for step in cams:
                now = time.monotonic() - start
                for name, image in step.images.items():
                    if image is not None:
                        assert image.shape == (120, 160, 3)
                        seen[name].append(now)
                if now > 1.5 and servers[1].poll() is None and outage == (0.0, 0.0):
                    servers[1].kill()  # the south camera drops out ...
                    servers[1].wait()
                    outage = (now, now + 1.5)
                if outage[1] and now > outage[1] and len(servers) == 2:
                    servers.append(_serve(loop_video, port_b))  # ... and comes back
                if now > 6.0:
                    break
    finally:
        cams.close()
        for s in servers:
            s.kill()
            s.wait()
    south, north = cams.sources[1], cams.sources[0]
    assert south.stats.failures >= 1 and south.stats.reconnects >= 1
    assert any(t > outage[1] for t in seen["south"]), "south never came back"
    during = [t for t in seen["north"] if outage[0] + 0.3 < t < outage[1]]
    assert len(during) >= 10, "north stopped while south was down"
    assert north.stats.reconnects == 0
    assert "south: stream" in caplog.text and "lost" in caplog.text and "back" in caplog.text


@pytest.mark.slow
def test_live_stream_keeps_only_the_latest_frame(loop_video):
    port = _free_port()
    server = _serve(loop_video, port)
    _wait_serving([server], [port])
    stream = LiveStream(f"http://127.0.0.1:{port}/live.ts", "cam")
    try:
        assert stream.wait_connected(10)
        # a slow consumer: it reads nothing while frames keep arriving
        wait_until(lambda: stream.stats.dropped >= 10, "10 frames dropped unread")
        got = stream.latest()
        assert got is not None and stream.latest() is None  # nothing newer yet
        assert stream.stats.dropped >= 10
    finally:
        stream.close()
        server.kill()
        server.wait()


def test_empty_or_malformed_frames_are_left_out_with_a_warning(caplog):
    from stereopose.io.video import FrameSet, usable_images

    good = np.zeros((4, 6, 3), np.uint8)
    step = FrameSet(
        3,
        0.1,
        {
            "a": good,
            "b": None,
            "c": np.zeros((0, 6, 3), np.uint8),
            "d": np.zeros((4, 6), np.uint8),
            "e": np.zeros((4, 6, 3), np.float32),
        },
    )
    with caplog.at_level(logging.WARNING):
        assert [n for n, _ in usable_images(step)] == ["a"]
    assert "camera c: frame 3" in caplog.text and "camera e" in caplog.text
