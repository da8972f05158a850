"""What a restarted service takes over from the event log of its earlier runs.

`stereopose serve` may be killed at any moment (kill -9, power cut). At the next start, before
the frame loop gives its first id or writes its first event:

    resume = Resume.from_log(output / "events.sqlite")
    memory = make_memory(rig, config, first_id=resume.person_ids(db))  # ids reserved first
    sink = SqliteSink(db, ..., first_id=resume.next_id)
    for s in event_sinks: s.write_events(resume.closing_events(t0, frame0))

- `next_id`: one above every id any earlier run may have given: the log's `persons`
  high-water mark (site.person_ids reserves blocks of ids on it, each committed before the
  tracker gives an id of it), the highest id SqliteSink reserved (`id_reservations`) and the
  highest person of its events, whichever is largest; so an id never names two people,
  whatever retention deleted (it never lowers a mark) and whenever a run was killed.
- `open_zones`: who was inside which zone at the last committed event: per (zone, person) the
  latest enter or exit is an enter; the events a killed run left waiting beside the log
  (io.sinks.spill: not stored yet, but sent by MQTT and the webhook) count after the log's.
  Retention never deletes such an enter while it is open (site.storage). Their
  `closing_events` are exits marked `restart`, written first through every event sink, so
  that occupancy (SQLite, MQTT's retained zone states, the webhook's receiver) is closed
  rather than left open for ever.
- `alarms`: the behaviour alarms left open (per rule and person, the latest behaviour event is
  an alarm: person_down, lone_worker, ...). Their `closing_events` end them (`person_up`,
  `<type>_end`) marked `restart`, after the zone exits: whoever was down when the service died
  is not known to be down still, and the new run raises the alarm again if they are.
"""

from __future__ import annotations

import logging
import sqlite3
from dataclasses import dataclass, replace
from pathlib import Path
from urllib.request import pathname2url

from stereopose.errors import StereoposeError
from stereopose.io.sinks.eventdb import read_mark, reading
from stereopose.io.sinks.incidents import on_clock, open_incidents
from stereopose.io.sinks.spill import read_spill, read_spilled_incidents
from stereopose.site.person_ids import PersonIds
from stereopose.types import Event

__all__ = ["Occupancy", "OpenAlarm", "Resume", "open_rows"]

# how each behaviour alarm ends (stereopose.behaviour.rules)
ALARM_ENDS = {
    "person_down": "person_up",
    "lone_worker": "lone_worker_end",
    "work_position": "work_position_end",
    "immobile": "immobile_end",
    "overreach": "overreach_end",
}

logger = logging.getLogger(__name__)

# per (zone, person), its latest enter or exit (by row id: the order events were stored)
_LAST_ZONE_SQL = """
SELECT MAX(id) AS id FROM events WHERE type IN ('enter', 'exit') GROUP BY zone, person
"""
_OPEN_SQL = f"""
SELECT e.zone, e.kind, e.person, e.t, e.run, e.x, e.y, e.allowed
FROM events AS e JOIN ({_LAST_ZONE_SQL}) AS last ON last.id = e.id
WHERE e.type = 'enter'
ORDER BY e.id
"""

# per (rule, person), its latest behaviour event, where that is an alarm (not its end)
_LAST_ALARM_SQL = """
SELECT MAX(id) AS id FROM events WHERE kind = 'behaviour' AND rule IS NOT NULL
GROUP BY rule, person
"""
_ALARM_TYPES_SQL = ", ".join(f"'{t}'" for t in ALARM_ENDS)
_OPEN_ALARMS_SQL = f"""
SELECT e.rule, e.type, e.person, e.zone, e.t, e.run, e.x, e.y
FROM events AS e JOIN ({_LAST_ALARM_SQL}) AS last ON last.id = e.id
WHERE e.type IN ({_ALARM_TYPES_SQL})
ORDER BY e.id
"""


