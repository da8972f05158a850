"""Rendered checkerboard photos of known cameras, shared by the calibration tests."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.calibration.board import Board
from stereopose.sim.calibration import Renderer, _frame
from stereopose.types import Camera

BOARD = Board(9, 6, 0.08)
CAMERA = Camera(
    "cam07",
    (1280.0, 720.0),
    np.array([[900.0, 0.0, 650.0], [0.0, 905.0, 350.0], [0.0, 0.0, 1.0]]),
    np.array([-0.25, 0.08, 0.001, -0.0005]),
    np.zeros(3),
    np.zeros(3),
)


def board_pose(rng: np.random.Generator, board: Board = BOARD) -> np.ndarray:
    """A board 1.4-2.6 m in front of a camera at the origin, tilted and turned."""
    at = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.35, 0.35), rng.uniform(1.4, 2.6)])
    R = _frame(np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.35, 3), rng.uniform(-0.5, 0.5))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = at - R @ (0.5 * board.square_m * np.array([board.cols - 1, board.rows - 1, 0]))
    return T


@pytest.fixture(scope="session")
def board() -> Board:
    return BOARD


@pytest.fixture(scope="session")
def camera() -> Camera:
    return CAMERA


@pytest.fixture(scope="session")
def rendered() -> tuple[list[np.ndarray], list[np.ndarray]]:
    """12 photos of BOARD by CAMERA (blur, noise, uneven light) and the board poses."""
    rng = np.random.default_rng(0)
    r = Renderer(CAMERA, BOARD)
    poses = [board_pose(rng) for _ in range(12)]
    return [r.render(T, rng) for T in poses], poses
