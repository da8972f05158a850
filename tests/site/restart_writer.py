"""A stand-in for serve's frame loop over a real event log, to be killed at any moment.

    python restart_writer.py EVENTS.sqlite SEED

Resumes from the log (Resume.from_log), writes the restart exits first, then frames for ever:
people appear (some enter a zone and leave it later, some only walk by) with ids taken as
serve's tracker takes them (Resume.person_ids: each reserved in the log first; a new person
waits while none is reserved). Reports on stdout, flushed, in this order: `next N`; `given ID`
before a frame holding that id is written anywhere (as a pose segment would hold it before
the event log commits); `sent TYPE ZONE PERSON` for each event once the sink has taken it
(committed, or waiting for a locked log: MQTT would have sent it by then); `event TYPE ZONE
PERSON FRAME RESTART` for each event once its write has committed; `waiting` once when a new
person first waits for an id.
"""

from __future__ import annotations

import sys

import numpy as np

from stereopose.io.sinks.base import FrameResult
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.site.restart import Resume
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import Event, People3D

ID_BLOCK = 8  # small, so that the reservation is extended many times before the kill


def people(frame: int, ids: list[int]) -> People3D:
    P = len(ids)
    return People3D(
        frame,
        np.zeros((P, NUM_JOINTS, 3)),
        np.ones((P, NUM_JOINTS)),
        np.array(ids, dtype=np.int64),
        np.zeros((P, NUM_JOINTS)),
        np.full((P, NUM_JOINTS), 2),
        np.zeros((P, 1), dtype=np.int64),
    )


def say(*words: object) -> None:
    sys.stdout.write(" ".join(map(str, words)) + "\n")
    sys.stdout.flush()


def sent(events: list[Event]) -> None:
    for e in events:
        say("sent", e.type, e.zone, e.person)


def report(events: list[Event]) -> None:
    for e in events:
        say("event", e.type, e.zone, e.person, e.frame, int(e.restart))


def main(db: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    resume = Resume.from_log(db)
    say("next", resume.next_id)
    sink = SqliteSink(db, site="test", source="writer", first_id=resume.next_id, id_block=ID_BLOCK)
    closing = resume.closing_events(0.0, 0)
    sink.write_events(closing)
    assert not sink.pending
    sent(closing)
    report(closing)
    source = resume.person_ids(db, block=ID_BLOCK)
    waited = False
    inside: dict[int, tuple[str, int]] = {}  # id -> (zone, frames left inside)
    passing: dict[int, int] = {}  # ids seen without a zone event -> frames left
    frame = 0
    while True:
        frame += 1
        t = frame / 25
        events = []
        for pid, (zone, left) in list(inside.items()):
            if left == 0:
                del inside[pid]
                events.append(Event(t, frame, pid, zone, "restricted", "exit", t))
            else:
                inside[pid] = (zone, left - 1)
        for pid, left in list(passing.items()):
            passing[pid] = left - 1
            if left == 0:
                del passing[pid]
        for _ in range(int(rng.integers(0, 3))):  # at most 2 new ids a frame
            pid = source.take()
            if pid is None:  # none reserved (the log locked): this person waits
                if not waited:
                    say("waiting")
                    waited = True
                break
            say("given", pid)
            if rng.random() < 0.6:
                zone = f"z{int(rng.integers(3))}"
                inside[pid] = (zone, int(rng.integers(1, 40)))
                events.append(Event(t, frame, pid, zone, "restricted", "enter", t))
            else:
                passing[pid] = int(rng.integers(1, 20))
        ids = sorted([*inside, *passing])
        sink.write(FrameResult(frame, t, {}, people(frame, ids), events))
        sent(events)
        if not sink.pending:
            report(events)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))
