"""The running service's warnings on site: its speakers and signals opened from the site's
`[warnings]`, the messages rendered, and all of it built again at each new site.

    onsite = OnSite(site, safe=..., publish=mqtt.set_warnings)   # at start: rendered now
    events = onsite.step(t, frame, people, fences)               # each step (never waits)
    onsite.set_site(new_site)        # a new site: rendered on a thread, then swapped in
    onsite.controls.silence("bay1_pa", 600, "amplifier serviced", by="alice")   # an admin's
    onsite.test("bay1_tower", by="alice")      # a test at the next step (onsite.control)
    onsite.outputs()                 # each speaker and signal: health, silence, what it says
    onsite.close()                   # every speaker quiet, every coil off

At a new site the speakers and signals whose settings are unchanged are kept as they are (a
page in progress goes on, a coil stays set); the others are closed and opened anew. Until the
new site's messages are rendered (a fraction of a second) the old site's warner goes on
warning, so that no step waits for speech.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Collection, Sequence
from typing import Protocol

from stereopose.onsite.control import ControlError, Controls
from stereopose.onsite.modbus import Signal
from stereopose.onsite.phrases import Phrasebook
from stereopose.onsite.rtp import Speaker
from stereopose.onsite.settings import WarningSettings
from stereopose.onsite.speaker_health import SpeakerChecks
from stereopose.onsite.speech import Speech
from stereopose.onsite.warner import Occupancy, Warner
from stereopose.types import Event, People3D
from stereopose.zones import Zone

__all__ = ["OnSite"]

logger = logging.getLogger(__name__)


class WarnedSite(Protocol):
    """What warnings on site read of a site (a fence.Site)."""

    @property
    def zones(self) -> Sequence[Zone]: ...

    @property
    def warnings(self) -> WarningSettings | None: ...


class OnSite:
    """See the module. site: a fence.Site (its zones and `warnings`, None: nothing on site);
    safe(): the zones safe now; publish(doc): the warnings now (MQTT's `warnings`)."""

    def __init__(
        self,
        site: WarnedSite | None,
        safe: Callable[[], Collection[str]] = lambda: (),
        publish: Callable[[dict], None] | None = None,
        speech: Speech | None = None,
    ) -> None:
        self.safe, self.publish = safe, publish
        self.speech = speech or Speech()
        self._lock = threading.Lock()
        self.warner: Warner | None = None
        self._speakers: dict[str, Speaker] = {}
        self._signals: dict[str, Signal] = {}
        self._building = threading.Lock()  # held by the site build in progress
        self._generation = 0  # the newest site asked for
        self._closed = False
        self.controls = Controls(self._names)  # an admin's silences and tests
        self.checks = SpeakerChecks(self._speaker_health)  # speakers with a health_url
        self.warner = self._build(site)  # at start: a bad template or recording fails here

    def _names(self) -> set[str]:
        return set(self._speakers) | set(self._signals)

    def _speaker_health(self, name: str, up: bool, why: str) -> None:
        warner = self.warner
        if warner is not None:
            warner.on_health(name, up, why)

    def _build(self, site: WarnedSite | None) -> Warner | None:
        """The warner of `site`: its phrasebook rendered, its speakers and signals (the
        unchanged ones kept)."""
        settings = site.warnings if site is not None else None
        if site is None or settings is None:
            self._swap_outputs({}, {})
            self.checks.watch(())
            return None
        book = Phrasebook(settings, site.zones, self.speech)
        speakers = {}
        for spec in settings.speakers:
            kept = self._speakers.get(spec.name)
            same = kept is not None and kept.spec == spec and kept.repeat_s == settings.repeat_s
            speakers[spec.name] = kept if same else Speaker(spec, settings.repeat_s)
        holder: list[Warner] = []  # the warner below, once made: the signals' health to it

        def health(name: str, up: bool, why: str) -> None:
            if holder:
                holder[0].on_health(name, up, why)

        signals = {}
        for spec in settings.signals:
            kept = self._signals.get(spec.name)
            if kept is not None and kept.spec == spec:
                kept.on_health = health  # kept: its health now told to the new warner
                signals[spec.name] = kept
            else:
                signals[spec.name] = Signal(spec, on_health=health)
        warner = Warner(site.zones, settings, book, speakers, signals, self.safe, self.publish)
        holder.append(warner)
        self._swap_outputs(speakers, signals)
        self.checks.watch(settings.speakers)
        return warner

    def _swap_outputs(self, speakers: dict[str, Speaker], signals: dict[str, Signal]) -> None:
        """The outputs of the new warner in place; those no longer used closed."""
        for name, s in self._speakers.items():
            if speakers.get(name) is not s:
                s.close()
        for name, g in self._signals.items():
            if signals.get(name) is not g:
                g.close()
        self._speakers, self._signals = speakers, signals

    def set_site(self, site: WarnedSite | None) -> None:
        """A new site (the frame loop's thread, never waiting): built on a thread of its own,
        one build at a time, and taken unless a newer site came meanwhile."""
        with self._lock:
            self._generation += 1
            generation = self._generation

        def build() -> None:
            with self._building:  # one at a time: the outputs are swapped by each
                with self._lock:
                    if self._closed or generation != self._generation:
                        return  # a newer site's build follows
                try:
                    warner = self._build(site)
                except Exception:
                    logger.exception("warnings on site: the new site's could not be built")
                    return
                with self._lock:
                    if self._closed:
                        return
                    self.warner = warner
            logger.info(
                "warnings on site: %s",
                "none"
                if warner is None
                else f"{len(warner.speakers)} speaker(s), {len(warner.signals)} signal(s)",
            )

        threading.Thread(target=build, name="onsite site", daemon=True).start()

    def step(
        self,
        t: float,
        frame: int,
        people: People3D,
        fences: Occupancy | None,
        events: Sequence[Event] = (),
    ) -> list[Event]:
        """The step's warnings and calls (its earlier `events`) to the outputs, the silenced
        ones left quiet; the outputs' health events and the admin's acts (onsite.control)."""
        warner = self.warner
        silenced = self.controls.silenced()
        tests = self.controls.take_tests()
        acts = self.controls.take(t, frame)
        if warner is None or fences is None:
            return acts
        try:
            for output, _by in tests:
                warner.test(output, t)
            return acts + warner.step(t, frame, people, fences, events, silenced)
        except Exception:  # an output's fault never ends the service's steps
            logger.exception("warnings on site: a step failed")
            return acts

    def test(self, output: str, by: str) -> None:
        """`output` tested at the next step (onsite.control); ControlError 409 while it warns
        or is silenced, 404 when there is no such output."""
        warner = self.warner
        if output in self.controls.silenced():
            raise ControlError(f"{output!r} is silenced: lift the silence to test it", 409)
        if warner is not None and warner.sounding(output):
            raise ControlError(f"{output!r} is warning now: not tested", 409)
        self.controls.test(output, by)

    def outputs(self) -> list[dict]:
        """Each speaker and signal: its kind, zones, health ("up", "down", "unknown", "not
        verifiable"), its silence (None) and what it gives now."""
        silenced = self.controls.silenced()
        now = self.now()
        out = []
        for name, sp in self._speakers.items():
            out.append(
                {
                    "name": name,
                    "type": "speaker",
                    "url": sp.spec.url,
                    "zones": list(sp.spec.zones),
                    "position": list(sp.spec.position) if sp.spec.position else None,
                    "health": self.checks.state(name),
                    "silenced": silenced[name].as_dict() if name in silenced else None,
                    "sounding": _giving(now, name, "speakers"),
                }
            )
        for name, g in self._signals.items():
            out.append(
                {
                    "name": name,
                    "type": "signal",
                    "url": f"modbus://{g.spec.host}:{g.spec.port}/{g.spec.unit}",
                    "zones": list(g.spec.zones),
                    "position": list(g.spec.position) if g.spec.position else None,
                    "health": "unknown" if g.up is None else "up" if g.up else "down",
                    "silenced": silenced[name].as_dict() if name in silenced else None,
                    "sounding": _giving(now, name, "signals"),
                }
            )
        return out

    def figures(self) -> dict:
        """What the outputs did (status.json's `warnings_on_site`): each speaker's packets,
        messages, cut-ins and failed sends, each signal's writes, failures and outages, the
        hazards and messages, and what was dropped (calls when too many were open, acts no
        step took in time)."""
        warner = self.warner
        return {
            "speakers": {n: dict(s.figures) for n, s in self._speakers.items()},
            "signals": {n: dict(g.figures) for n, g in self._signals.items()},
            "warner": dict(warner.figures) if warner is not None else {},
            "calls_dropped": warner.calls.dropped if warner is not None else 0,
            "acts_dropped": self.controls.dropped,
        }

    def now(self) -> dict:
        warner = self.warner
        doc = {"warnings": [], "calls": []} if warner is None else warner.now()
        doc["silenced"] = [s.as_dict() for s in self.controls.silenced().values()]
        return doc

    def close(self) -> None:
        with self._lock:
            self._closed = True
        with self._building:  # a build in progress ends first
            self._swap_outputs({}, {})
        self.checks.close()
        self.warner = None


def _giving(now: dict, name: str, where: str) -> list[dict]:
    """What output `name` gives now: the hazards and calls of `now` naming it in `where`."""
    return [
        {k: v for k, v in item.items() if k not in ("speakers", "signals")}
        for item in (*now.get("warnings", ()), *now.get("calls", ()))
        if name in item.get(where, ())
    ]
