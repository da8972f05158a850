"""The IEC 60870-5-104 outstation with c104's own Client as the master, over real sockets:
general interrogation returns every point `stereopose points` prints; zone, camera, service and
incident changes arrive spontaneously with the events' time tags; a camera down makes its
zones' points invalid; hostile clients (garbage, reconnects, dozens at once, addresses not
allowed) leave a well-behaved master served; commands acknowledge; the served demo's zone
entries reach the master."""

from __future__ import annotations

import contextlib
import csv
import datetime as dt
import io
import json
import socket
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

c104 = pytest.importorskip("c104")

from brokers import free_port  # noqa: E402
from stereopose.alarms import IncidentBook  # noqa: E402
from stereopose.calibration.formats import save_calibration  # noqa: E402
from stereopose.cli import main  # noqa: E402
from stereopose.cli.points import points_of  # noqa: E402
from stereopose.config import Iec104Config  # noqa: E402
from stereopose.fence import Site, Zone, save_site  # noqa: E402
from stereopose.io.sinks import FrameResult  # noqa: E402
from stereopose.scada.iec104 import Iec104Settings, Outstation  # noqa: E402
from stereopose.scada.points import points_table  # noqa: E402
from stereopose.sim.scene import make_rig  # noqa: E402
from stereopose.types import Event, People3D  # noqa: E402
from waiting import listening, wait_until  # noqa: E402

WALL_START = 1_780_000_000.0  # 2026-05-28T20:26:40Z
CA = 7


def typed_callback(fn, *, ret, **params):
    fn.__annotations__ = {**params, "return": ret}
    return fn


@dataclass(frozen=True)
class Got:
    """One information object as the master received it."""

    ioa: int
    cot: str
    value: object
    invalid: bool
    recorded_at: dt.datetime | None
    type: str
    at: float  # the master's time.time() on receipt


