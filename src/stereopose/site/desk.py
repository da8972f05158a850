"""The incident desk: how the HTTP API (and any other reader of the operators' acts) reaches the
incident book, given to the app when it is created.

The app is created before the cameras open (its health answers during the start-up), the
incident book when the frame loop opens its sinks: the desk is made first and handed to the
app; the frame loop's incident step (pipeline.incidents.IncidentStep) is attached to it once
it runs. Until then `step` is None, and the API answers 503 "the incident book is not running
yet".
"""

from __future__ import annotations

from stereopose.pipeline.incidents import IncidentStep

__all__ = ["IncidentDesk"]


class IncidentDesk:
    """See the module."""

    def __init__(self) -> None:
        self.step: IncidentStep | None = None  # once the book runs

    def attach(self, step: IncidentStep) -> None:
        """The running incident step: its acknowledge, shelve, unshelve and figures."""
        self.step = step
