"""A live camera decoded in a process of its own, against a real stream (ffmpeg over HTTP): its
frames come as in-process, and a decoder killed (SIGKILL, SIGSEGV) or hung (SIGSTOP) loses
that camera alone, within a second, and it is back once its stream is, with every replaced
decoder counted and its shared memory removed. Hostile streams too: one that stops mid-way
with its connection held open, one whose frames pass the decoder's memory bound."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import psutil
import pytest

from stereopose.io.cameraset import CameraSet
from stereopose.io.stream import StreamWaits
from stereopose.io.stream_process import ProcessStream
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

pytestmark = pytest.mark.slow


@pytest.fixture
def video(tmp_path) -> Path:
    return write_video(tmp_path / "loop.mp4", 50, 25.0, size=(160, 120))


def _frame(stream: ProcessStream, timeout_s: float = 10.0):
    stream.request()
    return wait_until(stream.latest, f"a frame of {stream.name}", timeout_s=timeout_s)


def _ours() -> set[str]:
    return {p.name for p in Path("/dev/shm").glob("psm_*")}


def test_frames_come_newest_first_as_in_process(video) -> None:
    port = free_port()
    servers = [serve(video, port)]
    before = _ours()
    try:
        wait_serving(servers, [port])
        source = ProcessStream(f"http://127.0.0.1:{port}/live.ts", "cam")
        try:
            seq, t, image = _frame(source)
            assert image.shape == (120, 160, 3) and source.shape == (120, 160)
            assert source.decoder_pid is not None and source.decoder_pid != os.getpid()
            assert source.connected and source.fps is not None and source.fps > 0
            # frames arrive unasked: taken, not converted, counted dropped
            wait_until(lambda: source.stats.dropped >= 1, "a frame taken unasked", timeout_s=5)
            seq2, t2, _ = _frame(source)
            assert seq2 > seq + 1 and t2 > t
            assert source.stats.dropped >= 1 and source.stats.decoded == 2
        finally:
            source.close()
    finally:
        stop(servers)
    assert _ours() <= before  # the shared memory removed


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSEGV, signal.SIGSTOP])
def test_a_decoder_that_dies_or_hangs_loses_its_camera_alone(video, sig) -> None:
    ports = [free_port(), free_port()]
    servers = [serve(video, p, f"cam{k}") for k, p in enumerate(ports)]
    before = _ours()
    try:
        wait_serving(servers, ports)
        urls = [f"http://127.0.0.1:{p}/cam{k}.ts" for k, p in enumerate(ports)]
        with CameraSet(urls, ["cam0", "cam1"], open_timeout_s=1.0, decoders="process") as cams:
            bad, good = cams.sources
            _frame(bad)
            _frame(good)
            assert not cams.lost("cam0")  # opened and delivering: not lost
            pid = bad.decoder_pid
            os.kill(pid, sig)
            killed = time.monotonic()
            # hung: killed after twice the timeout and a second; died: seen at once
            limit = 2 * 1.0 + 2.0 if sig == signal.SIGSTOP else 1.0
            wait_until(lambda: not bad.connected, "the camera lost", timeout_s=limit + 1)
            assert time.monotonic() - killed <= limit + 0.5
            assert good.connected
            assert bad.lost and cams.lost("cam0") and not cams.lost("cam1")  # known lost
            for _ in range(5):  # the other camera goes on meanwhile
                _frame(good, timeout_s=2.0)
            # the server serves one client: started again, the stream is good again
            stop([servers[0]])
            servers[0] = serve(video, ports[0], "cam0")
            wait_serving([servers[0]], [ports[0]])
            good_again = time.monotonic()
            wait_until(lambda: bad.connected, "the camera back", timeout_s=15)
            assert bad.decoder_pid != pid and not cams.lost("cam0")
            _frame(bad)
            back_s = time.monotonic() - good_again
            why = "decoder hung" if sig == signal.SIGSTOP else "decoder died"
            assert bad.decoder_restarts.get(why) == 1, bad.decoder_restarts
            assert good.decoder_restarts == {}
            assert back_s < 12, back_s  # the backoff's first waits, and an open
    finally:
        stop(servers)
    assert _ours() <= before


def test_a_stream_kept_encoded_stays_in_process() -> None:
    with pytest.raises(ValueError, match="in-process"):
        ProcessStream("http://127.0.0.1:9/x.ts", "cam", StreamWaits(), packets=object())


def test_a_stream_that_stops_mid_way_loses_its_camera_alone(video, tmp_path) -> None:
    """A hostile camera: a few good frames, then the connection held open with nothing more.
    Its camera is lost (FFmpeg's read timeout in the decoder, or the service's hung watch),
    the other camera goes on, and it is back once a good stream is served there."""
    head = transport_stream(video, tmp_path / "head.ts")
    good_port = free_port()
    servers = [serve(video, good_port, "cam1")]
    stalling = StallingServer(head)
    port = stalling.port
    try:
        wait_serving(servers, [good_port])
        urls = [stalling.url("cam0"), f"http://127.0.0.1:{good_port}/cam1.ts"]
        with CameraSet(urls, ["cam0", "cam1"], open_timeout_s=1.0, decoders="process") as cams:
            bad, good = cams.sources
            wait_until(lambda: bad.connected, "the hostile camera's first frames", timeout_s=15)
            wait_until(lambda: not bad.connected, "the camera lost", timeout_s=2 * 1.0 + 3.0)
            for _ in range(5):  # the other camera goes on meanwhile
                _frame(good, timeout_s=2.0)
            assert good.connected and good.decoder_restarts == {}
            stalling.close()
            servers.append(serve(video, port, "cam0"))
            wait_serving([servers[-1]], [port])
            wait_until(lambda: bad.connected, "the camera back", timeout_s=15)
            _frame(bad)
    finally:
        stalling.close()
        stop(servers)


def test_a_stream_too_large_for_its_decoder_s_memory_loses_its_camera_alone(tmp_path) -> None:
    """A camera whose frames make its decoder pass its memory bound (here 4K frames, against
    a bound set just above a small stream's decoder): killed and started again, counted and
    said why; the service's own memory is not the one that grows."""
    small = write_video(tmp_path / "small.mp4", 50, 25.0, size=(160, 120))
    large = write_video(tmp_path / "large.mp4", 10, 25.0, size=(3840, 2160))
    ports = [free_port(), free_port()]
    servers = [serve(large, ports[0], "big"), serve(small, ports[1], "small")]
    try:
        wait_serving(servers, ports)
        fine = ProcessStream(f"http://127.0.0.1:{ports[1]}/small.ts", "small")
        try:
            _frame(fine)
            base = psutil.Process(fine.decoder_pid).memory_info().rss / 1e6
            big = ProcessStream(f"http://127.0.0.1:{ports[0]}/big.ts", "big", max_mb=base + 40.0)
            try:
                wait_until(
                    lambda: big.decoder_restarts.get("decoder over its memory", 0) >= 1,
                    "the 4K decoder replaced for its memory",
                    timeout_s=30,
                )
                assert fine.connected and fine.decoder_restarts == {}
                _frame(fine, timeout_s=2.0)  # the small camera goes on
            finally:
                big.close()
        finally:
            fine.close()
    finally:
        stop(servers)


def test_a_camera_is_known_lost_by_the_stream_it_is_detected_on(video) -> None:
    """With a detection substream, the camera is lost when its substream is, not when only its
    full stream (kept for the clips) is: its steps still come."""
    ports = [free_port(), free_port()]
    servers = [serve(video, ports[0], "main"), serve(video, ports[1], "sub")]
    try:
        wait_serving(servers, ports)
        main = f"http://127.0.0.1:{ports[0]}/main.ts"
        sub = f"http://127.0.0.1:{ports[1]}/sub.ts"
        with CameraSet(
            [main], ["cam0"], detect=[sub], open_timeout_s=1.0, decoders="process"
        ) as cams:
            full, detected = cams.sources[0], cams.detect_sources["cam0"]
            assert isinstance(full, ProcessStream) and isinstance(detected, ProcessStream)
            _frame(full)
            _frame(detected)
            assert not cams.lost("cam0")
            os.kill(full.decoder_pid, signal.SIGKILL)  # its server serves one client: gone
            wait_until(lambda: full.lost, "the full stream lost", timeout_s=5)
            assert not cams.lost("cam0")  # still seen on its substream
            _frame(detected, timeout_s=2.0)
            os.kill(detected.decoder_pid, signal.SIGKILL)
            wait_until(lambda: cams.lost("cam0"), "the camera lost", timeout_s=5)
    finally:
        stop(servers)