class Master:
    """c104's Client as the telecontrol master of one outstation: it accepts every station
    and point the outstation sends, and keeps each message."""

    def __init__(self, port: int, init=None) -> None:
        self.lock = threading.Lock()
        self.got: list[Got] = []
        self.raw: list[str] = []
        self.client = c104.Client(tick_rate_ms=50, command_timeout_ms=5000)
        self.conn = self.client.add_connection(
            ip="127.0.0.1", port=port, init=init or c104.Init.ALL
        )

        def on_station(client, connection, common_address):
            connection.add_station(common_address=common_address)

        def on_point(client, station, io_address, point_type):
            pt = station.add_point(io_address=io_address, type=point_type)

            def receive(point, previous_info, message):
                return self._receive(point, message)

            pt.on_receive(
                callable=typed_callback(
                    receive,
                    point=c104.Point,
                    previous_info=c104.Information,
                    message=c104.IncomingMessage,
                    ret=c104.ResponseState,
                )
            )

        self.client.on_new_station(
            callable=typed_callback(
                on_station,
                client=c104.Client,
                connection=c104.Connection,
                common_address=int,
                ret=None,
            )
        )
        self.client.on_new_point(
            callable=typed_callback(
                on_point,
                client=c104.Client,
                station=c104.Station,
                io_address=int,
                point_type=c104.Type,
                ret=None,
            )
        )

        def on_raw(connection, data):
            with self.lock:
                self.raw.append(c104.explain_bytes(apdu=data))

        self.conn.on_receive_raw(
            callable=typed_callback(on_raw, connection=c104.Connection, data=bytes, ret=None)
        )
        self.client.start()

    def answers(self, text: str) -> list[str]:
        """The outstation's messages (as c104 explains them) that contain `text`."""
        with self.lock:
            return [r for r in self.raw if text in r]

    def _receive(self, point, message):
        value = point.value
        value = int(value) if isinstance(value, c104.Int16) else value
        g = Got(
            point.io_address,
            message.cot.name,
            value,
            not point.quality.is_good(),
            point.recorded_at,
            point.type.name,
            time.time(),
        )
        with self.lock:
            self.got.append(g)
        return c104.ResponseState.SUCCESS

    def messages(self, ioa: int | None = None, cot: str | None = None) -> list[Got]:
        with self.lock:
            return [
                g
                for g in self.got
                if (ioa is None or g.ioa == ioa) and (cot is None or g.cot == cot)
            ]

    def latest(self, ioa: int) -> Got | None:
        m = self.messages(ioa)
        return m[-1] if m else None

    def interrogated(self) -> dict[int, Got]:
        """The latest answer of each point to a general interrogation."""
        return {g.ioa: g for g in self.messages(cot="INTERROGATED_BY_STATION")}

    def wait_interrogated(self, points: int, timeout_s: float = 30.0) -> None:
        """Until the first interrogation (the connection's start) answered `points` points.

        c104's Client can miss its own start-up task (the unmute and the interrogation it
        schedules on opening a connection): the socket is then open and muted, or still
        awaiting its opening, and nothing comes. A master retries, as this one does: it
        unmutes and interrogates by itself, or reconnects."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with contextlib.suppress(pytest.fail.Exception):
                wait_until(
                    lambda: len(self.interrogated()) >= points,
                    "the interrogation",
                    timeout_s=min(3.0, max(0.1, deadline - time.monotonic())),
                )
                return
            self._nudge(interrogate=True)
        pytest.fail(f"still waiting for the interrogation after {timeout_s} s ({self})")

    def __repr__(self) -> str:
        with self.lock:
            return (
                f"master {self.conn.state.name}, {len(self.got)} points received, last "
                f"messages {self.raw[-3:]}"
            )

    def interrogate(self, points: int, timeout_s: float = 30.0) -> dict[int, Got]:
        """A fresh general interrogation, answered by `points` points. Asked again, as a
        master does, when it is not confirmed (the link was closed meanwhile: c104's Client
        missed its start-up, and the outstation closes a link without STARTDT)."""
        with self.lock:
            self.got = [g for g in self.got if g.cot != "INTERROGATED_BY_STATION"]
        deadline = time.monotonic() + timeout_s
        while not self.conn.interrogation(common_address=CA):
            if time.monotonic() > deadline:
                pytest.fail(f"no interrogation confirmed within {timeout_s} s ({self})")
            self.wait_open(timeout_s=max(0.1, deadline - time.monotonic()))
        wait_until(lambda: len(self.interrogated()) >= points, "the interrogation's answers")
        return self.interrogated()

    def command(self, ioa: int, on: bool) -> bool:
        """A single command (C_SC_NA_1) to `ioa`: whether the outstation confirmed it."""
        station = self.conn.get_station(CA) or self.conn.add_station(common_address=CA)
        point = station.get_point(ioa) or station.add_point(
            io_address=ioa, type=c104.Type.C_SC_NA_1
        )
        point.value = on
        return bool(point.transmit(cause=c104.Cot.ACTIVATION))

    def _nudge(self, interrogate: bool) -> None:
        """What a master does when its connection's start-up did not happen: unmute (and
        interrogate) an open, muted one; reopen one still awaiting its opening."""
        state = self.conn.state.name
        if state == "OPEN_MUTED":
            self.conn.unmute()
            if interrogate:
                self.conn.interrogation(common_address=CA)
        elif state == "CLOSED_AWAIT_OPEN":
            self.conn.disconnect()
            self.conn.connect()

    def wait_open(self, timeout_s: float = 30.0) -> None:
        """Until the connection is open and unmuted (STARTDT confirmed), nudged as in
        `wait_interrogated`."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with contextlib.suppress(pytest.fail.Exception):
                wait_until(
                    lambda: self.conn.is_connected and self.conn.state.name == "OPEN",
                    "the master's connection open",
                    timeout_s=min(3.0, max(0.1, deadline - time.monotonic())),
                )
                return
            self._nudge(interrogate=False)
        pytest.fail(f"still waiting for the master's connection open after {timeout_s} s ({self})")

    def close(self) -> None:
        self.client.stop()


# -- a site, a rig and an outstation --------------------------------------------------------


def _square(x: float, y: float, half: float = 0.5) -> np.ndarray:
    return np.array(
        [[x - half, y - half], [x + half, y - half], [x + half, y + half], [x - half, y + half]]
    )


