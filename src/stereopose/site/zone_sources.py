"""The zones' live or dead state read from the utility: a source per RTU (scada.iec104_master),
OPC UA endpoint (scada.opcua_watcher) and the site's broker (io.mqtt_watcher), each on its own
thread, onto one PowerBoard (zones.power_state) that the zone-state step reads.

`start_sources(zones, board, mqtt=..., base=...)` starts them; `.stop()` ends them. The service
holds them as one `ZonePower`: the site's sources started with the service, replaced whole at a
site change (`restart`), stopped with it.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import TypeVar

from stereopose.errors import ConfigError
from stereopose.fence import Site
from stereopose.io.mqtt_watcher import MqttWatcher
from stereopose.io.sinks.mqtt_settings import MqttSettings
from stereopose.scada.iec104_master import Iec104Master
from stereopose.scada.iec104_tls import Iec104TlsMaster, tls_context
from stereopose.scada.opcua_watcher import OpcuaWatcher
from stereopose.zones.power import Iec104Point, MqttPoint, OpcuaPoint, PointSource
from stereopose.zones.power_state import PowerBoard, ZoneStates
from stereopose.zones.safe import Safe
from stereopose.zones.zone import Zone

__all__ = ["PowerSources", "ZonePower", "start_sources"]

logger = logging.getLogger(__name__)


def _points(zones: Sequence[Zone]) -> list[PointSource]:
    seen: dict[str, PointSource] = {}
    for z in zones:
        if z.power is not None:
            for p in z.power.points:
                seen.setdefault(p.label, p)
    return list(seen.values())


class PowerSources:
    """The running sources (see the module); figures: messages taken and refused by source."""

    def __init__(self) -> None:
        self.parts: list[Iec104Master | Iec104TlsMaster | OpcuaWatcher | MqttWatcher] = []
        self.figures: dict[str, int] = defaultdict(int)

    def stop(self) -> None:
        for part in self.parts:
            try:
                part.stop()
            except Exception as e:  # stopping one never keeps the others running
                logger.warning("zone state: stopping %s: %s", part, e)


class ZonePower:
    """The zones' live or dead states of the running site and the sources that read them (none
    where no zone has a source): `start()` with the service, `restart(site)` at a site change
    (the frame loop's thread: the old sources stopped, the new site's started), `stop()` with
    the service. `states` is the running site's ZoneStates (None: no zone has a source)."""

    def __init__(self, site: Site | None, *, mqtt: MqttSettings | None, base: Path) -> None:
        self._mqtt, self._base = mqtt, base
        self._site = site
        self.states = _states(site)
        self._sources: PowerSources | None = None

    def start(self) -> None:
        if self.states is not None and self._site is not None:
            self._start(self._site, self.states)

    def _start(self, site: Site, states: ZoneStates) -> None:
        self._sources = start_sources(site.zones, states.board, mqtt=self._mqtt, base=self._base)

    def restart(self, site: Site) -> ZoneStates | None:
        """`site`'s sources in place of the running ones; its ZoneStates (None: none)."""
        self.stop()
        self._site, self.states = site, _states(site)
        if self.states is not None:
            self._start(site, self.states)
        return self.states

    def stop(self) -> None:
        """The sources that run now stopped (none: nothing to do)."""
        sources, self._sources = self._sources, None
        if sources is not None:
            sources.stop()

    def snapshot(self) -> dict:
        """The energized zones' states now (empty: no zone has a source)."""
        return self.states.snapshot() if self.states is not None else {}

    def safe_now(self) -> dict[str, Safe]:
        """The zones dead by their breakers now, each with its state's source (empty: none)."""
        return self.states.safe_now() if self.states is not None else {}

    def figures(self) -> dict | None:
        """status.json's `zone_state`: the zones' states and each source's messages (None:
        no zone has a source)."""
        states, sources = self.states, self._sources
        if states is None:
            return None
        return {"zones": states.snapshot(), "sources": dict(sources.figures) if sources else {}}


def _states(site: Site | None) -> ZoneStates | None:
    zones = site.zones if site is not None else ()
    return ZoneStates(zones, PowerBoard()) if any(z.power for z in zones) else None


def start_sources(
    zones: Sequence[Zone],
    board: PowerBoard,
    *,
    mqtt: MqttSettings | None = None,
    base: Path | None = None,
) -> PowerSources:
    """Start a source per RTU, OPC UA endpoint and the site's broker for the zones' points;
    a ConfigError when an MQTT point has no broker or a password file cannot be read."""
    out = PowerSources()
    links: dict[tuple[str, ...], list[PointSource]] = defaultdict(list)
    for p in _points(zones):
        links[p.link].append(p)
    if any(isinstance(ps[0], MqttPoint) for ps in links.values()) and mqtt is None:
        raise ConfigError("a zone's state comes over MQTT: set [mqtt] host (the site's broker)")
    try:
        for ps in links.values():
            out.parts.append(_source(ps, board, out.figures, mqtt, base))
        for part in out.parts:
            part.start()
    except BaseException:
        out.stop()
        raise
    return out


def _source(
    points: list[PointSource],
    board: PowerBoard,
    figures: dict[str, int],
    mqtt: MqttSettings | None,
    base: Path | None,
) -> Iec104Master | Iec104TlsMaster | OpcuaWatcher | MqttWatcher:
    """The client of one link's points."""
    first = points[0]
    if isinstance(first, Iec104Point):
        tls = first.tls
        iec = _of(points, Iec104Point)
        if any(p.tls != tls for p in iec):
            raise ConfigError(
                f"zone state: the points of IEC 104 {first.host}:{first.port} differ in their "
                "tls_ca, tls_certificate and tls_key: one link, one TLS setting"
            )
        if tls is None:
            return Iec104Master(first.host, first.port, iec, board, figures)
        here = base or Path(".")
        ca, cert, key = (here / Path(f).expanduser() for f in tls)
        context = tls_context(ca, cert, key, f"zone state: IEC 104 {first.host}:{first.port}")
        return Iec104TlsMaster(first.host, first.port, iec, board, figures, context)
    if isinstance(first, OpcuaPoint):
        return OpcuaWatcher(first.endpoint, _of(points, OpcuaPoint), board, figures, base)
    if mqtt is None:
        raise ConfigError("zone state: a point read over MQTT needs the [mqtt] broker")
    return MqttWatcher(mqtt, _of(points, MqttPoint), board, figures)


_P = TypeVar("_P", bound=PointSource)


def _of(points: list[PointSource], kind: type[_P]) -> list[_P]:
    """A link's points, all of one protocol (they are grouped by their link)."""
    out = [p for p in points if isinstance(p, kind)]
    assert len(out) == len(points)
    return out
