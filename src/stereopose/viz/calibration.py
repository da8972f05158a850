"""Calibration report pictures (PNG, matplotlib): reprojection errors, corner coverage, and
the rig with its board positions seen from above and from the side."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np

from stereopose.calibration.board import Board
from stereopose.types import Rig


def _plt() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def intrinsics_png(path: Path, results: dict, detections: dict) -> Path:
    """Per camera: corners of the photos used over the image frame, and the histogram of the
    photos' reprojection errors."""
    plt = _plt()
    names = sorted(results)
    fig, axes = plt.subplots(2, len(names), figsize=(3.2 * len(names), 6.4), squeeze=False)
    for k, name in enumerate(names):
        r = results[name]
        w, h = r.camera.size
        ax = axes[0, k]
        for d in detections[name]:
            if d.corners is not None and d.name in r.used:
                ax.plot(*d.corners.points.T, ".", ms=2)
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: {len(r.used)} photos, {100 * r.coverage:.0f}% covered", fontsize=9)
        ax = axes[1, k]
        ax.hist(list(r.view_rms_px.values()), bins=10, color="tab:blue")
        ax.set_xlabel("photo RMS reprojection error (px)")
        ax.set_title(f"fx {r.camera.matrix[0, 0]:.1f} px, RMS {r.rms_px:.2f} px", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def extrinsics_png(
    path: Path, rig: Rig, board: Board, board_poses: dict, residuals: np.ndarray
) -> Path:
    """Reprojection error histogram, and cameras and board positions from above (x-y) and
    from the side (x-z), world frame."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    ax = axes[0]
    ax.hist(residuals, bins=40, color="tab:blue")
    ax.set_xlabel("corner reprojection error (px)")
    ax.set_title(
        f"RMS {np.sqrt(np.mean(np.square(residuals))):.2f} px over {len(residuals)} corners"
    )
    obj = board.object_points()
    outline = obj[[0, board.cols - 1, board.count - 1, board.count - board.cols, 0]]
    for ax, (i, j), title in (
        (axes[1], (0, 1), "from above (x, y)"),
        (axes[2], (0, 2), "from the side (x, z)"),
    ):
        for T in board_poses.values():
            o = outline @ T[:3, :3].T + T[:3, 3]
            ax.plot(o[:, i], o[:, j], "-", color="0.6", lw=1)
        for cam in rig:
            c = cam.center
            look = cam.R[2]  # optical axis in the world
            ax.plot(c[i], c[j], "o", color="tab:red")
            ax.annotate(
                "",
                xy=(c[i] + 0.8 * look[i], c[j] + 0.8 * look[j]),
                xytext=(c[i], c[j]),
                arrowprops={"arrowstyle": "->", "color": "tab:red"},
            )
            ax.text(c[i], c[j], f" {cam.name}", fontsize=8)
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)" if j == 1 else "z (m)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