@pytest.fixture(scope="module")
def rig():
    return make_rig(4, np.random.default_rng(3), (12.0, 8.0, 4.0))


def _site(rig) -> Site:
    """A panel in the room's middle (every camera sees it) and a cabinet behind the first
    camera (which does not see it), and a behaviour rule."""
    cam = rig[0]
    back = cam.center - 2.0 * cam.R[2]
    zones = (
        Zone("panel A", "energized", _square(6.0, 4.0), (0.0, 2.5)),
        Zone(
            "cabinet", "restricted", _square(back[0], back[1], 0.2), (back[2] - 0.1, back[2] + 0.1)
        ),
    )
    return Site(zones, 25.0)


@pytest.fixture
def station(rig):
    """An outstation on a free port with commands on, and its table; closed after."""
    made = []

    def make(site=None, **settings):
        site = site if site is not None else _site(rig)
        settings = {"port": free_port(), "commands": True, **settings}
        cfg = Iec104Config(enabled=True, common_address=CA, **settings)
        table = points_table(site, rig, commands=cfg.commands)
        out = Outstation(
            Iec104Settings.from_config(cfg), table, wall_start=WALL_START, status_interval_s=0.1
        )
        made.append(out)
        return out, table

    yield make
    for out in made:
        out.close()


@pytest.fixture
def masters():
    made: list[Master] = []

    def make(port: int, init=None) -> Master:
        m = Master(port, init)
        made.append(m)
        return m

    yield make
    for m in made:
        m.close()


def _frame(t: float, events=(), people: int = 0) -> FrameResult:
    p3 = People3D(
        frame=int(t * 25),
        joints=np.zeros((people, 17, 3)),
        conf=np.ones((people, 17)),
        ids=np.arange(people),
        reprojection_px=np.zeros((people, 17)),
        views=np.full((people, 17), 2),
        detections=np.zeros((people, 2), dtype=int),
    )
    return FrameResult(int(t * 25), t, {}, p3, tuple(events))


def _zone(t: float, type_: str, zone: str = "panel A", person: int = 3) -> Event:
    return Event(
        t=t, frame=int(t * 25), person=person, zone=zone, kind="energized", type=type_, onset_t=t
    )


def _camera(t: float, type_: str, camera: str) -> Event:
    return Event(
        t=t,
        frame=int(t * 25),
        person=-1,
        zone="",
        kind="camera",
        type=type_,
        onset_t=t,
        camera=camera,
    )


def _service(t: float, type_: str) -> Event:
    return Event(t=t, frame=int(t * 25), person=-1, zone="", kind="service", type=type_, onset_t=t)


def _tag(t: float) -> dt.datetime:
    """The CP56Time2a time tag of the event at t (UTC fields, as the master reads them)."""
    return dt.datetime.fromtimestamp(WALL_START + t, dt.UTC).replace(tzinfo=None)


def _spontaneous(master: Master, ioa: int, value) -> Got:
    def seen() -> bool:
        g = master.latest(ioa)
        return g is not None and g.cot == "SPONTANEOUS" and g.value == value

    wait_until(seen, f"point {ioa} = {value} spontaneously")
    return master.latest(ioa)


# -- the tests ------------------------------------------------------------------------------


