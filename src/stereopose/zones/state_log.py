"""A recorded job judged with the states its site had: a switching log (CSV) that says when each
energized zone was live or dead, read by `run` and `reconstruct --zone-states FILE`.

    time,zone,state
    0,bay2_panel,live
    12.5,bay2_panel,dead             # switched out and earthed 12.5 s into the recording
    80,bay2_panel.qe2,open           # or a point of the zone's state (its [zones.state]):
                                     # its value, judged by the zone's rule

`time`: seconds from the recording's start (the steps' time). `zone`: a zone of the site, or
`<zone>.<point>` for one of its state's points. `state`: `live`, `dead` or `unknown` for a zone;
a point's value (`open`, `closed`, `on`, `off`, a number) for a point. Rows may come in any
order (sorted by time, stably). Before its first row a zone is live, as a run without a log
has every zone (unknown is live too). At each step the rows due are applied; a zone whose state
changed gives `zone_live`, `zone_dead` or `zone_unknown` (source: the log's file and line), a
dead zone's entries are information, and someone inside a zone that turns live again is an
alarm at once, as `serve` does with the breakers read live. A bad row is a ConfigError naming
the file, the line and the problem.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from stereopose.errors import ConfigError
from stereopose.types import Event
from stereopose.zones.power_state import DEAD, LIVE, UNKNOWN, Occupancy, entries, state_event
from stereopose.zones.safe import Safe
from stereopose.zones.zone import Zone

__all__ = ["StateLogFile", "StateRow", "ZoneStateLog", "read_state_log"]

MAX_ROWS = 100_000
STATES = (LIVE, DEAD, UNKNOWN)


class Moment(Protocol):
    """The step a rule runs at (pipeline.step_rules.StepContext)."""

    t: float
    frame: int


@dataclass(frozen=True)
class StateRow:
    """One row: at `t` seconds, a zone's state, or (point not None) one of its points' value."""

    t: float
    zone: str
    point: str | None
    value: object
    line: int


@dataclass(frozen=True)
class StateLogFile:
    """A switching log read and checked against a site (`read`), before any work: its rows,
    made a step's rule for each run (`rule`)."""

    path: Path
    rows: tuple[StateRow, ...]

    @classmethod
    def read(cls, path: str | Path, zones: Sequence[Zone]) -> StateLogFile:
        return cls(Path(path), tuple(read_state_log(path, zones)))

    def rule(self, zones: Sequence[Zone], monitor: Occupancy | None = None) -> ZoneStateLog:
        return ZoneStateLog(self.rows, zones, self.path.name, monitor)


def read_state_log(path: str | Path, zones: Sequence[Zone]) -> list[StateRow]:
    """The rows of a switching log (see the module), checked against the site's zones."""
    path = Path(path)
    by_name = {z.name: z for z in zones}
    try:
        with open(path, encoding="utf-8", newline="") as f:
            reader = csv.reader(line for line in f if not line.lstrip().startswith("#"))
            head = next(reader, None)
            if head is None or [h.strip().lower() for h in head] != ["time", "zone", "state"]:
                raise ConfigError(f"{path}: the first line must be `time,zone,state`")
            rows = [_row(path, n, cells, by_name) for n, cells in enumerate(reader, 2) if cells]
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the switching log: {e.strerror}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: the switching log is not UTF-8 text") from None
    except csv.Error as e:
        raise ConfigError(f"{path}: not a CSV file: {e}") from None
    if len(rows) > MAX_ROWS:
        raise ConfigError(f"{path}: {len(rows)} rows; a switching log holds at most {MAX_ROWS}")
    if not rows:
        raise ConfigError(f"{path}: the switching log has no rows")
    return sorted(rows, key=lambda r: r.t)


