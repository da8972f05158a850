"""A live camera decoded in a process of its own, against a real stream (ffmpeg over HTTP): its
frames come as in-process, and a decoder killed (SIGKILL, SIGSEGV) or hung (SIGSTOP) loses
that camera alone, within a second, and it is back once its stream is, with every replaced
decoder counted and its shared memory removed."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from stereopose.io.cameraset import CameraSet
from stereopose.io.stream import StreamWaits
from stereopose.io.stream_process import ProcessStream
from streams import free_port, serve, stop, wait_serving, write_video
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
            pid = bad.decoder_pid
            os.kill(pid, sig)
            killed = time.monotonic()
            # hung: killed after twice the timeout and a second; died: seen at once
            limit = 2 * 1.0 + 2.0 if sig == signal.SIGSTOP else 1.0
            wait_until(lambda: not bad.connected, "the camera lost", timeout_s=limit + 1)
            assert time.monotonic() - killed <= limit + 0.5
            assert good.connected
            for _ in range(5):  # the other camera goes on meanwhile
                _frame(good, timeout_s=2.0)
            # the server serves one client: started again, the stream is good again
            stop([servers[0]])
            servers[0] = serve(video, ports[0], "cam0")
            wait_serving([servers[0]], [ports[0]])
            good_again = time.monotonic()
            wait_until(lambda: bad.connected, "the camera back", timeout_s=15)
            assert bad.decoder_pid != pid
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
