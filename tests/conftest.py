"""Shared fixtures: the real-data folders beside the repository; every test leaves the
process's signal handlers as it found them."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from stereopose.io.pose2sim_data import pose2sim_demo_dir


@pytest.fixture(scope="session")
def shared_data_dir() -> Path:
    """YOLO11n-pose detections of Pose2Sim's multi-person demo, in ``shared/`` beside the repo."""
    path = Path(__file__).resolve().parents[2] / "shared" / "data" / "pose2sim-demo-yolo11n"
    if not path.is_dir():
        pytest.skip(f"shared real data not found at {path}")
    return path


@pytest.fixture(scope="session")
def pose2sim_dir() -> Path:
    """Pose2Sim demo files (downloaded from PyPI once, then cached)."""
    return pose2sim_demo_dir()


@pytest.fixture(scope="session")
def real_demo_dir(tmp_path_factory) -> Path:
    """The real demo (`stereopose demo`, as `make demo` runs it), run once per session."""
    from stereopose.cli import main

    out = tmp_path_factory.mktemp("demo")
    assert main(["demo", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="session")
def scene():
    """A small simulated scene: 3 cameras, 2 workers, 30 frames (the frame loop's and the
    service's tests)."""
    from stereopose.sim import simulate

    return simulate(num_cameras=3, num_people=2, num_frames=30, seed=2, difficulty="easy")


# what a test (or the service it runs in-process) may set and must put back: a handler left
# behind changes what every later test's Ctrl-C or SIGTERM does
WATCHED_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGUSR1, signal.SIGUSR2)


@pytest.fixture(autouse=True)
def signals_left_as_found(request):
    """Fail the test that leaves a signal handler changed (and put the handler back, so that
    the tests after it run as they would alone)."""
    before = {s: signal.getsignal(s) for s in WATCHED_SIGNALS}
    yield
    changed = [s for s, h in before.items() if signal.getsignal(s) is not h]
    for s in changed:
        signal.signal(s, before[s])
    if changed:
        names = ", ".join(signal.Signals(s).name for s in changed)
        pytest.fail(f"{request.node.nodeid} left the handler of {names} changed")
