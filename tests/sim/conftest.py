"""Simulated scenes shared by the sim tests (built once per session)."""

from __future__ import annotations

import pytest

from stereopose.sim import Scene, simulate


@pytest.fixture(scope="session")
def mid_scene() -> Scene:
    return simulate(difficulty="mid", num_frames=200, seed=3)


@pytest.fixture(scope="session")
def hard_scene() -> Scene:
    return simulate(difficulty="hard", num_frames=400, seed=5)


@pytest.fixture(scope="session")
def easy_scene() -> Scene:
    return simulate(difficulty="easy", num_frames=200, seed=7)
