"""The checkerboard: inner corners, square size, and its corner coordinates."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from stereopose.errors import CalibrationError


@dataclass(frozen=True)
class Board:
    """A checkerboard of `cols` x `rows` inner corners (a board of 15 x 11 squares has 14 x 10
    inner corners), squares of `square_m` metres.

    Corner k = r * cols + c lies at (c * square_m, r * square_m, 0) in the board's frame.
    """

    cols: int
    rows: int
    square_m: float

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise CalibrationError(
                f"board of {self.cols}x{self.rows} inner corners: needs at least 2x2"
            )
        if self.cols == self.rows:
            # a square grid has no orientation: corner order could turn by 90 degrees
            raise CalibrationError(
                f"board of {self.cols}x{self.rows} inner corners: use a board whose two sides "
                "differ (the corner order of a square grid is ambiguous)"
            )
        if not self.square_m > 0:
            raise CalibrationError(f"square size must be positive, got {self.square_m} m")

    @classmethod
    def parse(cls, size: str, square_m: float) -> Board:
        """'14x10' (inner corners) -> Board."""
        m = re.fullmatch(r"\s*(\d+)\s*[xX*]\s*(\d+)\s*", size)
        if not m:
            raise CalibrationError(
                f"board size {size!r}: expected COLSxROWS inner corners, e.g. 14x10 for a board "
                "of 15 x 11 squares"
            )
        return cls(int(m.group(1)), int(m.group(2)), float(square_m))

    @property
    def size(self) -> tuple[int, int]:
        return self.cols, self.rows

    @property
    def count(self) -> int:
        return self.cols * self.rows

    def object_points(self) -> np.ndarray:
        """(cols * rows, 3) corner coordinates in metres, board frame (z = 0)."""
        r, c = np.divmod(np.arange(self.count), self.cols)
        return np.stack([c * self.square_m, r * self.square_m, np.zeros(self.count)], axis=1)
