"""What the commands share: the consoles, progress bars, configuration overrides."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from stereopose.config import Config, load_config, with_overrides
from stereopose.errors import IncompleteOutputError, StereoposeError
from stereopose.io.summary import RunSummary

if TYPE_CHECKING:
    from stereopose.tracking.positioning import Trajectory

console = Console(stderr=True)
out = Console()


def _progress() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    )


def _config(args: argparse.Namespace) -> Config:
    cfg = load_config(args.config)
    if getattr(args, "mode", None):
        cfg = with_overrides(cfg, triangulation={"mode": args.mode})
    if getattr(args, "no_tracking", False):
        cfg = with_overrides(cfg, tracking={"enabled": False})
    if getattr(args, "fps", None) is not None:
        if not args.fps > 0:
            raise StereoposeError(f"--fps must be positive, got {args.fps}")
        cfg = dataclasses.replace(cfg, fps=args.fps)
    return cfg


def run_summary(e: IncompleteOutputError) -> RunSummary:
    """The summary of a run that finished without writing every output (its table is shown
    before exit 3); the error itself where it holds none."""
    if not isinstance(e.summary, RunSummary):
        raise e
    return e.summary


def _px(value: float) -> str:
    return f"{value:.2f} px" if value == value else "n/a (no joint reconstructed)"


def _trajectory_table(trajectories: Sequence[Trajectory]) -> Table:
    table = Table(title="People tracked")
    for col in ("id", "first frame", "last frame", "time in view s", "frames seen", "path m"):
        table.add_column(col, justify="right")
    for t in trajectories:
        table.add_row(
            str(t.id),
            str(t.first_frame),
            str(t.last_frame),
            f"{t.duration_s:.1f}",
            str(t.frames_seen),
            f"{t.path_m:.1f}",
        )
    return table


def rate_progress(label: str) -> Progress:
    """A progress bar with the frame rate: label, bar, done/total, frames/s, time left."""
    return Progress(
        TextColumn(label),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[fps]:.1f} frames/s"),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    )
