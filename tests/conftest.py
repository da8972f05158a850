"""Shared fixtures: the real-data folders beside the repository."""

from __future__ import annotations

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