def test_interrogation_returns_every_point_of_the_points_command(
    tmp_path: Path, rig, masters, capsys
) -> None:
    save_calibration(tmp_path / "calib.toml", rig)
    save_site(tmp_path / "site.toml", _site(rig))
    (tmp_path / "site.toml").write_text(
        (tmp_path / "site.toml").read_text() + '[[rules]]\nname = "down"\ntype = "person_down"\n'
    )
    port = free_port()
    cams = "".join(f'[[cameras]]\nname = "{n}"\nsource = "{n}.mp4"\n\n' for n in rig.names)
    config = tmp_path / "serve.toml"
    config.write_text(
        f'calibration = "calib.toml"\nsite = "site.toml"\n\n{cams}[iec104]\n'
        f"enabled = true\nport = {port}\ncommon_address = {CA}\n"
    )
    assert main(["points", str(config)]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    cfg, table = points_of(config)
    out = Outstation(Iec104Settings.from_config(cfg.iec104), table, wall_start=WALL_START)
    try:
        master = masters(port)
        monitored = {int(r["ioa"]): r["type"] for r in rows if not r["type"].startswith("C_")}
        master.wait_interrogated(len(monitored))
        got = master.interrogated()
        assert {ioa: g.type for ioa, g in got.items()} == monitored
        # at rest: running, nobody, no alarm, every camera up; the unseen cabinet invalid
        running = table.get("service_running").ioa
        assert got[running].value is True and not got[running].invalid
        assert got[table.get("people").ioa].value == 0
        assert all(got[table.get("camera_up", n).ioa].value is True for n in rig.names)
        assert got[table.get("zone_occupied", "cabinet").ioa].invalid
        assert not got[table.get("zone_occupied", "panel A").ioa].invalid
        assert got[table.get("rule_alarm", "down").ioa].value is False
        # asked again, the same points
        assert set(master.interrogate(len(monitored))) == set(monitored)
    finally:
        out.close()


def test_a_zone_entry_reaches_the_master_spontaneously_with_its_time_tag(station, masters) -> None:
    out, table = station()
    master = masters(out.settings.port)
    master.wait_interrogated(len(table.monitored))
    occupied = table.get("zone_occupied", "panel A").ioa
    out.write(_frame(12.345, [_zone(12.345, "enter")], people=2))
    g = _spontaneous(master, occupied, True)
    assert g.recorded_at == _tag(12.345) and not g.invalid and g.type == "M_SP_TB_1"
    people = _spontaneous(master, table.get("people").ioa, 2)
    assert people.recorded_at == _tag(12.345)
    # a second person in, the first out: still occupied, nothing sent for it
    out.write(_frame(13.0, [_zone(13.0, "enter", person=4), _zone(13.5, "exit", person=3)]))
    out.write(_frame(20.0, [_zone(20.0, "exit", person=4)]))
    g = _spontaneous(master, occupied, False)
    assert g.recorded_at == _tag(20.0)
    assert [m.value for m in master.messages(occupied, "SPONTANEOUS")] == [True, False]
    # and the interrogation says the same as the last spontaneous message
    assert master.interrogate(len(table.monitored))[occupied].value is False


def test_incidents_set_the_alarm_points_and_the_unacknowledged_count(station, masters) -> None:
    out, table = station()
    master = masters(out.settings.port)
    master.wait_open()
    book = IncidentBook()
    up = book.update([_zone(5.0, "enter")], 5.0)
    out.write_changes(up.changes)
    alarm = table.get("zone_alarm", "panel A").ioa
    unacked = table.get("unacknowledged").ioa
    g = _spontaneous(master, alarm, True)
    assert g.recorded_at == _tag(5.0)
    assert _spontaneous(master, unacked, 1).recorded_at == _tag(5.0)
    incident = up.changes[0].incident.id
    out.write_changes(book.acknowledge(incident, "otto", 6.0))
    assert _spontaneous(master, unacked, 0).recorded_at == _tag(6.0)
    assert master.latest(alarm).value is True  # acknowledged, still active
    out.write_changes(book.update([_zone(9.0, "exit")], 9.0).changes)
    assert _spontaneous(master, alarm, False).recorded_at == _tag(9.0)


def _ticket(t: float, type_: str, tid: str, step: str | None = None, person: int = 3) -> Event:
    return Event(
        t=t,
        frame=int(t * 25),
        person=person,
        zone="panel A" if step else "",
        kind="ticket",
        type=type_,
        onset_t=t,
        ticket=tid,
        step=step,
    )


def test_tickets_take_slots_with_their_deviation_and_steps_points(station, masters) -> None:
    """A ticket started takes the lowest free slot (active on), its steps done counted, a
    deviation's incident sets the slot's deviation point; at its end the slot is free again
    and the next ticket takes it."""
    out, table = station()
    master = masters(out.settings.port)
    master.wait_open()
    book = IncidentBook()
    active = [table.get("ticket_active", str(s)).ioa for s in (1, 2)]
    deviation = table.get("ticket_deviation", "1").ioa
    steps = table.get("ticket_steps", "1").ioa
    out.write(_frame(1.0, [_ticket(1.0, "ticket_started", "OT-1", person=-1)]))
    assert _spontaneous(master, active[0], True).recorded_at == _tag(1.0)
    out.write(_frame(2.0, [_ticket(2.0, "ticket_started", "OT-2", person=-1)]))
    assert _spontaneous(master, active[1], True).recorded_at == _tag(2.0)
    wrong = [_ticket(3.0, "step_out_of_order", "OT-1", "b"), _ticket(3.0, "step_done", "OT-1", "b")]
    up = book.update(wrong, 3.0)
    out.write(_frame(3.0, wrong))
    out.write_changes(up.changes)
    assert _spontaneous(master, deviation, True).recorded_at == _tag(3.0)
    assert _spontaneous(master, steps, 1).recorded_at == _tag(3.0)
    assert master.latest(table.get("ticket_deviation", "2").ioa).value is False
    end = [_ticket(5.0, "ticket_completed", "OT-1", person=-1)]
    up = book.update(end, 5.0)  # the ticket's end clears its incidents
    out.write(_frame(5.0, end))
    out.write_changes(up.changes)
    assert _spontaneous(master, active[0], False).recorded_at == _tag(5.0)
    assert _spontaneous(master, deviation, False).recorded_at == _tag(5.0)
    assert _spontaneous(master, steps, 0).recorded_at == _tag(5.0)
    assert master.latest(active[1]).value is True  # OT-2 keeps its slot
    out.write(_frame(6.0, [_ticket(6.0, "ticket_started", "OT-3", person=-1)]))
    assert _spontaneous(master, active[0], True).recorded_at == _tag(6.0)
    assert master.interrogate(len(table.monitored))[active[1]].value is True


def test_a_camera_down_makes_the_points_of_its_zones_invalid(station, masters, rig) -> None:
    out, table = station()
    master = masters(out.settings.port)
    master.wait_interrogated(len(table.monitored))
    panel = table.get("zone_occupied", "panel A")
    cabinet = table.get("zone_occupied", "cabinet")
    seen_by = set(table.get("zone_occupied", "panel A").cameras)
    assert rig.names[0] in seen_by
    out.write(_frame(3.0, [_camera(3.0, "camera_down", rig.names[0])]))
    g = _spontaneous(master, table.get("camera_up", rig.names[0]).ioa, False)
    assert g.recorded_at == _tag(3.0) and not g.invalid
    wait_until(lambda: master.latest(panel.ioa).invalid, "panel A invalid")
    assert master.latest(panel.ioa).recorded_at == _tag(3.0)
    # each point is its own message: each waited for, not read once after the first
    alarm, people = table.get("zone_alarm", "panel A").ioa, table.get("people").ioa
    wait_until(lambda: master.latest(alarm).invalid, "panel A's alarm point invalid")
    wait_until(lambda: master.latest(people).invalid, "the people count invalid")
    got = master.interrogate(len(table.monitored))
    assert got[panel.ioa].invalid and got[table.get("camera_up", rig.names[1]).ioa].value
    # the cabinet is invalid for ever (no camera sees it); the service points stay valid
    assert got[cabinet.ioa].invalid and not got[table.get("service_running").ioa].invalid
    out.write(_frame(8.0, [_camera(8.0, "camera_up", rig.names[0])]))
    wait_until(lambda: not master.latest(panel.ioa).invalid, "panel A valid again")
    assert master.latest(panel.ioa).recorded_at == _tag(8.0)


def test_a_stalled_service_is_not_running_and_its_readings_invalid(station, masters) -> None:
    out, table = station()
    master = masters(out.settings.port)
    master.wait_open()
    running = table.get("service_running").ioa
    out.write(_frame(4.0, [_service(4.0, "service_stalled")]))
    assert _spontaneous(master, running, False).recorded_at == _tag(4.0)
    wait_until(
        lambda: (
            master.latest(table.get("zone_occupied", "panel A").ioa) is not None
            and master.latest(table.get("zone_occupied", "panel A").ioa).invalid
        ),
        "panel A invalid in the stall",
    )
    out.write(_frame(9.0, [_service(9.0, "service_resumed")]))
    assert _spontaneous(master, running, True).recorded_at == _tag(9.0)
    # the degraded point follows the health answer
    health = ["ok"]
    out.status = lambda: health[0]
    health[0] = "degraded"
    _spontaneous(master, table.get("service_degraded").ioa, True)
    health[0] = "ok"
    _spontaneous(master, table.get("service_degraded").ioa, False)


def test_a_stop_tells_the_master_the_service_is_no_longer_running(station, masters) -> None:
    out, table = station()
    master = masters(out.settings.port)
    master.wait_open()
    out.close()
    _spontaneous(master, table.get("service_running").ioa, False)


def test_hostile_clients_leave_a_well_behaved_master_served(station, masters) -> None:
    out, table = station(max_connections=3)
    port = out.settings.port
    master = masters(port)
    master.wait_interrogated(len(table.monitored))
    # garbage bytes, a half frame, a wrong start byte, a frame too long: each on its own link
    for junk in (
        b"\x00" * 64,
        b"\x68\x04\x07",
        b"\xff" * 300,
        b"\x68\xff" + bytes(255),
        bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8)),
    ):
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(junk)
    # a dozen at once (beyond max_connections: refused), then dropped
    crowd = []
    for _ in range(12):
        with contextlib.suppress(OSError):
            crowd.append(socket.create_connection(("127.0.0.1", port), timeout=5))
    assert out.figures()["connections"] <= 3  # bounded: the rest refused
    for s in crowd:
        s.close()
    # masters that connect and go, again and again
    for _ in range(3):
        m = Master(port, c104.Init.NONE)
        wait_until(lambda m=m: m.conn.is_connected, "a passing master connected")
        m.close()
    out.write(_frame(30.0, [_zone(30.0, "enter")]))
    g = _spontaneous(master, table.get("zone_occupied", "panel A").ioa, True)
    assert g.recorded_at == _tag(30.0)
    assert master.conn.is_connected
    assert len(master.interrogate(len(table.monitored))) == len(table.monitored)
    # the crowd gone, and the master too, a new master is served (one master is active at a
    # time: IEC 60870-5-104's redundancy group; a second one waits muted)
    wait_until(lambda: out.figures()["connections"] <= 1, "the hostile links closed")
    master.close()
    wait_until(lambda: out.figures()["connections"] == 0, "the master gone")
    late = masters(port)
    late.wait_interrogated(len(table.monitored))  # (a master retries its start-up)
    assert late.interrogated()[table.get("zone_occupied", "panel A").ioa].value is True
    assert out.health().ok


