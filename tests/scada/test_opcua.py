"""The OPC UA server with asyncua's own Client over real sockets and Basic256Sha256: a login
browses the site's zones, cameras and counts and sees them change; an incident of the real
incident step appears as an OffNormalAlarm condition event with its severity; Acknowledge
acknowledges it as the OPC UA user (refused for a viewer, an unknown event, a stale login);
an ack made elsewhere reaches the condition; ConditionRefresh replays what is retained;
anonymous, wrong-password and unsecured connections are refused; a malformed [opcua] or a bad
key file is a ConfigError naming the file; the generated certificate is private and kept."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

asyncua = pytest.importorskip("asyncua")

from argon2 import PasswordHasher  # noqa: E402
from asyncua import Client, ua  # noqa: E402
from asyncua.crypto.cert_gen import (  # noqa: E402
    dump_private_key_as_pem,
    generate_private_key,
    generate_self_signed_app_certificate,
)
from cryptography import x509  # noqa: E402
from cryptography.hazmat.primitives.serialization import Encoding  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID  # noqa: E402

from brokers import free_port  # noqa: E402
from stereopose.alarms import IncidentBook  # noqa: E402
from stereopose.config import load_config  # noqa: E402
from stereopose.errors import ConfigError  # noqa: E402
from stereopose.io.sinks import FrameResult  # noqa: E402
from stereopose.pipeline.incidents import IncidentStep  # noqa: E402
from stereopose.pipeline.step_rules import step_chain  # noqa: E402
from stereopose.scada.opcua import SPARE_SOCKETS, CameraNode, OpcuaServer, ZoneNode  # noqa: E402
from stereopose.scada.opcua_settings import (  # noqa: E402
    OpcuaSettings,
    application_certificate,
    opcua_settings,
)
from stereopose.site.desk import IncidentDesk  # noqa: E402
from stereopose.types import Event, People3D  # noqa: E402
from stereopose.web.users import UserStore  # noqa: E402

PASSWORDS = {"vera": "viewer-pass-1", "otto": "operator-pass-1", "ada": "admin-pass-1"}
ROLES = {"vera": "viewer", "otto": "operator", "ada": "admin"}
WALL_START = 1_780_000_000.0
CLIENT_URI = "urn:stereopose:test-client"
ACK = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)
REFRESH = ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh)
ZONES = [
    ZoneNode("overhead_busbar", "energized", ("cam01", "cam02"), powered=True),
    ZoneNode("walkway", "work_area", ()),
]
CAMERAS = [CameraNode("cam01"), CameraNode("cam02")]
TIMEOUT_S = 20.0


def client_pair(folder: Path, uri: str = CLIENT_URI) -> tuple[Path, Path]:
    """A client application certificate (DER) and its key (PEM) made in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    key = generate_private_key()
    cert = generate_self_signed_app_certificate(
        key,
        uri,
        {},
        [x509.UniformResourceIdentifier(uri), x509.DNSName("localhost")],
        [ExtendedKeyUsageOID.CLIENT_AUTH],
    )
    (folder / "client.der").write_bytes(cert.public_bytes(Encoding.DER))
    (folder / "client.pem").write_bytes(dump_private_key_as_pem(key))
    return folder / "client.der", folder / "client.pem"


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    return client_pair(tmp_path_factory.mktemp("client"))


def user_store(folder: Path) -> UserStore:
    """The three roles' users, hashed with a small argon2 cost (the same code path)."""
    store = UserStore(
        folder / "users.json", PasswordHasher(time_cost=1, memory_cost=8 * 1024, parallelism=1)
    )
    for name, role in ROLES.items():
        store.add(name, PASSWORDS[name], role)
    return store


def settings(folder: Path, **kw) -> OpcuaSettings:
    base = OpcuaSettings(
        host="127.0.0.1",
        port=free_port(),
        path="/stereopose",
        site="testsite",
        certificate=None,
        key=None,
        cert_dir=folder / "opcua",
        trusted_clients=None,
        security=("Basic256Sha256_SignAndEncrypt",),
        allow_anonymous=False,
        max_connections=8,
        queue_size=1000,
    )
    return replace(base, **kw)


class Script:
    """The step's events, given in turn (the role ServeEvents plays in serve)."""

    def __init__(self) -> None:
        self.next: list[Event] = []

    def update(self, people3d) -> list[Event]:
        out, self.next = self.next, []
        return out


def people(n: int, frame: int) -> People3D:
    return People3D(
        frame=frame,
        joints=np.zeros((n, 17, 3)),
        conf=np.ones((n, 17)),
        ids=np.arange(n),
        reprojection_px=np.zeros((n, 17)),
        views=np.full((n, 17), 2),
        detections=np.zeros((n, 2), dtype=int),
    )


