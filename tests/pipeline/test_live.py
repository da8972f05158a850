"""`stereopose run` and `detect` on live cameras served on localhost: times follow the frames'
arrival, cameras that refuse or hang end in a clear error, and Ctrl-C always works."""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from stereopose.cli import main
from stereopose.io.results import read_poses
from streams import StallingServer, free_port, serve, stop, transport_stream, wait_serving
from streams import write_video as _write_video
from waiting import wait_until

pytestmark = pytest.mark.slow

SIZE = (160, 120)  # the served videos' frames, and the calibration's cameras


@pytest.fixture(scope="module", autouse=True)
def _model() -> None:
    """The runs detect with the default ONNX model, from the cache."""
    from stereopose.detection import ModelError
    from stereopose.detection.models import default_onnx

    try:
        default_onnx(export=False)
    except ModelError as e:
        pytest.skip(str(e))


def _calibration(path: Path) -> Path:
    """Two 160x120 cameras 5 m from the origin, looking at it from two sides."""
    cams = {"cam01": "[ 0.0, 0.0, 0.0]", "cam02": "[ 0.0, 1.5707963, 0.0]"}
    text = ""
    for name, rotation in cams.items():
        text += (
            f'[{name}]\nname = "{name}"\nsize = [ 160.0, 120.0]\n'
            "matrix = [ [ 150.0, 0.0, 80.0], [ 0.0, 150.0, 60.0], [ 0.0, 0.0, 1.0]]\n"
            "distortions = [ 0.0, 0.0, 0.0, 0.0]\n"
            f"rotation = {rotation}\ntranslation = [ 0.0, 0.0, 5.0]\nfisheye = false\n\n"
        )
    path.write_text(text)
    return path


def _config(tmp_path: Path, urls: dict[str, str], input_: str = "") -> Path:
    lines = [
        f'calibration = "{_calibration(tmp_path / "calib.toml")}"',
        f'output = "{tmp_path / "out"}"',
        "",
    ]
    for name, url in urls.items():
        lines += ["[[cameras]]", f'name = "{name}"', f'source = "{url}"', ""]
    lines += ["[detector]", "imgsz = 320", "threads = 1", "", "[input]", input_, ""]
    lines += ["[outputs]", "overlays = false", "report = false", ""]
    path = tmp_path / "run.toml"
    path.write_text("\n".join(lines))
    return path


def _stalling_urls(servers: list[StallingServer]) -> dict[str, str]:
    return {f"cam0{i + 1}": s.url(f"cam0{i + 1}") for i, s in enumerate(servers)}


# --- the live clock through the whole run --------------------------------------------------


@pytest.fixture(autouse=True)
def no_camera_thread_left():
    """A live camera's reader may outlive its close() (a read that ends only when its socket
    does): the next test starts once every reader has ended, so that no native read of one
    test runs on into another's (a detector loading, a signal raised)."""
    yield
    wait_until(
        lambda: not [t for t in threading.enumerate() if t.name.startswith("camera-")],
        "the cameras' reader threads ended",
        timeout_s=120,
    )


def test_live_run_times_follow_the_frames_arrival(tmp_path: Path) -> None:
    """Both cameras stream at 5 fps while the time steps are nominally 25 per second: each
    record's t is when its frames arrived (on the run's clock, clock_start_epoch + t on the
    wall clock), not step / 25."""
    from stereopose.pipeline.run import run

    video = _write_video(tmp_path / "slow.mp4", 20, 5.0, size=SIZE)
    ports = [free_port(), free_port()]
    servers = [serve(video, p, f"cam0{i + 1}", codec="mpeg4") for i, p in enumerate(ports)]
    wait_serving(servers, ports)
    urls = {f"cam0{i + 1}": f"http://127.0.0.1:{p}/cam0{i + 1}.ts" for i, p in enumerate(ports)}
    stepped: list[float] = []  # wall-clock time at the end of each step
    cfg = _config(tmp_path, urls, "fps = 25.0\nmax_frames = 12")
    try:
        summary = run(cfg, on_step=lambda done, total, fps: stepped.append(time.time()))
    finally:
        stop(servers)
    assert summary.live and summary.frames == 12 and summary.clock_start_epoch is not None
    ts = [t for _, t, _ in read_poses(tmp_path / "out" / "poses3d.jsonl")]
    assert len(ts) == 12 and all(b > a for a, b in itertools.pairwise(ts))
    walls = [summary.clock_start_epoch + t for t in ts]
    for k, wall in enumerate(walls):  # its frames arrived while the step was waited for
        assert wall <= stepped[k] + 0.01
        if k:
            assert wall >= stepped[k - 1] - 0.5
    assert ts[-1] - ts[0] == pytest.approx(stepped[-1] - stepped[0], abs=0.5)
    assert ts[-1] - ts[0] > 2 * 11 / 25  # at 25 steps/s the steps' times would span 0.44 s
    on_disk = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert on_disk["clock_start_epoch"] == summary.clock_start_epoch


# --- cameras that refuse or hang: bounded waits, clear errors ---------------------------------