def _row(path: Path, line: int, cells: list[str], zones: Mapping[str, Zone]) -> StateRow:
    where = f"{path}:{line}"
    if len(cells) != 3:
        raise ConfigError(f"{where}: expected time,zone,state; got {len(cells)} value(s)")
    when, name, state = (c.strip() for c in cells)
    try:
        t = float(when)
    except ValueError:
        raise ConfigError(f"{where}: time {when!r}: expected seconds") from None
    if not math.isfinite(t) or t < 0:
        raise ConfigError(f"{where}: time {when!r}: expected seconds from 0")
    zone, _, point = name.partition(".")
    z = zones.get(zone)
    if z is None or z.kind != "energized":
        known = ", ".join(n for n, zz in zones.items() if zz.kind == "energized") or "none"
        raise ConfigError(f"{where}: {zone!r} is not an energized zone of the site ({known})")
    if not point:
        if state not in STATES:
            raise ConfigError(f"{where}: state {state!r}: expected one of {', '.join(STATES)}")
        return StateRow(t, zone, None, state, line)
    names = [p.name for p in z.power.points] if z.power is not None else []
    if point not in names:
        raise ConfigError(
            f"{where}: {zone!r} has no state point {point!r} "
            f"(its points: {', '.join(names) or 'none: give the zone its state'})"
        )
    return StateRow(t, zone, point, _value(state), line)


def _value(text: str) -> Any:
    try:
        number = float(text)
    except ValueError:
        return text
    return number if math.isfinite(number) else text


class ZoneStateLog:
    """The zones' states of a switching log as a step's rule (pipeline.step_rules): `step(ctx)`
    applies the rows due by ctx.t; `safe_now()` the dead zones. monitor: the fence monitor
    (who is inside a zone turning live)."""

    def __init__(
        self,
        rows: Sequence[StateRow],
        zones: Sequence[Zone],
        source: str,
        monitor: Occupancy | None = None,
    ) -> None:
        self.rows, self.source, self.monitor = list(rows), source, monitor
        self.zones = {z.name: z for z in zones}
        self.states: dict[str, str] = {}  # a zone in the log -> its state (before: live)
        self.points: dict[str, dict[str, object]] = {}  # zone -> its points' values so far
        self.used: list[dict] = []  # each change: {"t", "zone", "state", "line"}
        self._next = 0
        self._dead: dict[str, str] = {}

    def step(self, ctx: Moment) -> list[Event]:
        t, frame = float(ctx.t), int(ctx.frame)
        changed: dict[str, int] = {}  # zone -> the line that changed it last
        while self._next < len(self.rows) and self.rows[self._next].t <= t:
            r = self.rows[self._next]
            self._next += 1
            if r.point is None:
                state = str(r.value)  # a state, as read
            else:
                self.points.setdefault(r.zone, {})[r.point] = r.value
                state = self._judge(self.zones[r.zone])
            if state != self.states.get(r.zone, LIVE) or r.zone not in self.states:
                changed[r.zone] = r.line
            self.states[r.zone] = state
        out: list[Event] = []
        for name, line in changed.items():
            zone, state = self.zones[name], self.states[name]
            text = f"{self.source}:{line}"
            self.used.append({"t": t, "zone": name, "state": state, "line": line})
            out.append(state_event(t, frame, zone, f"zone_{state}", text))
            was_dead = self._dead.get(name) is not None
            if was_dead and state != DEAD and self.monitor is not None:
                out += entries(t, frame, zone, self.monitor, text)
            if state == DEAD:
                self._dead[name] = text
            else:
                self._dead.pop(name, None)
        return out

    def _judge(self, zone: Zone) -> str:
        spec, values = zone.power, self.points.get(zone.name, {})
        if spec is None or any(p.name not in values for p in spec.points):
            return UNKNOWN
        try:
            return DEAD if spec.is_dead(values) else LIVE
        except (ValueError, TypeError, KeyError):
            return UNKNOWN

    def safe_now(self) -> dict[str, Safe]:
        return {zone: Safe.dead(source) for zone, source in self._dead.items()}
