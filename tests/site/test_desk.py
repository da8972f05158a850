"""The incident desk: the parts made before the frame loop runs its incident book (the IEC 104
outstation's commands, the outbox's acknowledgements from a control room) are given the desk's
acknowledge when they are made; it refuses, as not running, until the book's step is
attached, then acknowledges in the book."""

from __future__ import annotations

import pytest

from stereopose.alarms import IncidentBook
from stereopose.alarms.book import UnknownIncidentError
from stereopose.pipeline.incidents import IncidentStep
from stereopose.pipeline.step_rules import step_chain
from stereopose.site.desk import BookNotRunningError, IncidentDesk
from stereopose.types import Event, People3D


class _Script:
    """The step's events, given in turn (the role the service's events play in serve)."""

    def __init__(self) -> None:
        self.next: list[Event] = []

    def update(self, people3d: People3D) -> list[Event]:
        out, self.next = self.next, []
        return out


def test_the_desk_refuses_until_the_book_runs_then_acknowledges_in_it() -> None:
    desk = IncidentDesk()
    with pytest.raises(BookNotRunningError, match="not running yet"):
        desk.acknowledge(1, "iec104 master 3")
    script = _Script()
    step = IncidentStep(IncidentBook(), step_chain(script), clock=lambda: 1.0)
    script.next = [
        Event(t=1.0, frame=1, person=7, zone="busbar", kind="energized", type="enter", onset_t=1.0)
    ]
    out, _ = step.step(1.0, 1, People3D.empty(1, 2))
    incident = out[0].incident
    assert incident is not None
    desk.attach(step)
    record = desk.acknowledge(incident, "iec104 master 3")
    assert record.acked_by == "iec104 master 3"
    assert step.book.get(incident).acked_by == "iec104 master 3"
    with pytest.raises(UnknownIncidentError):
        desk.acknowledge(incident + 100, "iec104 master 3")
