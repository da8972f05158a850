"""Zone state from the utility's breakers and earthing switches, over real links: a c104
outstation playing the RTU, an asyncua server and Mosquitto. A zone goes dead and live with its
breaker and earthing switch; a lost link or an invalid point makes it unknown (live) with a
diagnostic incident naming the source; someone inside when it turns live is an alarm at once;
a dead zone's entries are info."""

from __future__ import annotations

import asyncio
import json
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bodies import people
from brokers import Broker, free_port
from stereopose.alarms import IncidentBook
from stereopose.alarms.levels import level
from stereopose.fence import FenceMonitor, load_site
from stereopose.io.sinks.mqtt_settings import MqttSettings
from stereopose.sim.motion import pose
from stereopose.site.zone_sources import start_sources
from stereopose.zones.power_state import DEAD, LIVE, UNKNOWN, PowerBoard, ZoneStates
from waiting import wait_until

c104 = pytest.importorskip("c104")

PANEL = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]


def _site(folder: Path, state: str) -> Path:
    path = folder / "site.toml"
    path.write_text(
        f"""
[[zones]]
name = "bay2_panel"
kind = "energized"
polygon = {PANEL}
z = [0.0, 2.5]
joints = ["left_wrist", "right_wrist"]
voltage_kv = 10
{state}
"""
    )
    return path


class Rtu:
    """A c104 outstation with a breaker QF2 and an earthing switch QE2 (double points)."""

    def __init__(self, qf: str = "closed", qe: str = "open") -> None:
        self.port = free_port()
        self.server = c104.Server(ip="127.0.0.1", port=self.port, tick_rate_ms=50)
        station = self.server.add_station(common_address=7)
        self.points = {
            "qf": station.add_point(io_address=2001, type=c104.Type.M_DP_TB_1),
            "qe": station.add_point(io_address=2002, type=c104.Type.M_DP_TB_1),
        }
        self.set("qf", qf, send=False)
        self.set("qe", qe, send=False)
        self.server.start()

    def set(self, name: str, position: str, send: bool = True, invalid: bool = False) -> None:
        p = self.points[name]
        p.value = {"open": c104.Double.OFF, "closed": c104.Double.ON}[position]
        p.quality = c104.Quality.Invalid if invalid else c104.Quality()
        if send:
            p.transmit(cause=c104.Cot.SPONTANEOUS)

    def stop(self) -> None:
        self.server.stop()


def _reaching(pid: int, inside: bool) -> dict[int, np.ndarray]:
    """A worker by the panel, a hand inside it (or not)."""
    J = pose(1.75, np.array([[1.5 if not inside else 1.2, 0.5]]), np.array([np.pi]))[0]
    if inside:
        J[9] = J[10] = [0.7, 0.5, 1.2]  # both wrists in the panel
    return {pid: J}


class Loop:
    """The service's order of things at each step: fences, the zones' states, relabelled."""

    def __init__(self, site, board) -> None:
        self.fences = FenceMonitor(site, 25.0)
        self.states = ZoneStates(site.zones, board, start_s=0.5)
        self.book = IncidentBook()
        self.frame = 0
        self.events: list = []

    def step(self, inside: bool) -> list:
        self.frame += 1
        t = self.frame / 25.0
        fence = self.fences.update(people(self.frame, _reaching(4, inside), t=t))
        mine = self.states.step(t, self.frame, self.fences)
        events = [*self.states.relabel(fence), *mine]
        up = self.book.update(events, t)
        events = [replace(e, incident=i) for e, i in zip(events, up.incidents, strict=True)]
        self.events += events
        return events

    def until(self, what, condition, inside: bool = False, timeout_s: float = 20.0) -> list:
        got: list = []

        def check() -> bool:
            got.extend(self.step(inside))
            return condition(got)

        wait_until(check, what, timeout_s=timeout_s, poll_s=0.02)
        return got


def _types(events) -> list[str]:
    return [e.type for e in events]


def _rtu_state(rtu: Rtu, interrogation_s: float) -> str:
    """The zone's [zones.state]: dead when the RTU's breaker QF2 is open and its earthing switch
    QE2 closed."""
    link = (
        f'host = "127.0.0.1", port = {rtu.port}, common_address = 7, type = "double", '
        f"interrogation_s = {interrogation_s}"
    )
    return f"""
[zones.state]
dead_when = "qf == 'open' and qe == 'closed'"
[zones.state.points]
qf = {{ iec104 = {{ {link}, ioa = 2001 }} }}
qe = {{ iec104 = {{ {link}, ioa = 2002 }} }}
"""