@dataclass
class Site:
    """A started server fed by a real IncidentStep, as serve wires them."""

    server: OpcuaServer
    step: IncidentStep
    script: Script
    store: UserStore
    db: object = None  # the event log (io.sinks.SqliteSink) or None
    t: float = 0.0
    frame: int = 0

    @property
    def url(self) -> str:
        return self.server.settings.endpoint

    def run(self, events=(), n_people: int = 0) -> list[Event]:
        """One step of the frame loop: its events through the book, then the sink."""
        self.frame += 1
        self.t = max(self.t + 0.1, *(e.t for e in events)) if events else self.t + 0.1
        self.script.next = list(events)
        p = people(n_people, self.frame)
        out, _ = self.step.step(self.t, self.frame, p)
        if self.db is not None:  # the step's incident records are stored with its events
            self.db.write_events(out)
        self.server.write(FrameResult(self.frame, self.t, {}, p, out))
        return out


@contextlib.contextmanager
def running(
    folder: Path, store: UserStore | None = None, db=None, limiter=None, **kw
) -> Iterator[Site]:
    """A started server; db: the event log the step stores its incidents in, as serve's;
    limiter: the console's login limiter, shared."""
    store = store or user_store(folder)
    desk = IncidentDesk()  # as serve: the server made with the desk, the step attached later
    server = OpcuaServer(
        settings(folder, **kw), ZONES, CAMERAS, store, incidents=desk, limiter=limiter
    )
    script = Script()
    site = Site(server, None, script, store, db)  # type: ignore[arg-type]
    site.step = IncidentStep(
        IncidentBook(),
        step_chain(script),
        outputs=[*([db.write_changes] if db is not None else []), server.write_changes],
        clock=lambda: site.t,
        wall_start=WALL_START,
    )
    server.start()
    desk.attach(site.step)
    server.show_book()
    try:
        yield site
    finally:
        server.close()


def enter(
    t: float,
    zone: str = "overhead_busbar",
    person: int = 7,
    type_: str = "enter",
    kind: str = "energized",
) -> Event:
    return Event(t=t, frame=int(t * 10), person=person, zone=zone, kind=kind, type=type_, onset_t=t)


async def connect(
    url: str,
    pair: tuple[Path, Path],
    user: str | None = "otto",
    password: str | None = None,
    mode: str = "SignAndEncrypt",
) -> Client:
    c = Client(url, timeout=10)
    c.application_uri = CLIENT_URI
    await c.set_security_string(f"Basic256Sha256,{mode},{pair[0]},{pair[1]}")
    if user is not None:
        c.set_user(user)
        c.set_password(password if password is not None else PASSWORDS[user])
    await c.connect()
    return c


async def until(check, what: str, timeout_s: float = TIMEOUT_S):
    """Await `check()` (a coroutine function) until it gives a true value, with a deadline."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while True:
        got = await check()
        if got:
            return got
        if loop.time() > deadline:
            pytest.fail(f"still waiting for {what} after {timeout_s} s")
        await asyncio.sleep(0.02)


class Events:
    """An event subscription on the Server object (where A&C clients subscribe)."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue = asyncio.Queue()

    def event_notification(self, event) -> None:
        self.queue.put_nowait(event)

    async def subscribe(self, client: Client):
        sub = await client.create_subscription(20, self)
        await sub.subscribe_events(client.nodes.server, ua.ObjectIds.OffNormalAlarmType)
        return sub

    async def next(self, match=lambda e: True, what: str = "an alarm event"):
        loop = asyncio.get_running_loop()
        deadline = loop.time() + TIMEOUT_S
        while True:
            left = deadline - loop.time()
            if left <= 0:
                pytest.fail(f"no {what} within {TIMEOUT_S} s")
            try:
                e = await asyncio.wait_for(self.queue.get(), left)
            except TimeoutError:
                continue
            if match(e):
                return e


def acked(e) -> bool:
    return getattr(e, "AckedState/Id")


def active(e) -> bool:
    return getattr(e, "ActiveState/Id")


async def in_thread(fn, *args):
    """The frame loop's side runs on another thread than the client's loop, as in serve."""
    return await asyncio.get_running_loop().run_in_executor(None, fn, *args)


async def site_node(client: Client):
    idx = await client.get_namespace_index("urn:stereopose:testsite")
    return idx, await client.nodes.objects.get_child([f"{idx}:testsite"])


# -- the address space ------------------------------------------------------------------------


