"""`reconstruct` and `events`."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from rich.table import Table

from stereopose.cli.common import (
    _config,
    _progress,
    _px,
    _trajectory_table,
    out,
    run_summary,
)
from stereopose.errors import (
    CalibrationError,
    ConfigError,
    IncompleteOutputError,
    KeypointsError,
    StereoposeError,
)

if TYPE_CHECKING:
    from stereopose.fence import Site
    from stereopose.tickets import Ticket
    from stereopose.types import Event
    from stereopose.zones.state_log import StateLogFile


def _check_inputs(args: argparse.Namespace) -> None:
    """The input files, checked before the 3D stage is imported: a missing one is an error at
    once (the readers check their content later)."""
    if not Path(args.calib).exists():
        raise CalibrationError(f"{args.calib}: calibration file not found")
    if not Path(args.pose).is_dir():
        raise KeypointsError(f"{args.pose}: keypoints folder not found")
    if args.site and not Path(args.site).exists():
        raise ConfigError(f"{args.site}: site file not found")


def _site_files(args: argparse.Namespace) -> tuple[Site | None, Ticket | None, StateLogFile | None]:
    """The site, the ticket and the zones' switching log the command names: the outputs of
    zone events, the ticket and the log need the site."""
    from stereopose.fence import load_site
    from stereopose.tickets import load_ticket
    from stereopose.zones.state_log import StateLogFile

    site = load_site(args.site) if args.site else None
    ticket = load_ticket(args.ticket) if args.ticket else None
    if site is None and (
        args.events or args.events_db or args.webhook or ticket or args.zone_states
    ):
        raise StereoposeError(
            "--events, --events-db, --webhook, --ticket and --zone-states need a site file (--site)"
        )
    if site is None or not args.zone_states:
        return site, ticket, None
    return site, ticket, StateLogFile.read(args.zone_states, site.zones)


def _reconstruct(args: argparse.Namespace) -> int:
    cfg = _config(args)
    _check_inputs(args)
    from stereopose.io.sinks import describe
    from stereopose.pipeline import Outputs, reconstruct_files

    site, ticket, states = _site_files(args)
    if site is not None and site.fps and args.fps is None:
        cfg = dataclasses.replace(cfg, fps=site.fps)
    with _progress() as progress:

        def show(events: list[Event]) -> None:
            for e in events:
                progress.console.print(describe(e), markup=False, highlight=False)

        task = progress.add_task("reconstructing", total=None)
        outputs = Outputs.from_keywords(
            args.out,
            trc_dir=args.trc,
            csv_path=args.csv,
            tracks_path=args.tracks,
            events_path=args.events,
            events_db=args.events_db,
            webhook=args.webhook,
            two_way=args.two_way,
        )
        incomplete: IncompleteOutputError | None = None
        try:
            summary = reconstruct_files(
                args.calib,
                args.pose,
                None,
                cfg,
                on_frame=lambda done, total: progress.update(task, completed=done, total=total),
                outputs=outputs,
                site=site,
                on_events=show if site is not None else None,
                config_path=args.config,
                overwrite=args.overwrite,
                ticket=ticket,
                zone_states=states,
            )
        except IncompleteOutputError as e:  # the work is done: its table first, then exit 3
            incomplete, summary = e, run_summary(e)
    table = Table(title=f"3D poses written to {args.out}", show_header=False)
    table.add_row("cameras", ", ".join(summary.cameras))
    table.add_row("mode", summary.mode)
    table.add_row(
        "tracking",
        f"on: {len(summary.trajectories)} people, {summary.predicted} bridged person-frames"
        if summary.tracking
        else "off (ids are per frame)",
    )
    table.add_row("frames", str(summary.frames))
    hist = ", ".join(
        f"{v} frame{'s' * (v != 1)} with {k}" for k, v in sorted(summary.people_histogram.items())
    )
    table.add_row("people per frame", f"{summary.mean_people:.2f} on average ({hist})")
    table.add_row("joints reconstructed", str(summary.joints_reconstructed))
    table.add_row("mean reprojection error", _px(summary.mean_reprojection_px))
    table.add_row(
        "median reprojection error, conf > 0.5", _px(summary.median_confident_reprojection_px)
    )
    table.add_row("3D back end speed", f"{summary.fps_3d:.0f} frames/s")
    table.add_row("compiled loops loaded", f"in {summary.load_s_3d:.2f} s (before the first frame)")
    if site is not None:
        counts = ", ".join(f"{v} {k}" for k, v in sorted(summary.events.items())) or "none"
        table.add_row("zone events", f"{counts} ({len(site.zones)} zones)")
    if summary.skipped_files:
        table.add_row("skipped files", f"{len(summary.skipped_files)} (listed below)")
    out.print(table)
    if summary.trajectories:
        out.print(_trajectory_table(summary.trajectories))
    for path in summary.outputs:
        if path == outputs.poses:
            continue
        out.print(f"wrote {path}", markup=False, highlight=False, soft_wrap=True)
    for path, why in summary.skipped_files:
        out.print(f"skipped {path}: {why}", markup=False, highlight=False, soft_wrap=True)
    if incomplete is not None:
        incomplete.written = []  # listed above
        raise incomplete
    if summary.interrupted:
        out.print("interrupted: every output above is complete up to the last frame processed")
        return 130
    return 0


def _events(args: argparse.Namespace) -> int:
    import csv
    import math

    from rich.text import Text

    from stereopose.io.sinks.events import COLUMNS, query_events

    if args.since is not None and not math.isfinite(args.since):
        raise StereoposeError(f"--since must be a time in seconds, got {args.since}")
    rows = query_events(
        args.db, person=args.person, zone=args.zone, event_type=args.type, since=args.since
    )
    if args.csv:
        w = csv.writer(sys.stdout, lineterminator="\n")
        w.writerow(COLUMNS)
        w.writerows([r[c] for c in COLUMNS] for r in rows)
        return 0
    table = Table(title=Text(f"{len(rows)} event(s) in {args.db}"))
    cols = ("run", "t", "frame", "person", "zone", "kind", "type", "joint", "distance_m", "x", "y")
    for c in cols:
        table.add_column(c, justify="left" if c in ("zone", "kind", "type", "joint") else "right")
    for r in rows:
        # Text cells: a zone name from the log is shown as it is, never read as markup
        table.add_row(
            *(
                Text(
                    "" if r[c] is None else f"{r[c]:.2f}" if isinstance(r[c], float) else str(r[c])
                )
                for c in cols
            )
        )
    out.print(table)
    return 0