def test_a_zone_follows_its_breaker_and_earthing_switch_over_iec104(tmp_path: Path) -> None:
    rtu = Rtu(qf="closed", qe="open")
    state = _rtu_state(rtu, interrogation_s=2)
    site = load_site(_site(tmp_path, state))
    assert site.zones[0].margin_m == 0.70  # 10 kV: GB 26860's 0.7 m
    board = PowerBoard()
    sources = start_sources(site.zones, board)
    loop = Loop(site, board)
    try:
        # (the master's first connection and interrogation: slow on a loaded machine)
        got = loop.until(
            "the zone live from the interrogation",
            lambda g: "zone_live" in _types(g),
            timeout_s=45,
        )
        assert loop.states.snapshot()["bay2_panel"]["state"] == LIVE
        # switched out and earthed: dead; the worker's touch is info, never an alarm
        rtu.set("qf", "open")
        rtu.set("qe", "closed")
        got = loop.until("the zone dead", lambda g: "zone_dead" in _types(g))
        dead = next(e for e in got if e.type == "zone_dead")
        assert "ioa 2001" in dead.source and "ioa 2002" in dead.source
        got = loop.until(
            "the worker's entry",
            lambda g: any(e.type == "enter" for e in g),
            inside=True,
        )
        entry = next(e for e in got if e.type == "enter")
        assert entry.kind == DEAD and level(entry.kind, entry.type) == "info"
        assert entry.incident is None and "ioa 2001" in entry.source
        # the earth opened while he is inside: live (unknown would be too), an alarm at once
        rtu.set("qe", "open")
        got = loop.until("live again", lambda g: "zone_live" in _types(g), inside=True)
        alarm = [e for e in got if e.type == "enter" and e.kind == "energized"]
        assert len(alarm) == 1 and alarm[0].person == 4 and alarm[0].incident is not None
        assert alarm[0].frame == next(e for e in got if e.type == "zone_live").frame
        # an invalid point: unknown, and said so with its source
        rtu.set("qf", "open")
        rtu.set("qe", "closed")
        loop.until("dead again", lambda g: "zone_dead" in _types(g), inside=True)
        rtu.set("qe", "closed", invalid=True)
        got = loop.until("unknown", lambda g: "zone_unknown" in _types(g), inside=True)
        unknown = next(e for e in got if e.type == "zone_unknown")
        assert "ioa 2002" in unknown.source and "invalid" in unknown.source
        assert unknown.incident is not None  # the diagnostic incident
        assert any(e.type == "enter" and e.kind == "energized" for e in got)  # live for safety
        # a link cut: unknown at once, then known again when the RTU is back
        rtu.set("qe", "closed")
        loop.until("known again", lambda g: "zone_dead" in _types(g), inside=True)
        rtu.stop()
        got = loop.until("unknown at the link cut", lambda g: "zone_unknown" in _types(g))
        assert "lost" in next(e for e in got if e.type == "zone_unknown").source
        assert loop.states.snapshot()["bay2_panel"]["state"] == UNKNOWN
        assert sources.figures["iec104_link_lost"] >= 1
    finally:
        sources.stop()
        rtu.stop()


def test_a_link_left_muted_is_started_again(tmp_path: Path) -> None:
    """c104's Client can miss a connection's start-up: the link stays open and muted, and the
    RTU sends nothing. The master sees it muted over a period and sends STARTDT again (counted),
    and the zone follows its breaker once more."""
    rtu = Rtu(qf="closed", qe="open")
    state = _rtu_state(rtu, interrogation_s=1)
    site = load_site(_site(tmp_path, state))
    board = PowerBoard()
    sources = start_sources(site.zones, board)
    loop = Loop(site, board)
    try:
        loop.until("live", lambda g: "zone_live" in _types(g), timeout_s=45)
        master = sources.parts[0]
        wait_until(lambda: master.connection.mute(), "STOPDT confirmed", timeout_s=10)
        wait_until(
            lambda: master.connection.state == c104.ConnectionState.OPEN_MUTED, "the link muted"
        )
        rtu.set("qf", "open")  # sent to no one: the link is muted
        rtu.set("qe", "closed")
        got = loop.until("dead once unmuted", lambda g: "zone_dead" in _types(g), timeout_s=30)
        assert sources.figures["iec104_unmuted"] >= 1
        # the zone's values may come before c104 reports the link's state as open again
        wait_until(
            lambda: master.connection.state == c104.ConnectionState.OPEN, "the link open again"
        )
        assert sources.figures["iec104_link_lost"] == 0
        assert "ioa 2001" in next(e for e in got if e.type == "zone_dead").source
    finally:
        sources.stop()
        rtu.stop()


