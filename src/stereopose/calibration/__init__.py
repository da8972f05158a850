"""Camera calibration: file formats (native TOML, Qualisys import) and solvers."""

from __future__ import annotations

from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.calibration.qualisys import read_qca

__all__ = ["load_calibration", "read_qca", "save_calibration"]
