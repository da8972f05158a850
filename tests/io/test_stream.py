"""Live cameras against real local servers that refuse, hang or stall: every wait bounded and
explained; live frames carry their arrival time; recorded time alignment always ends."""

from __future__ import annotations

import itertools
import logging
import math
import threading
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from stereopose.io.cameraset import CameraSet
from stereopose.io.stream import JOIN_S, LiveStream, StreamWaits, redact, why_not_open
from stereopose.io.video import VideoError, open_source, source_name
from streams import (
    StallingServer,
    free_port,
    serve,
    stop,
    transport_stream,
    wait_serving,
    write_video,
)
from waiting import wait_until


def test_cameras_that_refuse_end_with_an_error_naming_each(caplog) -> None:
    north, south = free_port(), free_port()
    urls = [f"rtsp://127.0.0.1:{north}/", f"http://user:secret@127.0.0.1:{south}/b.ts"]
    with caplog.at_level(logging.WARNING), pytest.raises(VideoError) as err:
        CameraSet(urls, names=["north", "south"], first_frame_timeout_s=1.0)
    msg = str(err.value)
    assert "no camera delivered a frame within 1 s" in msg
    assert f"north (rtsp://127.0.0.1:{north}/): connection refused" in msg
    assert f"south (http://user:***@127.0.0.1:{south}/b.ts): connection refused" in msg
    assert "first_frame_timeout_s" in msg and "secret" not in msg + caplog.text
    assert (
        f"waiting for camera north (rtsp://127.0.0.1:{north}/): connection refused; retry in"
        in caplog.text
    )


def test_a_server_that_accepts_but_never_sends_is_a_clear_error() -> None:
    with StallingServer() as server, pytest.raises(VideoError) as err:
        CameraSet([server.url("cam")], open_timeout_s=0.3, first_frame_timeout_s=1.0)
    assert f"cam ({server.url('cam')}): the server accepts connections but no video" in str(
        err.value
    )


def test_close_returns_while_a_stream_is_still_opening() -> None:
    with StallingServer() as server:
        stream = LiveStream(
            server.url(), "cam", StreamWaits(timeout_s=60.0)
        )  # FFmpeg would wait 60 s
        wait_until(lambda: server.clients, "the camera to connect")
        closing = threading.Thread(target=stream.close)
        closing.start()
        wait_until(lambda: not closing.is_alive(), "close()", timeout_s=JOIN_S + 2)
        assert not stream.delivered and not stream.connected


@pytest.fixture(scope="module")
def ts_bytes(tmp_path_factory) -> bytes:
    """A 1 s, 25 fps clip as the MPEG-TS bytes an HTTP camera sends."""
    folder = tmp_path_factory.mktemp("ts")
    return transport_stream(write_video(folder / "clip.mp4", 25, 25.0), folder / "clip.ts")


def test_a_camera_that_stops_sending_is_lost_logged_and_retried(ts_bytes, caplog) -> None:
    with caplog.at_level(logging.WARNING), StallingServer(ts_bytes) as server:
        stream = LiveStream(server.url(), "cam", StreamWaits(timeout_s=0.5, backoff_s=0.05))
        try:
            wait_until(lambda: stream.stats.reconnects >= 1, "the camera lost and back")
        finally:
            stream.close()
    assert stream.delivered and stream.stats.failures >= 1 and len(server.clients) >= 2
    assert "camera cam: stream" in caplog.text and "lost" in caplog.text and "back" in caplog.text


def test_why_a_stream_did_not_open_is_told_by_its_server() -> None:
    port = free_port()
    assert why_not_open(f"tcp://127.0.0.1:{port}", 1.0) == "connection refused"
    assert why_not_open("rtsp://nosuchhost.invalid/", 1.0) == "host nosuchhost.invalid not found"
    assert why_not_open("udp://127.0.0.1:5000", 1.0).startswith("no stream arrived within 1 s")
    assert why_not_open("http://[::1/x", 1.0).startswith("invalid URL")


def test_redact_hides_only_the_password() -> None:
    assert redact("rtsp://admin:pa55@10.0.0.5:554/ch1") == "rtsp://admin:***@10.0.0.5:554/ch1"
    assert redact("http://10.0.0.5/live.mjpg") == "http://10.0.0.5/live.mjpg"


