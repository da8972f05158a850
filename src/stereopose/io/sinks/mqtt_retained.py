"""What the MQTT sink's broker retains for late subscribers (io.sinks.mqtt): each zone's
occupancy and state (`zones/<zone>`), the running site (`site`) and what warns on site
(`warnings`). Only the latest of each is kept: sent once when it changes, and all of it again
on every connect (the broker may have lost it in a restart). Not thread-safe: the sink's lock
guards it.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from stereopose.io.sinks.mqtt_settings import topic_part
from stereopose.types import Event

__all__ = ["Message", "Retained", "dumps"]


@dataclass
class Message:
    kind: str
    topic: str
    payload: str
    qos: int
    retain: bool = False


def dumps(obj: object) -> str:
    return json.dumps(obj)  # as the events JSON lines write it


class Retained:
    """The retained states (see the module). topics: the sink's (`site`, `warnings`);
    zone_base: the zones' topic prefix; zone_names: the zones known at the start."""

    def __init__(
        self, topics: Mapping[str, str], zone_base: str, zone_names: Iterable[str]
    ) -> None:
        self.topics, self.zone_base = topics, zone_base
        self.zones: dict[str, tuple[set[int], float | None, int | None]] = {
            z: (set(), None, None) for z in zone_names
        }
        self.dirty: set[str] = set(self.zones)
        self.cleared: set[str] = set()  # removed zones whose retained state is to be cleared
        self.power: dict[str, tuple[str, str | None]] = {}  # zone -> its state, source
        self.off: set[str] = set()  # zones switched off
        self.site: str | None = None  # the `site` message's payload
        self.warnings: str | None = None  # the `warnings` message's payload
        self._send_site = self._send_warnings = False

    def set_site(self, version: str, zones: Sequence[str], t: float) -> None:
        """The running site: `site` with its version and zones; a new zone's state published
        empty, a removed one's cleared (an empty retained message)."""
        self.site = dumps({"version": version, "zones": list(zones), "t": round(float(t), 3)})
        for gone in [z for z in self.zones if z not in zones]:
            del self.zones[gone]
            self.dirty.discard(gone)
            self.cleared.add(gone)
        for z in zones:
            if z not in self.zones:
                self.zones[z] = (set(), None, None)
                self.dirty.add(z)
                self.cleared.discard(z)
        self._send_site = True

    def set_warnings(self, doc: dict) -> None:
        """What warns on site now: a newer one replaces one not sent yet."""
        self.warnings = dumps(doc)
        self._send_warnings = True

    def connected(self) -> None:
        """A new connection: everything sent again."""
        self._send_site = self.site is not None
        self._send_warnings = self.warnings is not None
        self.dirty.update(self.zones)

    def pending(self) -> int:
        return len(self.dirty) + len(self.cleared)

    def occupy(self, e: Event) -> None:
        """A zone's state after event `e`: who is inside, switched off or on, its power."""
        if not e.zone:  # a camera's event: no zone's occupancy changes
            return
        if e.type in ("zone_disabled", "zone_enabled"):  # switched off or on (mqtt_commands)
            (self.off.add if e.type == "zone_disabled" else self.off.discard)(e.zone)
            if e.zone in self.zones:
                self.dirty.add(e.zone)
            return
        if e.type in ("zone_live", "zone_dead", "zone_unknown"):  # its state from its breakers
            self.power[e.zone] = (e.type[5:], e.source)
            if e.zone in self.zones:
                self.dirty.add(e.zone)
            return
        inside, _, _ = self.zones.get(e.zone, (set(), None, None))
        if e.type == "enter":
            inside = inside | {e.person}
        elif e.type == "exit":
            inside = inside - {e.person}
        elif e.zone in self.zones:
            return
        self.zones[e.zone] = (inside, e.t, e.frame)
        self.dirty.add(e.zone)

    def next(self) -> Message | None:
        """The next retained message to send, or None."""
        if self._send_site and self.site is not None:
            self._send_site = False
            return Message("site", self.topics["site"], self.site, 1, retain=True)
        if self._send_warnings and self.warnings is not None:
            self._send_warnings = False
            return Message("warnings", self.topics["warnings"], self.warnings, 1, retain=True)
        if self.cleared:
            gone = self.zone_base + topic_part(self.cleared.pop())
            return Message("zones", gone, "", 1, retain=True)
        if self.dirty:
            return self._zone_message(self.dirty.pop())
        return None

    def _zone_message(self, zone: str) -> Message:
        inside, t, frame = self.zones[zone]
        people = sorted(inside)
        body = {"zone": zone, "people": people, "count": len(people), "t": t, "frame": frame}
        if zone in self.power:  # a zone with a state source: live, dead or unknown, and why
            body["power"], body["power_source"] = self.power[zone]
        if zone in self.off:
            body["enabled"] = False
        return Message("zones", self.zone_base + topic_part(zone), dumps(body), 1, True)