def test_idle_sockets_cannot_lock_the_master_out(station, masters) -> None:
    out, table = station(max_connections=2, start_within_s=2.0)
    port = out.settings.port
    # two sockets that never say a word take both places (the standard's timers let them
    # hold for 35 s, again and again)
    idle = [socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(2)]
    wait_until(lambda: out.figures()["connections"] == 2, "both places taken")
    # a master takes the place of the oldest one at once, and is served
    master = masters(port)
    master.wait_interrogated(len(table.monitored), timeout_s=30)
    assert out.figures()["evicted"] == 1
    # the other is closed once it has not started data transfer within start_within_s
    for s in idle:
        s.settimeout(10)
        with contextlib.suppress(ConnectionResetError):
            while s.recv(64):  # (anything the outstation sent first), then the close
                pass
        s.close()
    wait_until(lambda: out.figures()["unstarted_closed"] >= 1, "the unstarted link closed")
    # a socket that speaks IEC 104 (a TESTFR) but never starts data transfer leaves as well
    with socket.create_connection(("127.0.0.1", port), timeout=10) as talker:
        talker.sendall(b"\x68\x04\x43\x00\x00\x00")  # TESTFR act
        assert talker.recv(6) == b"\x68\x04\x83\x00\x00\x00"  # TESTFR con, from c104
        with contextlib.suppress(ConnectionResetError):
            while talker.recv(64):
                pass
    wait_until(lambda: out.figures()["unstarted_closed"] >= 2, "the talker's link closed")
    # a second master (started: data transfer asked for) is not evicted by newcomers; with
    # both places started, a newcomer is refused
    twin = masters(port)
    wait_until(lambda: twin.conn.is_connected, "the twin connected")
    # connected is not started: until the guard has seen the twin's STARTDT, a newcomer
    # would rightly take its place
    wait_until(lambda: out.figures()["started_connections"] == 2, "the twin started")
    evicted = out.figures()["evicted"]
    late = socket.create_connection(("127.0.0.1", port), timeout=10)
    with late, contextlib.suppress(ConnectionResetError):
        assert late.recv(64) == b""
    # counted before its socket is closed; waited for all the same (the guard's own thread)
    wait_until(lambda: out.figures()["full"] >= 1, "the refused newcomer counted")
    assert out.figures()["evicted"] == evicted and out.figures()["started_connections"] == 2
    assert master.conn.is_connected
    out.write(_frame(30.0, [_zone(30.0, "enter")]))
    _spontaneous(master, table.get("zone_occupied", "panel A").ioa, True)


