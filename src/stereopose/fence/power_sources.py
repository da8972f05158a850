"""The zones' breakers and earthing switches read from the utility (fence.power's sources)
onto a PowerBoard (fence.power_state), each on its own thread, never in the frame loop's way:

- **IEC 60870-5-104**: a master (c104's Client) per RTU (host, port): a general interrogation
  when the link opens and every `interrogation_s` after, spontaneous changes as they come,
  reconnection by itself when the link drops (c104's, every few seconds); a link whose start-up
  c104 missed (left muted, or awaiting its opening, over a period) is unmuted or reconnected
  (figures `iec104_unmuted`, `iec104_reconnected`). A lost link makes
  its points unknown at once; a point with invalid quality (or a double point indeterminate)
  is unknown. Points are M_SP_TB_1 / M_DP_TB_1 (`time_tag = false`: M_SP_NA_1 / M_DP_NA_1),
  as the RTU sends them.
- **OPC UA** (asyncua): a client per endpoint, subscribing to its nodes' data changes and
  reading them every `interrogation_s`; a failure or a bad status makes the points unknown
  and the client connects again after 1, 2, 4 ... 30 s. A password comes from
  `password_file` (its first line), never from the site file, and is never logged.
- **MQTT**: the site's broker (`[mqtt]`), subscribing to each point's topic (retained
  states come at once); a lost connection makes the points unknown.

`start_sources(zones, board, mqtt=..., base=...)` starts them; `.stop()` ends them.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import uuid
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from stereopose.errors import ConfigError
from stereopose.fence.power import DOUBLE, PointSource
from stereopose.fence.power_state import PowerBoard
from stereopose.fence.zones import Zone
from stereopose.scada.iec104_settings import _typed
from stereopose.secrets import redact

__all__ = ["PowerSources", "start_sources"]

logger = logging.getLogger(__name__)

BACKOFF_S = (1.0, 2.0, 4.0, 8.0, 15.0, 30.0)
MAX_PAYLOAD = 4096


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
        self.parts: list[Any] = []
        self.figures: dict[str, int] = defaultdict(int)

    def stop(self) -> None:
        for part in self.parts:
            try:
                part.stop()
            except Exception as e:  # stopping one never keeps the others running
                logger.warning("zone state: stopping %s: %s", part, e)


def start_sources(
    zones: Sequence[Zone], board: PowerBoard, *, mqtt: Any = None, base: Path | None = None
) -> PowerSources:
    """Start a source per RTU, OPC UA endpoint and the site's broker for the zones' points;
    a ConfigError when an MQTT point has no broker or a password file cannot be read."""
    out = PowerSources()
    points = _points(zones)
    by_kind: dict[str, dict[Any, list[PointSource]]] = defaultdict(lambda: defaultdict(list))
    for p in points:
        if p.protocol == "iec104":
            by_kind["iec104"][(p.get("host"), p.get("port"))].append(p)
        elif p.protocol == "opcua":
            by_kind["opcua"][p.get("endpoint")].append(p)
        else:
            by_kind["mqtt"][None].append(p)
    if by_kind["mqtt"] and mqtt is None:
        raise ConfigError("a zone's state comes over MQTT: set [mqtt] host (the site's broker)")
    try:
        for (host, port), ps in by_kind["iec104"].items():
            out.parts.append(Iec104Master(host, port, ps, board, out.figures))
        for endpoint, ps in by_kind["opcua"].items():
            out.parts.append(OpcuaWatcher(endpoint, ps, board, out.figures, base))
        if by_kind["mqtt"]:
            out.parts.append(MqttWatcher(mqtt, by_kind["mqtt"][None], board, out.figures))
        for part in out.parts:
            part.start()
    except BaseException:
        out.stop()
        raise
    return out


# -- IEC 60870-5-104 ---------------------------------------------------------------------------


class Iec104Master:
    """A c104 master of one RTU (see the module)."""

    def __init__(self, host: str, port: int, points: list[PointSource], board, figures) -> None:
        import c104

        self.c104, self.board, self.figures = c104, board, figures
        self.host, self.port = host, int(port)
        self.points = points
        self.keys = [p.label for p in points]
        self.interrogation_s = min(p.interrogation_s for p in points)
        self.client = c104.Client(tick_rate_ms=50, command_timeout_ms=5000)
        self.connection = self.client.add_connection(
            ip=host, port=self.port, init=c104.Init.INTERROGATION
        )
        if self.connection is None:
            raise ConfigError(f"zone state: cannot reach an IEC 104 RTU at {host}:{port}")
        self.connection.on_state_change(
            callable=_typed(
                lambda connection, state: self._on_state(connection, state),
                connection=c104.Connection,
                state=c104.ConnectionState,
                ret=None,
            )
        )
        on_receive = _typed(
            lambda point, previous_info, message: self._on_receive(point, previous_info, message),
            point=c104.Point,
            previous_info=c104.Information,
            message=c104.IncomingMessage,
            ret=c104.ResponseState,
        )
        self.stations: dict[int, Any] = {}
        self._by_point: dict[tuple[int, int], PointSource] = {}
        for p in points:
            ca = int(p.get("common_address"))
            station = self.stations.get(ca) or self.connection.add_station(common_address=ca)
            self.stations[ca] = station
            kind = {
                (False, True): c104.Type.M_SP_TB_1,
                (False, False): c104.Type.M_SP_NA_1,
                (True, True): c104.Type.M_DP_TB_1,
                (True, False): c104.Type.M_DP_NA_1,
            }[(p.get("type") == DOUBLE, bool(p.get("time_tag", True)))]
            point = station.add_point(io_address=int(p.get("ioa")), type=kind)
            point.on_receive(callable=on_receive)
            self._by_point[(ca, int(p.get("ioa")))] = p
        self._open = False
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._interrogate, name="zone-state-iec104", daemon=True
        )

    def __repr__(self) -> str:
        return f"IEC 104 master of {self.host}:{self.port}"

    def start(self) -> None:
        self.client.start()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self.client.stop()
        self._thread.join(timeout=5.0)

    def _interrogate(self) -> None:
        """A general interrogation every interrogation_s while the link is open.

        c104's Client can miss its own start-up of a connection: the socket then stays open
        and muted (no STARTDT: the RTU sends nothing), or stays awaiting its opening. A link
        seen so at two looks in a row is started again: unmuted, or reconnected (counted)."""
        c104, stuck = self.c104, None
        while not self._stop.wait(self.interrogation_s):
            state = self.connection.state
            if state in (c104.ConnectionState.OPEN_MUTED, c104.ConnectionState.CLOSED_AWAIT_OPEN):
                if stuck == state:
                    self._restart(state)
                    state = None
                stuck = state
                continue
            stuck = None
            if state != c104.ConnectionState.OPEN:
                continue
            for ca in self.stations:
                try:
                    self.connection.interrogation(common_address=ca, wait_for_response=False)
                except Exception as e:  # a refused command: the next period tries again
                    logger.debug("IEC 104 %s:%d: interrogation: %s", self.host, self.port, e)

    def _restart(self, state) -> None:
        muted = state == self.c104.ConnectionState.OPEN_MUTED
        self.figures["iec104_unmuted" if muted else "iec104_reconnected"] += 1
        logger.info(
            "IEC 104 %s:%d: link %s over a period, %s",
            self.host,
            self.port,
            "muted" if muted else "still opening",
            "STARTDT again" if muted else "connecting again",
        )
        try:
            if muted:
                self.connection.unmute()
            else:
                self.connection.disconnect()
                self.connection.connect()
        except Exception as e:  # the next period tries again
            logger.debug("IEC 104 %s:%d: restarting the link: %s", self.host, self.port, e)

    def _on_state(self, connection, state) -> None:  # c104's thread
        c104 = self.c104
        if state in (c104.ConnectionState.OPEN, c104.ConnectionState.OPEN_MUTED):
            self._open = True
            return
        if not self._open:  # not yet open (connecting): its points have no value yet anyway
            return
        self._open = False
        self.figures["iec104_link_lost"] += 1
        self.board.lost(self.keys, f"IEC 104 link to {self.host}:{self.port} lost")

    def _on_receive(self, point, previous_info, message):  # c104's thread
        c104 = self.c104
        try:
            p = self._by_point.get((point.station.common_address, point.io_address))
            if p is None:
                self.figures["iec104_refused"] += 1
                return c104.ResponseState.NONE
            value = point.value
            good = bool(point.quality.is_good())
            if isinstance(value, c104.Double):
                text = {
                    c104.Double.OFF: "open",
                    c104.Double.ON: "closed",
                    c104.Double.INTERMEDIATE: "intermediate",
                }.get(value)
                if text is None:
                    self.board.set(p.label, None, False, "double point indeterminate")
                else:
                    self.board.set(p.label, text, good)
            else:
                self.board.set(p.label, "on" if bool(value) else "off", good)
            self.figures["iec104_received"] += 1
        except Exception as e:  # a message this master cannot read: counted, never raised
            self.figures["iec104_refused"] += 1
            logger.debug("IEC 104 %s:%d: a message not read: %s", self.host, self.port, e)
        return c104.ResponseState.NONE


# -- OPC UA ------------------------------------------------------------------------------------


def _password(p: PointSource, base: Path | None) -> str | None:
    name = p.get("password_file")
    if name is None:
        return None
    path = Path(name) if base is None or Path(name).is_absolute() else base / name
    try:
        return path.read_text(encoding="utf-8").splitlines()[0].strip()
    except (OSError, UnicodeDecodeError, IndexError) as e:
        raise ConfigError(f"{path}: cannot read the OPC UA password: {type(e).__name__}") from None


def _reading(value: Any) -> Any:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, (int, float, str)):
        return value
    return str(value)


class OpcuaWatcher:
    """An asyncua client of one endpoint, on a thread with its own event loop."""

    def __init__(self, endpoint: str, points, board, figures, base: Path | None) -> None:
        self.endpoint, self.points, self.board, self.figures = endpoint, points, board, figures
        self.keys = [p.label for p in points]
        self.user = next((p.get("username") for p in points if p.get("username")), None)
        self.password = next((_password(p, base) for p in points if p.get("password_file")), None)
        self.interrogation_s = min(p.interrogation_s for p in points)
        self._loop = asyncio.new_event_loop()
        self._stopping: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._run, name="zone-state-opcua", daemon=True)

    def __repr__(self) -> str:
        return f"OPC UA client of {redact(self.endpoint)}"

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        if self._stopping is not None:
            self._loop.call_soon_threadsafe(self._stopping.set)
        self._thread.join(timeout=10.0)

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)
        self._loop.run_until_complete(self._main())

    async def _main(self) -> None:
        self._stopping = asyncio.Event()
        attempt = 0
        while not self._stopping.is_set():
            try:
                await self._session()
                attempt = 0
            except Exception as e:  # any failure: unknown, then connect again
                self.figures["opcua_link_lost"] += 1
                where = redact(self.endpoint)
                self.board.lost(self.keys, f"OPC UA {where}: {type(e).__name__}")
                logger.info("zone state: OPC UA %s: %s; connecting again", where, e)
            wait = BACKOFF_S[min(attempt, len(BACKOFF_S) - 1)]
            attempt += 1
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), wait)

    async def _session(self) -> None:
        from asyncua import Client

        client = Client(self.endpoint, timeout=5)
        if self.user:
            client.set_user(self.user)
        if self.password:
            client.set_password(self.password)
        async with client:
            nodes = {p.label: client.get_node(p.get("node_id")) for p in self.points}
            handler = _Changes(self)
            sub = await client.create_subscription(200, handler)
            handler.labels = {n.nodeid: label for label, n in nodes.items()}
            await sub.subscribe_data_change(list(nodes.values()))
            while not self._stopping.is_set():
                for label, node in nodes.items():
                    dv = await node.read_data_value()
                    self._take(label, dv.Value.Value if dv.Value else None, dv.StatusCode)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stopping.wait(), self.interrogation_s)

    def _take(self, label: str, value: Any, status: Any) -> None:
        good = status is None or bool(getattr(status, "is_good", lambda: True)())
        if value is None:
            self.board.set(label, None, False, "no value")
        else:
            self.board.set(label, _reading(value), good, "" if good else f"status {status}")
        self.figures["opcua_received"] += 1


class _Changes:
    def __init__(self, watcher: OpcuaWatcher) -> None:
        self.watcher = watcher
        self.labels: dict[Any, str] = {}

    def datachange_notification(self, node, val, data) -> None:
        label = self.labels.get(node.nodeid)
        if label is None:
            self.watcher.figures["opcua_refused"] += 1
            return
        status = getattr(getattr(data, "monitored_item", None), "Value", None)
        self.watcher._take(label, val, getattr(status, "StatusCode", None))

    def status_change_notification(self, status) -> None:
        where = redact(self.watcher.endpoint)
        self.watcher.board.lost(self.watcher.keys, f"OPC UA {where}: {status}")


# -- MQTT --------------------------------------------------------------------------------------


def _payload(raw: bytes) -> Any:
    """An MQTT payload as a reading: its JSON value, or its text; None when unreadable."""
    if len(raw) > MAX_PAYLOAD:
        return None
    try:
        text = raw.decode("utf-8").strip()
    except UnicodeDecodeError:
        return None
    try:
        value = json.loads(text)
    except (ValueError, RecursionError):
        return text or None
    if isinstance(value, dict):  # {"value": ...} as many bridges publish
        value = value.get("value", value.get("state"))
    if value is None or isinstance(value, (list, dict)):
        return None
    return _reading(value)


class MqttWatcher:
    """A subscriber on the site's broker (paho's thread reconnects with backoff)."""

    def __init__(self, settings: Any, points: list[PointSource], board, figures) -> None:
        from stereopose.io.sinks.mqtt_settings import make_client

        self.settings, self.board, self.figures = settings, board, figures
        self.topics = {p.get("topic"): p.label for p in points}
        self.client = make_client(settings, f"stereopose-state-{uuid.uuid4().hex[:8]}")
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message

    def __repr__(self) -> str:
        return f"MQTT subscriber of {self.settings.host}:{self.settings.port}"

    def start(self) -> None:
        self.client.connect_async(self.settings.host, self.settings.port, keepalive=30)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_connect(self, client, userdata, flags, reason, props) -> None:
        if getattr(reason, "is_failure", False):
            self.board.lost(list(self.topics.values()), f"MQTT broker refused: {reason}")
            return
        for topic in self.topics:
            client.subscribe(topic, qos=1)

    def _on_disconnect(self, client, userdata, flags, reason, props) -> None:
        self.figures["mqtt_link_lost"] += 1
        self.board.lost(list(self.topics.values()), "MQTT broker link lost")

    def _on_message(self, client, userdata, message) -> None:
        label = self.topics.get(message.topic)
        value = _payload(message.payload) if label is not None else None
        if label is None or value is None:
            self.figures["mqtt_refused"] += 1
            if label is not None:
                self.board.set(label, None, False, "an unreadable payload")
            return
        self.figures["mqtt_received"] += 1
        self.board.set(label, value, True)