def test_a_login_browses_the_site_and_sees_its_values_change(tmp_path, pair):
    async def body(site: Site) -> None:
        client = await connect(site.url, pair, "vera")
        try:
            idx, root = await site_node(client)
            names = {(await n.read_browse_name()).Name for n in await root.get_children()}
            assert names == {
                "Running",
                "Status",
                "People",
                "ActiveIncidents",
                "Zones",
                "UnacknowledgedIncidents",
                "Cameras",
                "Incidents",
                "Tickets",
            }
            zones = await root.get_child([f"{idx}:Zones"])
            assert {(await n.read_browse_name()).Name for n in await zones.get_children()} == {
                "overhead_busbar",
                "walkway",
            }
            busbar = client.get_node(ua.NodeId("zone/overhead_busbar", idx))
            kind = await busbar.get_child([f"{idx}:Kind"])
            assert await kind.read_value() == "energized"
            occupied = client.get_node(ua.NodeId("zone/overhead_busbar/Occupied", idx))
            up = client.get_node(ua.NodeId("camera/cam02/Up", idx))
            count = client.get_node(ua.NodeId("site/People", idx))
            assert await occupied.read_value() is False and await up.read_value() is True
            assert (await occupied.read_data_value(raise_on_bad_status=False)).StatusCode.is_good()
            # a zone no camera sees is never certain
            walkway = client.get_node(ua.NodeId("zone/walkway/Occupied", idx))
            assert await _uncertain(walkway)
            assert await client.get_node(ua.NodeId("site/Running", idx)).read_value() is True

            await in_thread(site.run, [enter(1.0)], 2)
            await until(occupied.read_value, "the busbar occupied")
            dv = await occupied.read_data_value(raise_on_bad_status=False)
            assert dv.SourceTimestamp.timestamp() == pytest.approx(WALL_START + 1.0, abs=1e-3)
            await until(lambda: _equals(count, 2), "2 people on site")
            alarm = client.get_node(ua.NodeId("zone/overhead_busbar/Alarm", idx))
            await until(alarm.read_value, "the busbar's alarm")

            down = Event(
                t=2.0,
                frame=20,
                person=-1,
                zone="",
                kind="camera",
                type="camera_down",
                onset_t=2.0,
                camera="cam02",
            )
            await in_thread(site.run, [down])
            await until(lambda: _equals(up, False), "cam02 down")
            dv = await until(lambda: _uncertain(occupied), "the busbar uncertain")
            assert dv.Value.Value is True  # the last usable value kept
            await in_thread(site.run, [enter(3.0, type_="exit")])
            await until(lambda: _equals(occupied, False), "the busbar empty")
            # its state from its breakers: unknown (uncertain) until known, then dead
            power = client.get_node(ua.NodeId("zone/overhead_busbar/Power", idx))
            assert await _uncertain(power) and await _equals(power, "unknown")
            dead = Event(
                t=4.0,
                frame=40,
                person=-1,
                zone="overhead_busbar",
                kind="energized",
                type="zone_dead",
                onset_t=4.0,
                source="iec104 rtu ioa 1",
            )
            await in_thread(site.run, [dead])
            await until(lambda: _equals(power, "dead"), "the busbar dead")
            dv = await power.read_data_value(raise_on_bad_status=False)
            assert dv.StatusCode.is_good()
        finally:
            await client.disconnect()

    with running(tmp_path) as site:
        asyncio.run(body(site))


def ticket_event(t: float, type_: str, ticket: str = "OT-7", step: str | None = None) -> Event:
    return Event(
        t=t,
        frame=int(t * 10),
        person=-1 if type_.startswith("ticket_") else 7,
        zone="",
        kind="ticket",
        type=type_,
        onset_t=t,
        ticket=ticket,
        step=step,
    )


def test_tickets_are_slots_beside_the_incidents(tmp_path, pair):
    """Each active ticket in the lowest free slot (as IEC 104's), its steps done, its deviation
    while an incident of it is not closed, the slot free again when it ends."""

    async def body(site: Site) -> None:
        client = await connect(site.url, pair, "vera")
        try:
            idx, root = await site_node(client)
            tickets = await root.get_child([f"{idx}:Tickets"])
            slots = {(await n.read_browse_name()).Name for n in await tickets.get_children()}
            assert slots == {f"Slot{k}" for k in range(1, 9)}

            def node(k: int, name: str):
                return client.get_node(ua.NodeId(f"ticket/{k}/{name}", idx))

            assert await _equals(node(1, "Ticket"), "") and await _equals(node(1, "Active"), False)
            await in_thread(site.run, [ticket_event(1.0, "ticket_started", "OT-7")])
            await in_thread(site.run, [ticket_event(1.1, "ticket_started", "OT-8")])
            await until(lambda: _equals(node(2, "Ticket"), "OT-8"), "OT-8 in slot 2")
            assert await _equals(node(1, "Ticket"), "OT-7") and await _equals(
                node(1, "Active"), True
            )
            await in_thread(site.run, [ticket_event(2.0, "step_done", "OT-7", "open QS1")])
            await until(lambda: _equals(node(1, "StepsDone"), 1), "OT-7's step done")
            wrong = ticket_event(3.0, "step_out_of_order", "OT-7", "test dead")
            out = await in_thread(site.run, [wrong])
            assert out[0].incident is not None  # a deviation: an incident of the ticket
            await until(lambda: _equals(node(1, "Deviation"), True), "OT-7 deviating")
            assert await _equals(node(2, "Deviation"), False)
            await in_thread(site.run, [ticket_event(4.0, "ticket_completed", "OT-7")])
            await until(lambda: _equals(node(1, "Ticket"), ""), "slot 1 free again")
            assert await _equals(node(1, "Active"), False)
            assert await _equals(node(1, "StepsDone"), 0)
            assert await _equals(node(2, "Active"), True)
        finally:
            await client.disconnect()

    with running(tmp_path) as site:
        asyncio.run(body(site))