def test_a_zone_state_over_mqtt_and_its_broker_lost(tmp_path: Path) -> None:
    import paho.mqtt.client as paho

    broker = Broker(tmp_path / "broker").start()
    state = 'state = { mqtt = { topic = "scada/bay2/qf2", energized_when = "closed" } }'
    site = load_site(_site(tmp_path, state))
    board = PowerBoard()
    settings = MqttSettings(host="127.0.0.1", port=broker.port, site="test")
    sources = start_sources(site.zones, board, mqtt=settings)
    loop = Loop(site, board)
    pub = paho.Client(paho.CallbackAPIVersion.VERSION2)
    pub.connect("127.0.0.1", broker.port)
    pub.loop_start()
    try:
        pub.publish("scada/bay2/qf2", json.dumps({"value": "open"}), qos=1, retain=True)
        loop.until("dead", lambda g: "zone_dead" in _types(g))
        pub.publish("scada/bay2/qf2", b"\xff\xfe not text", qos=1)
        got = loop.until("unknown on a bad payload", lambda g: "zone_unknown" in _types(g))
        assert "unreadable" in next(e for e in got if e.type == "zone_unknown").source
        pub.publish("scada/bay2/qf2", "closed", qos=1, retain=True)
        loop.until("live", lambda g: "zone_live" in _types(g))
        assert sources.figures["mqtt_refused"] == 1
        pub.loop_stop()
        broker.stop()
        got = loop.until("unknown when the broker goes", lambda g: "zone_unknown" in _types(g))
        assert "MQTT" in next(e for e in got if e.type == "zone_unknown").source
    finally:
        sources.stop()
        broker.stop()


def test_a_zone_state_over_opcua_and_the_server_gone(tmp_path: Path) -> None:
    from asyncua import Server, ua

    port = free_port()
    ready, stop = threading.Event(), threading.Event()
    holder: dict = {}

    def serve() -> None:
        async def main() -> None:
            server = Server()
            await server.init()
            server.set_endpoint(f"opc.tcp://127.0.0.1:{port}/rtu/")
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
            ns = await server.register_namespace("urn:test:rtu")
            qf = await server.nodes.objects.add_variable(
                ua.NodeId("QF2", ns), "QF2", True, varianttype=ua.VariantType.Boolean
            )
            await qf.set_writable()
            holder["qf"], holder["loop"], holder["ns"] = qf, asyncio.get_running_loop(), ns
            async with server:
                ready.set()
                while not stop.is_set():
                    await asyncio.sleep(0.05)

        asyncio.run(main())

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    assert ready.wait(20)
    ns = holder["ns"]
    endpoint = f"opc.tcp://127.0.0.1:{port}/rtu/"
    state = f'state = {{ opcua = {{ endpoint = "{endpoint}", node_id = "ns={ns};s=QF2" }} }}'
    site = load_site(_site(tmp_path, state))
    board = PowerBoard()
    sources = start_sources(site.zones, board)
    loop = Loop(site, board)

    def write(value: bool) -> None:
        asyncio.run_coroutine_threadsafe(holder["qf"].write_value(value), holder["loop"]).result(5)

    try:
        loop.until("live", lambda g: "zone_live" in _types(g), timeout_s=20)
        write(False)
        loop.until("dead", lambda g: "zone_dead" in _types(g))
        write(True)
        loop.until("live", lambda g: "zone_live" in _types(g))
        stop.set()
        thread.join(10)
        got = loop.until("unknown with the server gone", lambda g: "zone_unknown" in _types(g))
        assert "opcua" in next(e for e in got if e.type == "zone_unknown").source
    finally:
        stop.set()
        sources.stop()
