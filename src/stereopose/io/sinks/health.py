"""The alarm outputs' one interface (`AlarmOutput`), and how one says whether alarms get
through: `health() -> OutputHealth`.

An alarm output (the event log, the webhook, MQTT, the IEC 104 outstation, the OPC UA server)
is a sink of the frame loop that also takes the incident book's changes. The site service
registers every one in one loop: its events and incident changes, its health, its queue (what
it holds, what it dropped) and its figures in `status.json` under its `output_name`.

- `output_name`: its short name in the health answer, /metrics and `status.json`
  (events_db, webhook, mqtt, iec104, opcua); `label`: what a log line or `failed_outputs`
  calls it (never a credential);
- `write(frame)`: a step's events (and people, where it shows them); `write_changes(changes)`:
  the incident book's changes (alarms.Change) of the step, or of an operator's act;
- `health()`: below; `queued()`: what it holds not delivered yet; `dropped`: how many it has
  dropped so far; `figures()`: its own counts for `status.json`;
- `close()`: what it holds delivered within its own bound (a sink's close).

Every output that carries alarms off the machine or into the record (MQTT, the webhook, the
event log; SCADA links later) has a `health()` method returning (ok, waiting, reason): ok
False while it cannot deliver (the broker unreachable, the receiver failing, the log not
writable), waiting the alarms and messages it holds that are not delivered yet, reason a
short text for the health answer (None when ok). The service's health state collects them
(site.health.state.ServiceState.register_output), so a new output reports by having the method.

`health()` is called at each health or metrics read: it must be quick, must not block and
must not raise. The reason is shown to anonymous clients: no path, host name or credential.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple, Protocol, runtime_checkable

from stereopose.alarms import Change
from stereopose.io.sinks.base import FrameResult


class OutputHealth(NamedTuple):
    """ok: delivering now; waiting: held, not delivered yet; reason: why not ok (None: ok)."""

    ok: bool
    waiting: int
    reason: str | None = None


@runtime_checkable
class ReportsHealth(Protocol):
    """An output with a health() (see the module)."""

    def health(self) -> tuple[bool, int, str | None]: ...


@runtime_checkable
class AlarmOutput(Protocol):
    """One alarm output (see the module)."""

    output_name: str

    @property
    def stage(self) -> str: ...

    @property
    def label(self) -> str: ...

    def write(self, frame: FrameResult) -> None: ...

    def write_changes(self, changes: Sequence[Change]) -> None: ...

    def health(self) -> tuple[bool, int, str | None]: ...

    def queued(self) -> int: ...

    @property
    def dropped(self) -> int: ...

    def figures(self) -> dict: ...

    def close(self) -> list[Path]: ...
