"""An admin's hand on the outputs on site (the console, the API): a speaker or a signal
silenced for a set time with a reason, silenced no more, or tested.

    controls = Controls(names=lambda: {"bay1_pa", "bay1_tower"})
    controls.silence("bay1_pa", 600, "maintenance of the PA amplifier", by="alice")
    controls.test("bay1_tower", by="alice")         # the beacon pulsed at the next step
    silenced = controls.silenced()                  # each step: expired silences ended
    events = controls.take()                        # each step: what was done, as events

The operator's acknowledgement of an alarm never silences the site (the hazard is physical);
only this does, and only for a time: a silence ends by itself at `until`, or when an admin
lifts it. Each act is an event of kind "service" at the next step (`take`):
warning_output_silenced (an incident until its end), warning_output_unsilenced and
warning_output_test, the output's name in `source` and who, why and until when in `result`.
Silences outlive a new site (an output of the same name stays silenced) but not a restart:
a service that starts again warns everywhere.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass

from stereopose.errors import StereoposeError
from stereopose.types import Event

__all__ = ["MAX_SILENCE_S", "ControlError", "Controls", "Silence", "output_event"]

MAX_SILENCE_S = 24 * 3600.0  # a silence lasts at most a day
MAX_REASON = 500  # characters
MAX_PENDING = 256  # acts waiting for the next step, at most (the oldest dropped)
SERVICE_KIND = "service"


class ControlError(StereoposeError):
    """An act that cannot be done: `status` is its HTTP answer (404 no such output, 409 the
    output is warning now, 400 a bad time or reason)."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class Silence:
    """An output silenced until `until` (Unix time) by `by`, for `reason`."""

    output: str
    until: float
    reason: str
    by: str
    since: float

    def as_dict(self) -> dict:
        return {
            "output": self.output,
            "until": round(self.until, 3),
            "since": round(self.since, 3),
            "reason": self.reason,
            "by": self.by,
        }


class Controls:
    """See the module. names(): the outputs there are now (speakers and signals); clock: Unix
    time."""

    def __init__(
        self,
        names: Callable[[], Collection[str]] = lambda: (),
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.names, self.clock = names, clock
        self._lock = threading.Lock()
        self._silences: dict[str, Silence] = {}
        self._tests: deque[tuple[str, str]] = deque(maxlen=MAX_PENDING)
        self._acts: deque[tuple[str, str, dict]] = deque(maxlen=MAX_PENDING)
        self.dropped = 0  # acts no step took in time (the oldest went)

    def _known(self, output: str) -> None:
        if output not in set(self.names()):
            raise ControlError(f"no speaker or signal named {output!r} on this site", 404)

    def _act(self, type_: str, output: str, result: dict) -> None:
        if len(self._acts) == self._acts.maxlen:
            self.dropped += 1
        self._acts.append((type_, output, result))

    def silence(self, output: str, seconds: float, reason: str, by: str) -> Silence:
        """`output` silent for `seconds` (at most a day) from now; a silence of it already
        there is replaced."""
        self._known(output)
        if not 0 < seconds <= MAX_SILENCE_S:
            raise ControlError(f"a silence lasts more than 0 s and at most {MAX_SILENCE_S:g} s")
        reason = " ".join(str(reason).split())
        if not reason or len(reason) > MAX_REASON:
            raise ControlError(f"a silence needs a reason of 1 to {MAX_REASON} characters")
        now = self.clock()
        s = Silence(output, now + float(seconds), reason, by, now)
        with self._lock:
            self._silences[output] = s
            self._act("warning_output_silenced", output, s.as_dict())
        return s

    def lift(self, output: str, by: str) -> Silence:
        """The silence of `output` ended now (ControlError 404 when there is none)."""
        with self._lock:
            s = self._silences.pop(output, None)
            if s is None:
                raise ControlError(f"{output!r} is not silenced", 404)
            self._act("warning_output_unsilenced", output, {**s.as_dict(), "ended_by": by})
        return s

    def test(self, output: str, by: str) -> None:
        """`output` tested at the next step: a speaker says the test message, a signal pulses
        its coils."""
        self._known(output)
        with self._lock:
            if len(self._tests) == self._tests.maxlen:
                self.dropped += 1
            self._tests.append((output, by))
            self._act("warning_output_test", output, {"by": by})

    def silenced(self) -> dict[str, Silence]:
        """The silences now (those past their time ended, each an act)."""
        now = self.clock()
        with self._lock:
            for name, s in list(self._silences.items()):
                if s.until <= now:
                    del self._silences[name]
                    self._act("warning_output_unsilenced", name, {**s.as_dict(), "ended_by": ""})
            return dict(self._silences)

    def take_tests(self) -> list[tuple[str, str]]:
        with self._lock:
            out = list(self._tests)
            self._tests.clear()
        return out

    def take(self, t: float, frame: int) -> list[Event]:
        """The acts since the last step, as events at this one."""
        with self._lock:
            acts = list(self._acts)
            self._acts.clear()
        return [output_event(t, frame, type_, output, result) for type_, output, result in acts]


def output_event(
    t: float, frame: int, type_: str, output: str, result: dict | None = None
) -> Event:
    """An event of a warning output on site (kind "service", its name in `source`)."""
    return Event(
        t=t,
        frame=frame,
        person=-1,
        zone="",
        kind=SERVICE_KIND,
        type=type_,
        onset_t=t,
        source=output,
        result=result,
    )