# --- frame rates: refused at the boundary; recorded time alignment always ends ----------------


@pytest.fixture(scope="module")
def two_videos(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("videos")
    return [write_video(folder / "a.mp4", 5, 25.0), write_video(folder / "b.mp4", 3, 10.0)]


@pytest.mark.parametrize("fps", [0, -5, -0.0, math.nan, math.inf, -math.inf, 1e-300, 1e300, True])
def test_rates_that_would_never_advance_are_refused(two_videos, fps) -> None:
    with pytest.raises(VideoError, match=r"fps .*must be a number from 0\.1 to 1000, got"):
        CameraSet(two_videos, sync="time", fps=fps)
    with pytest.raises(VideoError, match=r"a\.mp4: fps must be"):
        open_source(two_videos[0], fps=fps)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(fps=st.one_of(st.floats(), st.integers(-1000, 2000), st.none()))
@example(fps=1.0).via("the lowest rates: every frame its own step")
@example(fps=1000).via("the highest rate")
@example(fps=None).via("the cameras' own rates")
def test_time_alignment_ends_or_refuses_the_rate(two_videos, fps) -> None:
    try:
        cams = CameraSet(two_videos, sync="time", fps=fps)
    except VideoError:
        assert fps is not None and not 0.1 <= fps <= 1000
        return
    with cams:
        # at their own rates the longer video lasts 0.3 s; at a given rate, 5 frames
        bound = 6 if fps is not None else math.ceil(0.3 * cams.fps) + 2
        steps = 0
        for steps, _ in enumerate(cams, 1):
            assert steps <= bound, f"{steps} steps at {cams.fps} fps"
    assert steps >= 1


# --- the live clock -------------------------------------------------------------------------


@pytest.fixture
def live_video(tmp_path) -> Path:
    return write_video(tmp_path / "loop.mp4", 50, 25.0, size=(160, 120))


@pytest.mark.slow
def test_live_steps_carry_their_frames_arrival_time(live_video) -> None:
    """Frames come at 25 fps, steps are taken at a third of that: each step's t is when its
    frame arrived on the set's clock (not step / fps), strictly increasing."""
    port = free_port()
    server = serve(live_video, port)
    wait_serving([server], [port])
    seen: list[tuple[float, float]] = []  # (step t, clock time the step was taken)
    try:
        with CameraSet([f"http://127.0.0.1:{port}/live.ts"], names=["cam"]) as cams:
            stream = cams.sources[0]
            for step in cams:
                seen.append((step.t, cams.clock.since(time.monotonic())))
                assert step.times["cam"] == step.t
                if len(seen) == 10:
                    break
                dropped = stream.stats.dropped
                # a slow consumer: two more frames arrive (and are dropped) before the next step
                wait_until(lambda d=dropped: stream.stats.dropped >= d + 2, "2 frames dropped")
    finally:
        stop([server])
    ts = [t for t, _ in seen]
    assert all(b > a for a, b in itertools.pairwise(ts))
    for t, taken in seen:  # arrived before it was taken, and not long before
        assert taken - 0.5 < t <= taken
    span, taken_span = ts[-1] - ts[0], seen[-1][1] - seen[0][1]
    assert span == pytest.approx(taken_span, abs=0.3)
    assert span > 2 * 9 / cams.fps  # at least 3 frames per step: far from step / fps


_SCHEMES = st.sampled_from(["rtsp://", "http://", "udp://", "HTTPS://"])
_WORD = st.text("abcXYZ019-_", min_size=1, max_size=8)


@given(rest=st.text(), scheme=_SCHEMES)
def test_any_stream_url_gets_a_name_and_a_label(rest: str, scheme: str) -> None:
    assert source_name(scheme + rest) and isinstance(redact(scheme + rest), str)


@given(
    scheme=_SCHEMES,
    user=_WORD,
    password=st.text("abc019!$%;=~", min_size=1),
    host=_WORD,
    path=st.text(),
)
def test_a_urls_password_is_never_shown(scheme, user, password, host, path) -> None:
    shown = redact(f"{scheme}{user}:{password}@{host}:554/{path}")
    assert shown.startswith(f"{scheme}{user}:***@{host}:554/")