def open_rows(db: sqlite3.Connection) -> set[int]:
    """The ids of the events that hold state open: each enter still the latest of its (zone,
    person), each behaviour alarm still the latest of its (rule, person). Retention keeps them
    (site.storage): deleted, the state they open could never be closed at a restart."""
    found = {
        int(i)
        for (i,) in db.execute(
            f"SELECT e.id FROM events AS e JOIN ({_LAST_ZONE_SQL}) AS last ON last.id = e.id "
            "WHERE e.type = 'enter'"
        )
    }
    if "rule" in {r[1] for r in db.execute("PRAGMA table_info(events)")}:
        found |= {
            int(i)
            for (i,) in db.execute(
                f"SELECT e.id FROM events AS e JOIN ({_LAST_ALARM_SQL}) AS last ON last.id = e.id "
                f"WHERE e.type IN ({_ALARM_TYPES_SQL})"
            )
        }
    return found


@dataclass(frozen=True)
class OpenAlarm:
    """A behaviour alarm not ended at the last committed event of the log."""

    rule: str
    type: str
    person: int
    zone: str
    t: float
    run: int
    position: tuple[float, float] | None = None


@dataclass(frozen=True)
class Occupancy:
    """A person inside a zone at the last committed event of the log.

    enter_t: the enter event's t (on the clock of its run); position: its floor point (x, y)."""

    zone: str
    kind: str
    person: int
    enter_t: float
    run: int
    position: tuple[float, float] | None = None
    allowed: bool = False