def test_run_on_cameras_that_refuse_or_hang_is_a_clear_error(tmp_path: Path, capsys) -> None:
    refused = free_port()
    with StallingServer() as silent:
        urls = {"cam01": f"rtsp://127.0.0.1:{refused}/", "cam02": silent.url("cam02")}
        cfg = _config(tmp_path, urls, "open_timeout_s = 0.3\nfirst_frame_timeout_s = 1.0")
        assert main(["run", str(cfg)]) == 2
    err = " ".join(capsys.readouterr().err.split())  # the console wraps long lines
    assert "error: no camera delivered a frame within 1 s" in err and "Traceback" not in err
    assert f"cam01 (rtsp://127.0.0.1:{refused}/): connection refused" in err
    assert "cam02 (http://127.0.0.1:" in err and "accepts connections but no video" in err
    assert not (tmp_path / "out" / "poses3d.jsonl").exists()  # nothing written for no frame


# --- Ctrl-C on a real subprocess --------------------------------------------------------------


class Process:
    """`python -m stereopose.cli ARGS`, its output gathered on threads as it comes."""

    def __init__(self, *args: str) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1", COLUMNS="200")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
            text=True,
            # Ctrl-C as at a terminal, whatever an earlier test left the test process's SIGINT
            # at (an ignored signal is inherited, and Python then installs no handler)
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
        self.out: list[str] = []
        self.err: list[str] = []
        self._readers = [
            threading.Thread(target=self._gather, args=(f, sink), daemon=True)
            for f, sink in ((self.proc.stdout, self.out), (self.proc.stderr, self.err))
        ]
        for r in self._readers:
            r.start()

    @staticmethod
    def _gather(f, sink: list[str]) -> None:
        for line in f:
            sink.append(line)

    def said(self, text: str) -> bool:
        return self.proc.poll() is not None or text in "".join(self.out + self.err)

    def interrupt(self, timeout_s: float = 15.0) -> int:
        """Send one SIGINT; its exit code, which must come within timeout_s."""
        assert self.proc.poll() is None, "".join(self.err)
        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            for r in self._readers:
                r.join(timeout=5)
            pytest.fail(
                f"still running {timeout_s} s after one Ctrl-C; it said:\n{self.text()[-3000:]}"
            )
        for r in self._readers:
            r.join(timeout=5)
        return code

    def text(self) -> str:
        return "".join(self.out + self.err)


@pytest.fixture(scope="module")
def ts_bytes(tmp_path_factory) -> bytes:
    folder = tmp_path_factory.mktemp("ts")
    clip = _write_video(folder / "clip.mp4", 10, 25.0, size=SIZE)
    return transport_stream(clip, folder / "clip.ts")


def test_ctrl_c_ends_a_run_whose_cameras_hang_mid_stream(tmp_path: Path, ts_bytes) -> None:
    """Cameras send a few frames, then nothing (the reads hang for 60 s): one Ctrl-C ends the
    run at once, with exit code 130 and every output closed and readable."""
    with StallingServer(ts_bytes) as a, StallingServer(ts_bytes) as b:
        cfg = _config(tmp_path, _stalling_urls([a, b]), "open_timeout_s = 60.0")
        run = Process("run", str(cfg))
        poses = tmp_path / "out" / "poses3d.jsonl"
        wait_until(
            lambda: run.proc.poll() is not None or (poses.is_file() and poses.read_text()),
            "a first time step written",
            timeout_s=120,
        )
        code = run.interrupt()
    assert code == 130, run.text()
    assert "Traceback" not in run.text() and "interrupted" in run.text()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    frames = list(read_poses(poses))
    assert summary["interrupted"] and summary["frames"] == len(frames) >= 1


def test_ctrl_c_ends_detect_while_it_waits_for_a_first_frame(tmp_path: Path) -> None:
    with StallingServer() as silent:
        detect = Process(
            "detect", "--videos", silent.url("cam"), "--out", str(tmp_path / "kp"), "--imgsz", "320"
        )
        wait_until(lambda: detect.said("waiting for camera"), "the wait logged", timeout_s=120)
        code = detect.interrupt()
    assert code == 130, detect.text()
    assert "Traceback" not in detect.text()


def test_detect_stops_after_the_step_in_progress_at_the_first_ctrl_c(tmp_path: Path) -> None:
    from stereopose.detection import make_detector
    from stereopose.pipeline.detect import detect_videos

    videos = [_write_video(tmp_path / f"cam0{i}.mp4", 20, 25.0, size=SIZE) for i in (1, 2)]

    def interrupt(done, total, fps) -> None:
        if done == 2:
            signal.raise_signal(signal.SIGINT)

    before = signal.getsignal(signal.SIGINT)
    summary = detect_videos(
        videos, tmp_path / "kp", make_detector("onnx", imgsz=320), on_step=interrupt
    )
    assert summary.interrupted and summary.steps == 2 and signal.getsignal(signal.SIGINT) is before
    for cam in ("cam01", "cam02"):
        assert len(list((tmp_path / "kp" / f"{cam}_json").iterdir())) == 2
