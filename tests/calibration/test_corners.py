"""Board sizes and corner detection on rendered photos."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.calibration.board import Board
from stereopose.calibration.corners import canonical, find_corners
from stereopose.errors import CalibrationError
from stereopose.geometry.camera import project


@pytest.mark.parametrize(
    ("text", "cols", "rows"), [("14x10", 14, 10), (" 4 X 7 ", 4, 7), ("9*6", 9, 6)]
)
def test_board_sizes(text: str, cols: int, rows: int) -> None:
    b = Board.parse(text, 0.05)
    assert (b.cols, b.rows, b.count) == (cols, rows, cols * rows)
    obj = b.object_points()
    assert obj[cols] == pytest.approx([0.0, 0.05, 0.0])


@pytest.mark.parametrize(
    ("text", "square", "message"),
    [
        ("15", 0.05, "expected COLSxROWS inner corners, e.g. 14x10"),
        ("1x5", 0.05, "at least 2x2"),
        ("6x6", 0.05, "two sides"),
        ("6x4", 0.0, "square size must be positive"),
    ],
)
def test_bad_board_sizes(text: str, square: float, message: str) -> None:
    with pytest.raises(CalibrationError, match=message):
        Board.parse(text, square)


def test_corners_match_the_rendered_truth(rendered, board, camera) -> None:
    images, poses = rendered
    for img, T in zip(images, poses, strict=True):
        found = find_corners(img, board)
        assert found is not None
        truth = project(board.object_points() @ T[:3, :3].T + T[:3, 3], camera)
        # the same corners, possibly in the half-turned order
        err = min(
            np.linalg.norm(found.points - truth, axis=-1).max(),
            np.linalg.norm(found.points[::-1] - truth, axis=-1).max(),
        )
        assert err < 0.3


def test_no_board_and_wrong_size_find_nothing(rendered, board) -> None:
    blank = np.full((720, 1280), 128, np.uint8)
    assert find_corners(blank, board) is None
    assert find_corners(rendered[0][0], Board(7, 5, 0.08)) is None


def test_canonical_order_undoes_transposed_and_mirrored_grids() -> None:
    b = Board(4, 3, 0.1)
    grid = np.stack(np.meshgrid(np.arange(4), np.arange(3)), -1).reshape(-1, 2) * 50.0 + 100
    assert np.array_equal(canonical(grid, b), grid)
    transposed = grid.reshape(3, 4, 2).transpose(1, 0, 2).reshape(-1, 2)
    assert np.array_equal(canonical(transposed, b), grid)
    mirrored = grid.reshape(3, 4, 2)[:, ::-1].reshape(-1, 2)
    assert np.array_equal(canonical(mirrored, b), grid)