async def _equals(node, value) -> bool:
    dv = await node.read_data_value(raise_on_bad_status=False)  # uncertain values too
    return dv.Value.Value == value


async def _uncertain(node):
    dv = await node.read_data_value(raise_on_bad_status=False)
    return dv if dv.StatusCode.is_uncertain() else None


# -- alarms and acknowledgements ------------------------------------------------------------


def test_an_incident_is_an_alarm_condition_acknowledged_as_the_opcua_user(tmp_path, pair):
    async def body(site: Site) -> None:
        client = await connect(site.url, pair, "otto")
        events = Events()
        try:
            await events.subscribe(client)
            out = await in_thread(site.run, [enter(1.0)])
            incident = out[0].incident
            e = await events.next()
            assert e.EventType == ua.NodeId(ua.ObjectIds.OffNormalAlarmType)
            assert e.Severity == 900  # priority 1: a person inside an energized zone
            assert "person 7" in e.Message.Text and "overhead_busbar" in e.Message.Text
            assert e.Message.Text.startswith("critical")
            assert active(e) and not acked(e) and e.Retain is True
            assert e.SourceName == "overhead_busbar"
            assert e.Time.timestamp() == pytest.approx(WALL_START + 1.0, abs=1e-3)
            assert e.NodeId.Identifier == f"incident/{incident}"
            idx, _ = await site_node(client)
            unacked = client.get_node(ua.NodeId("site/UnacknowledgedIncidents", idx))
            await until(lambda: _equals(unacked, 1), "1 incident unacknowledged")

            cond = client.get_node(e.NodeId)
            await cond.call_method(
                ACK,
                ua.Variant(e.EventId, ua.VariantType.ByteString),
                ua.LocalizedText("seen on the SCADA"),
            )
            rec = site.step.book.get(incident)
            assert rec.state == "acknowledged" and rec.acked_by == "otto"
            e2 = await events.next(acked, "the condition acknowledged")
            assert e2.NodeId == e.NodeId and active(e2) and e2.Retain is True
            assert e2.ClientUserId == "otto"
            await until(lambda: _equals(unacked, 0), "none unacknowledged")
            with pytest.raises(ua.UaStatusCodeError) as err:  # twice: already acknowledged
                await cond.call_method(
                    ACK, ua.Variant(e2.EventId, ua.VariantType.ByteString), ua.LocalizedText("")
                )
            assert err.value.code == ua.StatusCodes.BadConditionBranchAlreadyAcked
            # the change reaches the other outputs with the next step, by the same user
            await in_thread(site.run)
            await in_thread(site.run, [enter(2.0, type_="exit")])
            e3 = await events.next(lambda ev: not active(ev), "the condition closed")
            assert e3.Retain is False and acked(e3)
            await until(lambda: _gone(client, e.NodeId), "the closed condition's node removed")
        finally:
            await client.disconnect()

    with running(tmp_path) as site:
        asyncio.run(body(site))
        assert site.server.figures()["acknowledged"] == 1


async def _gone(client: Client, nodeid) -> bool:
    try:
        await client.get_node(nodeid).read_browse_name()
    except ua.UaStatusCodeError:
        return True
    return False


def test_acknowledge_refused_for_a_viewer_an_unknown_event_and_a_stale_login(tmp_path, pair):
    async def body(site: Site) -> None:
        viewer, operator = await connect(site.url, pair, "vera"), await connect(site.url, pair)
        events = Events()
        try:
            await events.subscribe(viewer)
            out = await in_thread(site.run, [enter(1.0)])
            e = await events.next()
            args = (ua.Variant(e.EventId, ua.VariantType.ByteString), ua.LocalizedText("x"))
            with pytest.raises(ua.UaStatusCodeError) as err:
                await viewer.get_node(e.NodeId).call_method(ACK, *args)
            assert err.value.code == ua.StatusCodes.BadUserAccessDenied
            with pytest.raises(ua.UaStatusCodeError) as err:
                await operator.get_node(e.NodeId).call_method(
                    ACK,
                    ua.Variant(b"not an event", ua.VariantType.ByteString),
                    ua.LocalizedText("x"),
                )
            assert err.value.code == ua.StatusCodes.BadEventIdUnknown
            with pytest.raises(ua.UaStatusCodeError) as err:  # a viewer writes nothing
                idx, _ = await site_node(viewer)
                await viewer.get_node(ua.NodeId("site/People", idx)).write_value(
                    ua.Variant(5, ua.VariantType.UInt32)
                )
            assert err.value.code == ua.StatusCodes.BadUserAccessDenied
            # otto is made a viewer after logging in: his session may no longer acknowledge
            await in_thread(_demote, site.store, "otto")
            with pytest.raises(ua.UaStatusCodeError) as err:
                await operator.get_node(e.NodeId).call_method(ACK, *args)
            assert err.value.code == ua.StatusCodes.BadUserAccessDenied
            assert site.step.book.get(out[0].incident).state == "active"
            admin = await connect(site.url, pair, "ada")
            try:
                await admin.get_node(e.NodeId).call_method(ACK, *args)
            finally:
                await admin.disconnect()
            assert site.step.book.get(out[0].incident).acked_by == "ada"
        finally:
            await viewer.disconnect()
            await operator.disconnect()

    with running(tmp_path) as site:
        asyncio.run(body(site))
        assert site.server.figures()["acknowledge_refused"] == 3


