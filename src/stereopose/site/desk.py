"""The incident desk: how the HTTP API (and any other reader of the operators' acts) reaches the
incident book, given to the app when it is created.

The app is created before the cameras open (its health answers during the start-up), the
incident book when the frame loop opens its sinks: the desk is made first and handed to the
app; the frame loop's incident step (pipeline.incidents.IncidentStep) is attached to it once
it runs. Until then `step` is None, and the API answers 503 "the incident book is not running
yet". The parts made before it that act on the book or read it (the IEC 104 outstation's
commands, the outbox's acknowledgements from a control room, the OPC UA server) are given the
desk when they are made, never the step later: until it runs, the desk says so (`running`,
BookNotRunningError).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from contextlib import AbstractContextManager

from stereopose.alarms import IncidentBook, IncidentRecord
from stereopose.errors import StereoposeError
from stereopose.pipeline.incidents import IncidentStep
from stereopose.site.handover import Handover

__all__ = ["BookNotRunningError", "IncidentDesk", "remote_ack"]

logger = logging.getLogger(__name__)


class BookNotRunningError(StereoposeError):
    """An act on the incident book before the frame loop runs it."""


class IncidentDesk(Handover[IncidentStep]):
    """See the module: the running incident step attached (site.handover), its acknowledge,
    shelve, unshelve and figures."""

    @property
    def step(self) -> IncidentStep | None:
        """The running incident step (None: not yet)."""
        return self.current

    @property
    def running(self) -> bool:
        """Whether the frame loop runs the book (its step attached)."""
        return self.step is not None

    def _running_step(self) -> IncidentStep:
        step = self.step
        if step is None:
            raise BookNotRunningError("the incident book is not running yet")
        return step

    @property
    def lock(self) -> AbstractContextManager:
        """The running step's lock, held while its book is read (BookNotRunningError before)."""
        return self._running_step().lock

    @property
    def book(self) -> IncidentBook:
        """The running step's book (BookNotRunningError before)."""
        return self._running_step().book

    @property
    def wall_start(self) -> float | None:
        """The Unix time of the running step's t = 0 (BookNotRunningError before)."""
        return self._running_step().wall_start

    def acknowledge(self, incident_id: int, by: str) -> IncidentRecord:
        """The running book's acknowledge (any thread), for the parts built before it runs
        (the IEC 104 outstation's and the control room's commands); BookNotRunningError
        before it runs, an IncidentError as the book's own."""
        return self._running_step().acknowledge(incident_id, by)


def remote_ack(
    acknowledge: Callable[[int, str], IncidentRecord] | None, incident: int, by: str
) -> str:
    """A control room's acknowledgement of `incident` by `by` acted on (site.outbox, paho's
    thread): its answer (site.wire): "acknowledged", "already" (someone else's first),
    "unknown" (no such open incident), "unavailable" (no book, not yet running, or failing:
    logged, never raised)."""
    if acknowledge is None:
        return "unavailable"
    try:
        return "acknowledged" if acknowledge(incident, by).acked_by == by else "already"
    except BookNotRunningError:  # the frame loop not yet running it
        return "unavailable"
    except StereoposeError:  # no such open incident (never raised, or forgotten)
        return "unknown"
    except Exception:  # the book failing must not end the caller's thread
        logger.exception("acknowledging incident %d for a control room failed", incident)
        return "unavailable"
