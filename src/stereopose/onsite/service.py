"""The running service's warnings on site: its speakers and signals opened from the site's
`[warnings]`, the messages rendered, and all of it built again at each new site.

    onsite = OnSite(site, safe=..., publish=mqtt.set_warnings)   # at start: rendered now
    events = onsite.step(t, frame, people, fences)               # each step (never waits)
    onsite.set_site(new_site)        # a new site: rendered on a thread, then swapped in
    onsite.close()                   # every speaker quiet, every coil off

At a new site the speakers and signals whose settings are unchanged are kept as they are (a
page in progress goes on, a coil stays set); the others are closed and opened anew. Until the
new site's messages are rendered (a fraction of a second) the old site's warner goes on
warning, so that no step waits for speech.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Collection

from stereopose.onsite.modbus import Signal
from stereopose.onsite.phrases import Phrasebook
from stereopose.onsite.rtp import Speaker
from stereopose.onsite.speech import Speech
from stereopose.onsite.warner import Occupancy, Warner
from stereopose.types import Event, People3D

__all__ = ["OnSite"]

logger = logging.getLogger(__name__)


class OnSite:
    """See the module. site: a fence.Site (its zones and `warnings`, None: nothing on site);
    safe(): the zones safe now; publish(doc): the warnings now (MQTT's `warnings`)."""

    def __init__(
        self,
        site,
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
        self.warner = self._build(site)  # at start: a bad template or recording fails here

    def _build(self, site) -> Warner | None:
        """The warner of `site`: its phrasebook rendered, its speakers and signals (the
        unchanged ones kept)."""
        settings = getattr(site, "warnings", None) if site is not None else None
        if settings is None:
            self._swap_outputs({}, {})
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

    def set_site(self, site) -> None:
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

    def step(self, t: float, frame: int, people: People3D, fences: Occupancy | None) -> list[Event]:
        """The step's warnings to the outputs; the outputs' health events."""
        warner = self.warner
        if warner is None or fences is None:
            return []
        try:
            return warner.step(t, frame, people, fences)
        except Exception:  # an output's fault never ends the service's steps
            logger.exception("warnings on site: a step failed")
            return []

    def now(self) -> dict:
        warner = self.warner
        return {"warnings": []} if warner is None else warner.now()

    def close(self) -> None:
        with self._lock:
            self._closed = True
        with self._building:  # a build in progress ends first
            self._swap_outputs({}, {})
        self.warner = None