def _demote(store: UserStore, name: str) -> None:
    store.remove(name)
    store.add(name, PASSWORDS[name], "viewer")


def test_an_ack_elsewhere_reaches_the_condition_and_refresh_replays_the_retained(tmp_path, pair):
    async def body(site: Site) -> None:
        # raised before any client: a client learns of it by ConditionRefresh
        busbar = (await in_thread(site.run, [enter(1.0)]))[0].incident
        walk = (
            await in_thread(site.run, [enter(1.5, "walkway", 8, "left_work_area", "work_area")])
        )[0].incident
        client = await connect(site.url, pair, "vera")
        events = Events()
        try:
            sub = await events.subscribe(client)
            ctype = client.get_node(ua.NodeId(ua.ObjectIds.ConditionType))
            await ctype.call_method(REFRESH, ua.Variant(sub.subscription_id, ua.VariantType.UInt32))
            seen = {}
            while len(seen) < 2:
                e = await events.next()
                seen[e.NodeId.Identifier] = e
            assert seen[f"incident/{busbar}"].Severity == 900
            assert seen[f"incident/{walk}"].Severity == 500  # medium: left the work area
            assert "left work area walkway" in seen[f"incident/{walk}"].Message.Text
            # the console acknowledges: the condition follows with the next step
            await in_thread(site.step.acknowledge, busbar, "console-op")
            await in_thread(site.run)  # the loop's next step (its heartbeat)
            e = await events.next(acked, "the console's ack")
            assert e.NodeId.Identifier == f"incident/{busbar}" and e.ClientUserId == "console-op"
        finally:
            await client.disconnect()

    with running(tmp_path) as site:
        asyncio.run(body(site))


def test_acks_both_ways_between_opcua_and_the_console(tmp_path, pair):
    """Served as serve does: the console's users and incident API over the same step."""
    from consoled import console_server

    async def body(site: Site, served) -> None:
        client = await connect(site.url, pair, "otto")
        events = Events()
        try:
            await events.subscribe(client)
            one = (await in_thread(site.run, [enter(1.0)]))[0].incident
            two = (await in_thread(site.run, [enter(1.2, "walkway", 8)]))[0].incident
            first = {}
            while len(first) < 2:
                e = await events.next()
                first[e.NodeId.Identifier] = e
            e = first[f"incident/{one}"]
            await client.get_node(e.NodeId).call_method(
                ACK, ua.Variant(e.EventId, ua.VariantType.ByteString), ua.LocalizedText("")
            )
            await in_thread(site.run)  # stored with the next step
            viewer = served.client("vera")
            got = {i["id"]: i for i in viewer.get("/api/incidents").json()["incidents"]}
            assert got[one]["acked_by"] == "otto" and got[one]["state"] == "acknowledged"
            # the console's operator acknowledges the other: the condition follows
            r = served.client("ada").post(f"/api/incidents/{two}/ack")
            assert r.status_code == 200, r.text
            await in_thread(site.run)
            e = await events.next(
                lambda ev: ev.NodeId.Identifier == f"incident/{two}" and acked(ev),
                "the console's ack",
            )
            assert e.ClientUserId == "ada"
        finally:
            await client.disconnect()

    with (
        console_server(tmp_path / "out") as served,
        running(tmp_path, served.console.users, db=served.db) as site,
    ):
        served.server.app.state.incidents.attach(site.step)
        asyncio.run(body(site, served))


def test_changes_over_the_bound_are_dropped_counted_and_read_again_from_the_book(tmp_path, pair):
    async def body(site: Site) -> None:
        client = await connect(site.url, pair, "vera")
        try:
            # one step, five incidents: more changes than the queue holds
            out = await in_thread(site.run, [enter(1.0, person=p) for p in range(5)])
            assert site.server.dropped >= 3
            idx, root = await site_node(client)
            folder = await root.get_child([f"{idx}:Incidents"])

            async def all_there():
                names = {(await n.read_browse_name()).Name for n in await folder.get_children()}
                return names == {f"Incident {e.incident}" for e in out}

            await until(all_there, "every incident's condition, read again from the book")
            unacked = client.get_node(ua.NodeId("site/UnacknowledgedIncidents", idx))
            await until(lambda: _equals(unacked, 5), "5 unacknowledged")
        finally:
            await client.disconnect()

    with running(tmp_path, queue_size=2) as site:
        asyncio.run(body(site))
        assert site.server.figures()["dropped"] == site.server.dropped


# -- logins and security --------------------------------------------------------------------