def test_a_client_outside_the_allowed_addresses_is_refused(station, masters) -> None:
    out, _ = station(allowed_clients=("10.9.9.0/24",))
    master = masters(out.settings.port)
    # refused at once, and again at each of the master's retries; never served
    wait_until(lambda: out.figures()["refused"] >= 2, "the refusals")
    assert not master.messages() and not master.answers("I-Format")
    assert out.figures()["active_connections"] == 0


def test_the_frame_loop_never_waits_and_drops_are_counted(station) -> None:
    out, _ = station(queue_size=5)
    with out._state.lock:  # the outstation's thread held up inside a refresh
        out.write(_frame(1.0, [_zone(1.0, "enter")]))
        wait_until(lambda: out.queued() == 0, "the first change taken")
        for k in range(20):
            out.write(_frame(2.0 + k, [_zone(2.0 + k, "exit" if k % 2 else "enter")]))
        assert out.queued() == 5 and out.dropped == 15
    wait_until(lambda: out.queued() == 0, "the queue drained")
    assert out.figures()["dropped"] == 15


def test_commands_acknowledge_a_zones_and_a_prioritys_incidents(station, masters) -> None:
    out, table = station()
    book = IncidentBook()
    acked: list[tuple[int, str]] = []

    def acknowledge(incident: int, by: str):
        acked.append((incident, by))
        out.write_changes(book.acknowledge(incident, by, 7.0))

    out.acknowledger = acknowledge
    master = masters(out.settings.port)
    master.wait_open()
    up = book.update([_zone(5.0, "enter"), _camera(5.0, "camera_down", "cam02")], 5.0)
    out.write_changes(up.changes)
    unacked = table.get("unacknowledged").ioa
    _spontaneous(master, unacked, 2)
    zone_incident = next(c.incident for c in up.changes if c.incident.zone == "panel A")
    assert master.command(table.get("ack_zone", "panel A").ioa, True)
    assert acked[0][0] == zone_incident.id and acked[0][1].startswith("iec104 master")
    _spontaneous(master, unacked, 1)
    assert not master.command(table.get("ack_zone", "panel A").ioa, False)  # OFF: refused
    camera = next(c.incident for c in up.changes if c.incident.camera == "cam02")
    assert master.command(table.get("ack_priority", str(camera.priority)).ioa, True)
    _spontaneous(master, unacked, 0)
    assert [i for i, _ in acked] == [zone_incident.id, camera.id]