@dataclass(frozen=True)
class Resume:
    """The state a service starts from (see the module's docstring).

    next_id: the first id to give; occupied: zone occupancy left open, in the order the enters
    were stored; runs: the runs in the log; crashed: the last run did not close cleanly (killed,
    or still running in another process)."""

    next_id: int = 1
    occupied: tuple[Occupancy, ...] = ()
    alarms: tuple[OpenAlarm, ...] = ()
    runs: int = 0
    crashed: bool = False
    # the incidents not closed, (record, the wall_start of its times): io.sinks.incidents
    incidents: tuple = ()

    @property
    def open_zones(self) -> dict[str, tuple[int, ...]]:
        """zone -> the ids inside it when the last run stopped."""
        out: dict[str, list[int]] = {}
        for o in self.occupied:
            out.setdefault(o.zone, []).append(o.person)
        return {z: tuple(ids) for z, ids in out.items()}

    @classmethod
    def from_log(cls, db_path: str | Path) -> Resume:
        """The state left by the event log at db_path (a fresh start when there is none).

        Reads only (the log is not changed). A file that is not a readable event log is a
        StereoposeError naming it: a service must not start over ids it cannot see."""
        path = Path(db_path)
        if not path.exists():
            return cls()

        def read() -> Resume:
            db = sqlite3.connect(
                f"file:{pathname2url(str(path.resolve()))}?mode=ro", uri=True, timeout=5.0
            )
            try:
                db.execute("BEGIN")  # one snapshot: the ids and the open state agree
                return cls._read(db)
            finally:
                db.close()

        try:
            return (
                reading(read)
                .with_waiting(read_spill(path))
                .with_incidents(read_spilled_incidents(path))
            )
        except sqlite3.DatabaseError as e:
            raise StereoposeError(
                f"{path}: cannot resume from the event log: {e}; move it away to start afresh"
            ) from None

    @classmethod
    def _read(cls, db: sqlite3.Connection) -> Resume:
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if not tables:  # made by a run killed before its tables were committed: nothing in it
            return cls()
        if "events" not in tables or "runs" not in tables:
            raise sqlite3.DatabaseError("no events or runs table (not an event log)")
        top = db.execute("SELECT MAX(person) FROM events").fetchone()[0]
        next_id = max(1, int(top) + 1 if top is not None else 1)
        if "id_reservations" in tables:
            upto = db.execute("SELECT MAX(upto) FROM id_reservations").fetchone()[0]
            if upto is not None:
                next_id = max(next_id, int(upto))
        mark = read_mark(db, "persons")  # ids reserved ahead (site.person_ids)
        if mark is not None:
            next_id = max(next_id, mark)
        occupied = tuple(
            Occupancy(
                zone=zone,
                kind=kind,
                person=int(person),
                enter_t=float(t),
                run=int(run),
                position=(float(x), float(y)) if x is not None and y is not None else None,
                allowed=bool(allowed),
            )
            for zone, kind, person, t, run, x, y, allowed in db.execute(_OPEN_SQL)
        )
        alarms: tuple[OpenAlarm, ...] = ()
        if "rule" in {r[1] for r in db.execute("PRAGMA table_info(events)")}:
            alarms = tuple(
                OpenAlarm(
                    rule=str(rule),
                    type=str(type_),
                    person=int(person),
                    zone=str(zone or ""),
                    t=float(t),
                    run=int(run),
                    position=(float(x), float(y)) if x is not None and y is not None else None,
                )
                for rule, type_, person, zone, t, run, x, y in db.execute(_OPEN_ALARMS_SQL)
            )
        runs = int(db.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
        crashed = False
        cols = {r[1] for r in db.execute("PRAGMA table_info(runs)")}
        if runs and "ended" in cols:
            crashed = (
                db.execute("SELECT ended FROM runs ORDER BY id DESC LIMIT 1").fetchone()[0] is None
            )
        return cls(
            next_id=next_id,
            occupied=occupied,
            alarms=alarms,
            runs=runs,
            crashed=crashed,
            incidents=tuple(open_incidents(db)),
        )

    def with_waiting(self, waiting: list[tuple[int, Event]]) -> Resume:
        """This state with the events a run left waiting beside the log (io.sinks.spill: not
        stored when it died, but sent by the other sinks) applied after the log's, in order."""
        if not waiting:
            return self
        zones = {(o.zone, o.person): o for o in self.occupied}
        alarms = {(a.rule, a.person): a for a in self.alarms}
        next_id = self.next_id
        for run, e in waiting:
            next_id = max(next_id, e.person + 1)
            if e.type == "enter":
                zones[(e.zone, e.person)] = Occupancy(
                    e.zone, e.kind, e.person, e.t, run, e.position, e.allowed
                )
            elif e.type == "exit":
                zones.pop((e.zone, e.person), None)
            elif e.kind == "behaviour" and e.rule is not None:
                if e.type in ALARM_ENDS:
                    alarms[(e.rule, e.person)] = OpenAlarm(
                        e.rule, e.type, e.person, e.zone, e.t, run, e.position
                    )
                else:
                    alarms.pop((e.rule, e.person), None)
        return replace(
            self, next_id=next_id, occupied=tuple(zones.values()), alarms=tuple(alarms.values())
        )

    def with_incidents(self, spilled: dict) -> Resume:
        """This state with the incident records a run left waiting beside the log (id ->
        (record, wall_start)): each replaces the log's row of its incident; closed ones go."""
        if not spilled:
            return self
        held = {rec.id: (rec, wall) for rec, wall in self.incidents}
        held.update(spilled)
        kept = tuple(held[i] for i in sorted(held) if held[i][0].state != "closed")
        return replace(self, incidents=kept)

    def open_incidents(self, wall_start: float | None) -> list:
        """The incidents the last run left open, their times on the clock starting at
        wall_start (the new run's): for IncidentBook.restore. The closing events of the first
        step then clear those whose hazard is gone."""
        return [on_clock(rec, wall, wall_start) for rec, wall in self.incidents]

    def person_ids(self, db_path: str | Path, block: int = 1000) -> PersonIds:
        """Where the new run's tracker takes its ids: from next_id on, each reserved in the
        log at db_path before it is given (site.person_ids)."""
        return PersonIds(db_path, self.next_id, block=block)

    def closing_events(self, t: float, frame: int) -> list[Event]:
        """An exit marked `restart` for each open occupancy, at time t and frame of the new run
        (its onset is t too: when the person left is not known; duration_s unknown, None)."""
        return [
            Event(
                t=t,
                frame=frame,
                person=o.person,
                zone=o.zone,
                kind=o.kind,
                type="exit",
                onset_t=t,
                position=o.position,
                allowed=o.allowed,
                restart=True,
            )
            for o in self.occupied
        ] + [
            Event(
                t=t,
                frame=frame,
                person=a.person,
                zone=a.zone,
                kind="behaviour",
                type=ALARM_ENDS[a.type],
                onset_t=t,
                position=a.position,
                restart=True,
                rule=a.rule,
            )
            for a in self.alarms
        ]