def test_anonymous_wrong_password_and_unsecured_connections_are_refused(tmp_path, pair, caplog):
    async def body(site: Site) -> None:
        denied = ua.StatusCodes.BadUserAccessDenied
        for user, password, code in (
            (None, None, ua.StatusCodes.BadIdentityTokenRejected),
            ("otto", "not-his-password", denied),
            ("nobody", "whatever-pass-1", denied),
        ):
            with pytest.raises(ua.UaStatusCodeError) as err:
                c = await connect(site.url, pair, user, password)
                await c.disconnect()
            assert err.value.code == code, (user, err.value)
        with pytest.raises(Exception):  # noqa: B017 (no such endpoint: the client says so)
            c = await connect(site.url, pair, mode="Sign")
            await c.disconnect()
        plain = Client(site.url, timeout=10)  # no security at all: no endpoint offers it
        with pytest.raises(Exception):  # noqa: B017
            await plain.connect()
            await plain.disconnect()
        # a well-behaved client still gets in
        ok = await connect(site.url, pair)
        await ok.disconnect()

    with caplog.at_level(logging.WARNING), running(tmp_path) as site:
        asyncio.run(body(site))
    assert "login refused for 'otto'" in caplog.text
    assert "not-his-password" not in caplog.text  # never a password in the log


def test_password_guesses_are_limited_as_the_consoles_and_with_its_limiter(tmp_path, pair):
    from stereopose.login_limit import MAX_FAILURES, LoginLimiter

    limiter = LoginLimiter()

    async def body(site: Site) -> None:
        denied = ua.StatusCodes.BadUserAccessDenied

        async def refused(user: str, password: str) -> None:
            with pytest.raises(ua.UaStatusCodeError) as err:
                c = await connect(site.url, pair, user, password)
                await c.disconnect()
            assert err.value.code == denied

        for k in range(MAX_FAILURES):  # each checked, and failing
            await refused("otto", f"guess-{k}-wrong")
        assert limiter.checked == MAX_FAILURES and site.server.figures()["logins_limited"] == 0
        # past the address's failures: refused unchecked, even the right password
        await refused("otto", PASSWORDS["otto"])
        await refused("vera", PASSWORDS["vera"])
        assert limiter.checked == MAX_FAILURES and limiter.refused == 2
        assert site.server.figures()["logins_limited"] == 2

    with running(tmp_path, limiter=limiter) as site:
        asyncio.run(body(site))


def test_idle_sockets_cannot_lock_logins_out(tmp_path, pair):
    import socket

    async def body(site: Site) -> None:
        port = site.server.settings.port
        idle = []
        for _ in range(16):  # more than its places: the rest refused at once
            with contextlib.suppress(OSError):
                idle.append(socket.create_connection(("127.0.0.1", port), timeout=10))

        async def places_freed() -> bool:
            return site.server.figures()["idle_closed"] >= 2

        try:
            await until(places_freed, "the oldest idle sockets closed")
            for _ in range(8):  # the idle sockets come back as fast as places free
                with contextlib.suppress(OSError):
                    idle.append(socket.create_connection(("127.0.0.1", port), timeout=10))
            # a client still gets in (as a client does, it retries a connection refused)
            deadline = time.monotonic() + 20
            while True:
                try:
                    client = await connect(site.url, pair, "vera")
                    break
                except (OSError, TimeoutError, ua.UaError):
                    if time.monotonic() > deadline:
                        raise
                    await asyncio.sleep(0.2)
            idx, _ = await site_node(client)
            assert await client.get_node(ua.NodeId("site/Running", idx)).read_value() is True
            await client.disconnect()
        finally:
            for s in idle:
                s.close()

    with running(tmp_path) as site:
        asyncio.run(body(site))


@pytest.mark.slow  # the half-sent messages are closed by the 10 s activation bound
def test_garbage_and_a_crowd_of_connections_leave_a_client_served(tmp_path, pair):
    import socket

    async def body(site: Site) -> None:
        crowd = []
        for k in range(12):  # more than max_connections (8), each sending garbage
            s = socket.create_connection(("127.0.0.1", site.server.settings.port), timeout=10)
            with contextlib.suppress(OSError):  # refused ones may already be closed
                s.sendall(bytes(range(256)) * 4 if k % 2 else b"HEL\x00\xff\xff\xff\xff" * 64)
            crowd.append(s)

        async def all_closed() -> bool:  # the server drops each of them by itself
            for s in crowd:
                try:
                    s.settimeout(0.01)
                    if s.recv(65536):
                        return False  # an error answer first; the close comes after
                except TimeoutError:
                    return False
                except OSError:
                    pass
            return True

        await until(all_closed, "the garbage connections closed by the server")
        for s in crowd:
            s.close()
        client = await connect(site.url, pair, "vera")
        try:
            idx, _ = await site_node(client)
            assert await client.get_node(ua.NodeId("site/Running", idx)).read_value() is True
        finally:
            await client.disconnect()

    with running(tmp_path) as site:
        asyncio.run(body(site))


def test_anonymous_when_allowed_browses_but_never_acknowledges(tmp_path, pair):
    async def body(site: Site) -> None:
        anon = await connect(site.url, pair, None)
        events = Events()
        try:
            await events.subscribe(anon)
            await in_thread(site.run, [enter(1.0)])
            e = await events.next()
            with pytest.raises(ua.UaStatusCodeError) as err:
                await anon.get_node(e.NodeId).call_method(
                    ACK, ua.Variant(e.EventId, ua.VariantType.ByteString), ua.LocalizedText("")
                )
            assert err.value.code == ua.StatusCodes.BadUserAccessDenied
        finally:
            await anon.disconnect()

    with running(tmp_path, allow_anonymous=True) as site:
        asyncio.run(body(site))