def test_without_commands_a_command_is_refused(station, masters) -> None:
    out, table = station(commands=False)
    master = masters(out.settings.port)
    master.wait_open()
    assert not any(p.command for p in table)
    master.command(10_019, True)  # where zone 1's acknowledge would be
    wait_until(
        lambda: master.answers("C_SC_NA_1 | ACTIVATION_CON | NEGATIVE"), "a negative confirmation"
    )
    # the unknown address's answer is a message of its own, perhaps not here yet
    wait_until(
        lambda: master.answers("C_SC_NA_1 | UNKNOWN_INFORMATION_OBJECT_ADDRESS"),
        "the unknown address's answer",
    )
    assert out.figures()["commands"] == 0


def test_a_clock_sync_is_confirmed_and_never_applied(station, masters) -> None:
    out, _ = station()
    master = masters(out.settings.port)
    master.wait_open()
    before = time.time()
    # c104's call can report False when the confirmation comes after its own timeout (a
    # loaded machine); the contract is the outstation's positive confirmation, seen on the wire
    master.conn.clock_sync(common_address=CA)
    wait_until(
        lambda: master.answers("C_CS_NA_1 | ACTIVATION_CON | POSITIVE"), "the sync confirmed"
    )
    wait_until(lambda: out.figures()["clock_syncs"] >= 1, "the sync counted")
    assert abs(out.figures()["clock_offset_s"]) < 5.0
    assert not master.answers("C_CS_NA_1 | ACTIVATION_CON | NEGATIVE")
    assert time.time() >= before  # the machine's clock was not set back


