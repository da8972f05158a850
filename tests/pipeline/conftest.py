"""Fixtures of the frame-loop tests."""

from __future__ import annotations

import pytest

from stereopose.sim import Scene, simulate


@pytest.fixture(scope="session")
def scene() -> Scene:
    """A small simulated scene: 3 cameras, 2 workers, 30 frames."""
    return simulate(num_cameras=3, num_people=2, num_frames=30, seed=2, difficulty="easy")