def test_only_trusted_client_certificates_connect_when_a_folder_is_given(tmp_path, pair):
    trusted = tmp_path / "trusted"
    other = client_pair(tmp_path / "other", "urn:stereopose:other-client")
    trusted.mkdir()
    (trusted / "client.der").write_bytes(pair[0].read_bytes())

    async def body(site: Site) -> None:
        ok = await connect(site.url, pair)
        await ok.disconnect()
        c = Client(site.url, timeout=10)
        c.application_uri = "urn:stereopose:other-client"
        await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{other[0]},{other[1]}")
        c.set_user("otto")
        c.set_password(PASSWORDS["otto"])
        with pytest.raises(Exception):  # noqa: B017 (refused at CreateSession)
            await c.connect()
            await c.disconnect()

    with running(tmp_path, trusted_clients=trusted) as site:
        asyncio.run(body(site))


def test_the_generated_certificate_is_private_and_kept_across_starts(tmp_path, caplog):
    s = settings(tmp_path)
    with caplog.at_level(logging.INFO):
        first = application_certificate(s)
    key = tmp_path / "opcua" / "key.pem"
    assert first.generated and first.path == tmp_path / "opcua" / "certificate.der"
    assert os.stat(key).st_mode & 0o777 == 0o600
    assert first.thumbprint in caplog.text and "BEGIN" not in caplog.text
    assert first.application_uri.startswith("urn:stereopose:")
    assert application_certificate(s).thumbprint == first.thumbprint  # made once, then kept
    key.write_bytes(b"garbage")  # a broken pair is made again, with a warning
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        again = application_certificate(s)
    assert again.thumbprint != first.thumbprint and "cannot be used" in caplog.text
    assert os.stat(key).st_mode & 0o777 == 0o600


def test_a_port_taken_is_a_clear_error(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        taken = s.getsockname()[1]
        server = OpcuaServer(
            settings(tmp_path, port=taken),
            ZONES,
            CAMERAS,
            user_store(tmp_path),
            incidents=IncidentDesk(),
        )
        with pytest.raises(Exception, match=r"cannot (start|listen)"):
            server.start()


# -- configuration --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('port = "4840"', "opcua.port: expected an integer"),
        ("port = 0", "opcua.port"),
        ('host = "opc.example.org"', "opcua.host: expected an IP address"),
        ('security = ["None"]', "opcua.security[0]: expected one of"),
        ("security = []", "opcua.security: empty"),
        ('certificate = "server.der"', "opcua.certificate and opcua.key: give both"),
        ('path = "no/leading/slash"', "opcua.path"),
        ("allow_anonymous = 1", "opcua.allow_anonymous: expected true or false"),
        ("anonymous = true", "opcua: unknown key(s) anonymous"),
    ],
)
def test_a_malformed_opcua_section_is_an_error_naming_the_file(tmp_path, body, message):
    path = tmp_path / "service.toml"
    path.write_text(f"[opcua]\nenabled = true\n{body}\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_certificate_and_key_files_are_checked_before_any_work(tmp_path):
    from asyncua.crypto.cert_gen import generate_private_key as key_of

    cert, key = client_pair(tmp_path / "pki", "urn:stereopose:site")
    path = tmp_path / "service.toml"

    def check(cert_name: str, key_name: str) -> str:
        path.write_text(
            f'[opcua]\nenabled = true\ncertificate = "{cert_name}"\nkey = "{key_name}"\n'
        )
        with pytest.raises(ConfigError) as err:
            opcua_settings(path, load_config(path), tmp_path / "out")
        assert str(path) in str(err.value)
        return str(err.value)

    os.chmod(key, 0o644)
    assert "opcua.key" in check("pki/client.der", "pki/client.pem")
    assert "readable by every user" in check("pki/client.der", "pki/client.pem")
    os.chmod(key, 0o600)
    assert "cannot read" in check("pki/missing.der", "pki/client.pem")
    (tmp_path / "pki" / "junk.der").write_bytes(b"\x00garbage" * 10)
    assert "not a DER or PEM X.509 certificate" in check("pki/junk.der", "pki/client.pem")
    other = tmp_path / "pki" / "other.pem"
    other.write_bytes(dump_private_key_as_pem(key_of()))
    os.chmod(other, 0o600)
    assert "the key is not the certificate's" in check("pki/client.der", "pki/other.pem")
    path.write_text(
        '[opcua]\nenabled = true\ncertificate = "pki/client.der"\nkey = "pki/client.pem"\n'
    )
    got = opcua_settings(path, load_config(path), tmp_path / "out")
    assert got is not None and got.certificate == cert and got.key == key
    path.write_text("[opcua]\nport = 4841\n")  # not enabled: off
    assert opcua_settings(path, load_config(path), tmp_path / "out") is None


# -- the served demo --------------------------------------------------------------------------


@pytest.mark.realdata
@pytest.mark.slow
def test_the_served_demos_incident_is_acknowledged_over_opcua_and_the_console_shows_it(
    tmp_path, pair
):
    """`stereopose serve` of the real demo with [opcua]: a condition appears, the OPC UA user
    acknowledges it, /api/incidents shows the ack by that user."""
    import subprocess
    import sys

    import httpx

    from stereopose.pipeline.demo import write_serve_demo_config

    port, http_port = free_port(), free_port()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", http_port, imgsz=320)
    config.write_text(
        config.read_text() + f'\n[opcua]\nenabled = true\nport = {port}\nsite = "testsite"\n'
    )
    user_store(tmp_path / "data")  # the console's users, before the service starts
    log = tmp_path / "serve.log"
    url = f"opc.tcp://127.0.0.1:{port}/stereopose"

    async def body() -> int:
        client = await until(lambda: _try_connect(url, pair), "the OPC UA server", 90)
        events = Events()
        try:
            sub = await events.subscribe(client)
            ctype = client.get_node(ua.NodeId(ua.ObjectIds.ConditionType))
            await ctype.call_method(REFRESH, ua.Variant(sub.subscription_id, ua.VariantType.UInt32))
            e = await events.next(lambda ev: ev.Retain and not acked(ev), "a condition to ack")
            await client.get_node(e.NodeId).call_method(
                ACK, ua.Variant(e.EventId, ua.VariantType.ByteString), ua.LocalizedText("seen")
            )
            await events.next(lambda ev: ev.NodeId == e.NodeId and acked(ev), "its ack")
            return int(e.NodeId.Identifier.split("/")[1])
        finally:
            await client.disconnect()

    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    try:
        incident = asyncio.run(body())
        http = httpx.Client(base_url=f"http://127.0.0.1:{http_port}", timeout=30)
        r = http.post("/api/login", json={"username": "vera", "password": PASSWORDS["vera"]})
        assert r.status_code == 200, r.text

        def shown() -> bool:
            got = http.get("/api/incidents").json()["incidents"]
            return any(i["id"] == incident and i["acked_by"] == "otto" for i in got)

        from waiting import wait_until

        wait_until(shown, "the OPC UA ack in /api/incidents", timeout_s=30, poll_s=0.2)
    finally:
        proc.terminate()
        try:
            rc = proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"serve did not stop within 40 s:\n{log.read_text()}")
    text = log.read_text()
    assert rc == 0, text
    assert "Traceback" not in text and PASSWORDS["otto"] not in text