def test_a_port_taken_is_a_clear_error(station) -> None:
    from stereopose.errors import StereoposeError

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        with pytest.raises(StereoposeError, match="cannot listen"):
            station(port=s.getsockname()[1])


# -- the served demo --------------------------------------------------------------------------


def _wall_events(db: Path) -> list[tuple[str, str, float]]:
    """(zone, type, wall time) of the zone events in the log."""
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return con.execute(
            "SELECT e.zone, e.type, e.t + r.wall_start FROM events e JOIN runs r "
            "ON e.run = r.id WHERE e.zone != '' ORDER BY e.id"
        ).fetchall()
    except sqlite3.OperationalError:
        return []
    finally:
        con.close()


@pytest.mark.realdata
@pytest.mark.slow
def test_the_served_demos_zone_entry_reaches_the_master_time_tagged(tmp_path: Path) -> None:
    import subprocess
    import sys

    from stereopose.pipeline.demo import write_serve_demo_config

    port = free_port()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320)
    config.write_text(
        config.read_text() + f"\n[iec104]\nenabled = true\nport = {port}\ncommon_address = {CA}\n"
    )
    _, table = points_of(config)
    busbar = table.get("zone_occupied", "overhead_busbar").ioa
    log = tmp_path / "serve.log"
    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    master = None
    try:
        wait_until(
            lambda: listening(port) or proc.poll() is not None,
            "the outstation listening",
            timeout_s=60,
            poll_s=0.05,
        )
        master = Master(port)
        master.wait_interrogated(len(table.monitored), timeout_s=60)
        assert set(master.interrogated()) == {p.ioa for p in table.monitored}

        def entered() -> bool:
            return any(g.value is True for g in master.messages(busbar, "SPONTANEOUS"))

        wait_until(entered, "the busbar's entry at the master", timeout_s=60, poll_s=0.1)
        g = next(g for g in master.messages(busbar, "SPONTANEOUS") if g.value is True)
        db = tmp_path / "data" / "events.sqlite"

        def entries() -> list[float]:
            return [w for z, t, w in _wall_events(db) if (z, t) == ("overhead_busbar", "enter")]

        # the time tag is the event's own wall time (CP56Time2a: milliseconds); the entry the
        # master saw first may be a later one than the log's first (one made while the master
        # was still being interrogated is not sent spontaneously)
        tag = g.recorded_at.replace(tzinfo=dt.UTC).timestamp()
        wait_until(
            lambda: any(abs(tag - w) < 1.0 for w in entries()), "the master's entry in the log"
        )
        wall = min(entries(), key=lambda w: abs(tag - w))
        assert abs(tag - wall) < 0.0015, (tag, wall, entries())
        latency = g.at - wall
        print(json.dumps({"iec104_entry_latency_s": round(latency, 3)}))
    finally:
        if master is not None:
            master.close()
        proc.terminate()
        try:
            rc = proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"serve did not stop within 40 s:\n{log.read_text()}")
    assert rc == 0, log.read_text()
    assert "Traceback" not in log.read_text()
