"""How an alarm output says whether alarms get through: `health() -> OutputHealth`.

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

from typing import NamedTuple, Protocol, runtime_checkable


class OutputHealth(NamedTuple):
    """ok: delivering now; waiting: held, not delivered yet; reason: why not ok (None: ok)."""

    ok: bool
    waiting: int
    reason: str | None = None


@runtime_checkable
class ReportsHealth(Protocol):
    """An output with a health() (see the module)."""

    def health(self) -> tuple[bool, int, str | None]: ...