async def _try_connect(url: str, pair) -> Client | None:
    try:
        return await connect(url, pair, "otto")
    except (OSError, TimeoutError, ua.UaError):
        await asyncio.sleep(0.3)
        return None


def test_a_client_speaking_slowly_keeps_its_place_in_a_flood_of_idle_sockets(tmp_path, pair):
    async def body(site: Site) -> None:
        port = site.server.settings.port
        flood: list[asyncio.StreamWriter] = []
        stop = asyncio.Event()

        async def keep_flooding() -> None:  # idle sockets, as fast as places free, all along
            while not stop.is_set():
                with contextlib.suppress(OSError):
                    _, w = await asyncio.open_connection("127.0.0.1", port)
                    flood.append(w)
                await asyncio.sleep(0.02)

        async def places_freed() -> bool:
            return site.server.figures()["idle_closed"] >= 2

        flooding = asyncio.create_task(keep_flooding())
        c = Client(site.url, timeout=10)
        c.application_uri = CLIENT_URI
        await c.set_security_string(f"Basic256Sha256,SignAndEncrypt,{pair[0]},{pair[1]}")
        c.set_user("vera")
        c.set_password(PASSWORDS["vera"])
        try:
            await until(places_freed, "the oldest idle sockets closed")
            deadline = time.monotonic() + 20
            while True:  # a place, as a client gets one: it tries again when refused
                try:
                    await c.connect_socket()
                    await c.send_hello()
                    break
                except (OSError, TimeoutError, ua.UaError):
                    c.disconnect_socket()
                    if time.monotonic() > deadline:
                        raise
                    await asyncio.sleep(0.1)
            await c.open_secure_channel()
            closed = site.server.figures()["idle_closed"]
            places = site.server.settings.max_connections + SPARE_SOCKETS

            async def older_ones_gone() -> bool:  # slow to log in: a slow link, a slow client
                return site.server.figures()["idle_closed"] >= closed + places + 2

            # every socket older than it closed, and more: it was the oldest waiting one
            await until(older_ones_gone, "the idle sockets older than the client made way")
            await c._create_and_activate_session()  # its place kept: it goes on
            idx, _ = await site_node(c)
            assert await c.get_node(ua.NodeId("site/Running", idx)).read_value() is True
            await c.disconnect()
        finally:
            stop.set()
            await flooding
            for w in flood:
                w.close()

    with running(tmp_path) as site:
        asyncio.run(body(site))
