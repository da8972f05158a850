"""serve's OPC UA server: the site in an address space, each incident an alarm condition.

    server = OpcuaServer(settings, zones, cameras, users,   # scada.opcua_settings, UserStore
                         incidents=desk)  # site.desk.IncidentDesk: the book, once it runs
    server.start()                 # listening once it returns (a StereoposeError otherwise)
    server.write(frame)            # the frame loop: zone occupancy, cameras, people (a sink)
    server.write_changes(changes)  # an incident output (alarms.Change)
    server.show_book()             # the book runs: its open incidents shown (restored ones)
    server.close()

asyncua is asyncio: the server runs on its own thread with its own event loop. The frame loop
only enqueues: zone occupancy, camera states and the people count are kept as their latest
values (bounded by the site), incident changes in a queue of `queue_size` (the oldest dropped
and counted at the bound, after which the conditions are read again from the book). The
address space and the alarms are scada.opcua_space's.

Security: only signed endpoints ([opcua] security, Basic256Sha256 SignAndEncrypt by default)
with the application certificate of scada.opcua_settings; clients log in as the console's
users (scada.opcua_security: the same names and passwords as `<output>/users.json`),
anonymous clients only when allow_anonymous. Every login may browse, read and subscribe, and
call ConditionRefresh; none may write or change the address space; Acknowledge needs the role
operator or admin, checked again at each call (a user removed, demoted or given a new password
since the login is refused). An Acknowledge (OPC UA's method of the condition, with the event's
EventId) acknowledges the incident in the book as the session's user, as the console's ack
does; an ack made elsewhere (the console, the API) reaches the condition as the book's change.
Logins count against the console's limits on password guesses (per address, per account).

Connections: `max_connections` sessions, and SPARE_SOCKETS more sockets for clients still in
their handshake. A socket that has not activated a session within ACTIVATE_S is closed, and
while fewer than two places are free the oldest such socket (past opcua_security.MIN_IDLE_S,
a silent one before one that opened a secure channel) is closed at once: idle or
unauthenticated sockets cannot keep a client out, nor take the place of one logging in.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from asyncua import ua
from asyncua.common.connection import TransportLimits
from asyncua.crypto.permission_rules import User
from asyncua.server.server import Server
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes

from stereopose.alarms import UnknownIncidentError
from stereopose.alarms.book import DROPPED
from stereopose.alarms.incident import CLOSED, IncidentRecord
from stereopose.errors import StereoposeError
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.sinks.health import OutputHealth
from stereopose.scada.opcua_ack import IncidentSide, comment_of, may_acknowledge, refusal
from stereopose.scada.opcua_security import (
    LoginServer,
    Permissions,
    Users,
    caller,
    sweep_idle,
    trusted_clients,
)
from stereopose.scada.opcua_settings import OpcuaSettings, application_certificate
from stereopose.scada.opcua_space import CameraNode, SiteSpace, ZoneNode
from stereopose.scada.ticket_slots import TicketSlots

if TYPE_CHECKING:
    from stereopose.login_limit import LoginLimiter
    from stereopose.web.users import UserStore

__all__ = ["CameraNode", "OpcuaServer", "ZoneNode"]

logger = logging.getLogger(__name__)

START_TIMEOUT_S = 60.0  # the standard address space takes seconds to load on a loaded machine
STOP_TIMEOUT_S = 10.0
STATUS_EVERY_S = 2.0  # the health status polled this often
MAX_MESSAGE = 4 * 1024 * 1024  # bytes of one request at most
SPARE_SOCKETS = 4  # sockets beyond max_connections, for handshakes
ACTIVATE_S = 5.0  # a socket with no activated session is closed after this long
# asyncua annotates a node id's number as its own Int32; it takes an int
_ACK = ua.NodeId(ObjectIds.AcknowledgeableConditionType_Acknowledge)  # pyright: ignore[reportArgumentType]


class OpcuaServer(ClosesOnce):
    """See the module. zones, cameras: what the address space shows; users: the console's
    users (web.users.UserStore: verify(name, password) and get(name) give a user with
    name, role and stamp); incidents: the incident book's desk (scada.opcua_ack.IncidentSide,
    site.desk.IncidentDesk: the book once the frame loop runs it, its wall_start the wall
    times' origin); status(): the service's health status (ok / degraded / down),
    polled; limiter: the console's login limiter (stereopose.login_limit), so that guesses here
    and there count together (None: one of its own)."""

    stage = "write"

    def __init__(
        self,
        settings: OpcuaSettings,
        zones: Sequence[ZoneNode],
        cameras: Sequence[CameraNode],
        users: UserStore,
        *,
        incidents: IncidentSide,
        status: Callable[[], str] | None = None,
        limiter: LoginLimiter | None = None,
    ) -> None:
        self.settings, self.users, self.status = settings, users, status
        self.login_users = Users(users, settings.allow_anonymous, limiter)
        self.zones, self.cameras = list(zones), list(cameras)
        self.desk = incidents
        self.certificate = None  # the AppCertificate, once started
        self._lock = threading.Lock()
        self._changes: deque[tuple[IncidentRecord, str, float | None, float | None]] = deque()
        self._occupants: dict[str, set[int]] = {z.name: set() for z in self.zones}
        self._dirty_zones: dict[str, float | None] = {}
        self._dirty_power: dict[str, tuple[str, float | None]] = {}  # zone -> state, when
        self._dirty_cameras: dict[str, tuple[bool, float | None]] = {}
        self._stall: bool | None = None
        self._people: int | None = None
        self._people_sent: int | None = None
        self._tickets = TicketSlots()  # the active tickets' slots, as IEC 104 has them
        self._tickets_dirty = True  # (written once at the start: every slot free)
        self._resync = False
        self._pending = False
        self.dropped = 0  # incident changes dropped (the queue full)
        self.acks = self.acks_refused = 0
        self.evicted = 0  # sockets without a session closed to free a place
        self._loop: asyncio.AbstractEventLoop | None = None
        self._wake: asyncio.Event | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="opcua", daemon=True)
        self.space: SiteSpace | None = None

    def __repr__(self) -> str:
        return f"OpcuaServer({self.settings.endpoint})"

    # -- starting and stopping ------------------------------------------------------------

    def start(self, timeout_s: float = START_TIMEOUT_S) -> None:
        """Listening once this returns; a StereoposeError says why it cannot."""
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise StereoposeError(
                f"OPC UA {self.settings.endpoint}: not started within {timeout_s:g} s"
            )
        if self._error is not None:
            self._thread.join(STOP_TIMEOUT_S)
            raise StereoposeError(f"OPC UA {self.settings.endpoint}: cannot start: {self._error}")
        logger.info("OPC UA: serving %s", self.settings.endpoint)

    def _close(self) -> list[Path]:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and self._thread.is_alive():
            with contextlib.suppress(RuntimeError):  # the loop already closed
                loop.call_soon_threadsafe(stop.set)
            self._thread.join(STOP_TIMEOUT_S)
            if self._thread.is_alive():
                logger.warning("OPC UA: the server did not stop within %g s", STOP_TIMEOUT_S)
        return []

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as e:  # reported by start(), or logged once running
            if not self._ready.is_set():
                self._error = e
                self._ready.set()
            else:
                logger.exception("OPC UA: the server stopped")

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._wake, self._stop = asyncio.Event(), asyncio.Event()
        logging.getLogger("asyncua").setLevel(logging.WARNING)  # its info logs every request
        server = await self._server()
        try:
            await server.start()
        except OSError as e:
            raise StereoposeError(f"cannot listen: {e.strerror or e}") from None
        self._ready.set()
        poll = asyncio.create_task(self._poll_status())
        sweep = asyncio.create_task(sweep_idle(server, self._evicted_one))
        try:
            while not self._stop.is_set():
                await self._wait()
                try:
                    await self._drain()
                except Exception:  # a bug here must not end the server
                    logger.exception("OPC UA: updating the address space failed")
        finally:
            poll.cancel()
            sweep.cancel()
            try:
                if self.space is not None:
                    await self.space.write("site/Running", False, ua.VariantType.Boolean)
            finally:
                await server.stop()

    async def _wait(self) -> None:
        stop_event, wake_event = self._stop, self._wake
        assert stop_event is not None and wake_event is not None  # made by the running loop
        stop = asyncio.create_task(stop_event.wait())
        wake = asyncio.create_task(wake_event.wait())
        await asyncio.wait((stop, wake), return_when=asyncio.FIRST_COMPLETED)
        for t in (stop, wake):
            t.cancel()
        wake_event.clear()
        with self._lock:
            self._pending = False

    async def _server(self) -> Server:
        s = self.settings
        iserver = LoginServer(user_manager=self.login_users)
        iserver.bind_condition_methods = True  # ConditionRefresh
        iserver.max_connections = s.max_connections + SPARE_SOCKETS
        iserver.max_subscriptions = 4 * s.max_connections
        iserver.max_monitored_item_queue_size = 1000
        iserver.max_pending_activation_seconds = ACTIVATE_S
        server = Server(iserver=iserver)
        server.limits = TransportLimits(
            max_recv_buffer=65535,
            max_send_buffer=65535,
            max_chunk_count=MAX_MESSAGE // 65535 + 1,
            max_message_size=MAX_MESSAGE,
        )
        await server.init()
        app = application_certificate(s)
        self.certificate = app
        await server.set_application_uri(app.application_uri)
        server.set_server_name(f"stereopose {s.site}")
        server.product_uri = "urn:stereopose"
        server.manufacturer_name = "stereopose"
        server.application_type = ua.ApplicationType.Server
        server.set_endpoint(s.endpoint)
        policies = [getattr(ua.SecurityPolicyType, name) for name in s.security]
        # asyncua annotates its simple ruleset here; it takes any PermissionRuleset
        rules = Permissions()
        server.set_security_policy(policies, permission_ruleset=rules)  # pyright: ignore[reportArgumentType]
        tokens: list[type] = [ua.UserNameIdentityToken]
        if s.allow_anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        iserver.certificate, iserver.private_key = app.certificate, app.key
        if s.trusted_clients is not None:
            server.set_certificate_validator(await trusted_clients(s.trusted_clients))
        self.space = SiteSpace(server, s.site, self.zones, self.cameras)
        await self.space.build()
        server.link_method(server.get_node(_ACK), self._acknowledge)
        return server

    # -- the frame loop's side: only enqueues -----------------------------------------------

    def write(self, frame: FrameResult) -> None:
        """The frame's zone and camera events and its people count, kept as latest values."""
        people = len(frame.people3d)
        if not frame.events and people == self._people:
            return
        desk = self.desk
        wall0 = desk.wall_start if desk.running else None  # the Unix time of t = 0
        with self._lock:
            self._people = people
            for e in frame.events:
                wall = None if wall0 is None else wall0 + e.t
                if e.kind == "ticket":
                    self._tickets_dirty |= self._tickets.event(e)
                elif e.type in ("enter", "exit") and e.zone in self._occupants:
                    inside = self._occupants[e.zone]
                    (inside.add if e.type == "enter" else inside.discard)(e.person)
                    self._dirty_zones[e.zone] = wall
                elif e.type in ("zone_live", "zone_dead", "zone_unknown"):
                    self._dirty_power[e.zone] = (e.type[5:], wall)
                elif e.type in ("camera_down", "camera_up") and e.camera:
                    self._dirty_cameras[e.camera] = (e.type == "camera_up", wall)
                elif e.type in ("service_stalled", "service_resumed"):
                    self._stall = e.type == "service_stalled"
        self._poke()

    def write_changes(self, changes: Sequence) -> None:
        """Incident changes (alarms.Change), queued for the server's thread (bounded)."""
        if not changes:
            return
        with self._lock:
            for c in changes:
                wall = None if c.wall_start is None else c.wall_start + c.t
                if len(self._changes) >= self.settings.queue_size:
                    self._changes.popleft()
                    self.dropped += 1
                    if not self._resync:
                        logger.warning(
                            "OPC UA: %d incident changes waiting, the bound: dropping "
                            "the oldest (the conditions are read again from the book)",
                            self.settings.queue_size,
                        )
                    self._resync = True
                self._changes.append((c.incident, c.what, wall, c.wall_start))
        self._poke()

    def show_book(self) -> None:
        """The book runs (its desk's step attached): its open incidents shown at once, the
        restored ones too."""
        with self._lock:
            self._resync = True
        self._poke()

    def _poke(self) -> None:
        """Wake the server's loop (once until it has looked)."""
        loop, wake = self._loop, self._wake
        if loop is None or wake is None:
            return
        with self._lock:
            if self._pending:
                return
            self._pending = True
        with contextlib.suppress(RuntimeError):  # the loop is closing
            loop.call_soon_threadsafe(wake.set)

    # -- the server's loop ----------------------------------------------------------------

    async def _drain(self) -> None:
        space = self.space
        assert space is not None  # drained once the server runs
        with self._lock:
            changes = list(self._changes)
            self._changes.clear()
            zones = {z: (len(self._occupants[z]), w) for z, w in self._dirty_zones.items()}
            cameras, stall = dict(self._dirty_cameras), self._stall
            power = dict(self._dirty_power)
            self._dirty_power.clear()
            self._dirty_zones.clear()
            self._dirty_cameras.clear()
            people, resync, desk = self._people, self._resync, self.desk
            self._resync = False
            tickets = TicketSlots(list(self._tickets.slots), dict(self._tickets.steps_done))
            tickets_dirty, self._tickets_dirty = self._tickets_dirty, False
        if stall is not None:
            await space.set_stalled(stall)
        for name, (up, wall) in cameras.items():
            await space.set_camera(name, up, wall)
        for name, (n, wall) in zones.items():
            await space.set_zone(name, n, wall)
        for name, (state, wall) in power.items():
            await space.set_power(name, state, wall)
        if people is not None and people != self._people_sent:
            self._people_sent = people
            await space.write("site/People", people, ua.VariantType.UInt32)
        records = []
        for rec, what, wall, wall_start in changes:
            if what == DROPPED:
                await space.drop(rec, wall, wall_start)
            else:
                records.append((rec, wall, wall_start))
        await space.apply(records)
        if resync and desk.running:
            await self._resync_from(desk)
        if tickets_dirty or changes or resync:  # a slot, or a ticket's incident, changed
            await space.set_tickets(tickets)

    async def _resync_from(self, desk: IncidentSide) -> None:
        """The book's incidents as the conditions (after drops, or once the book runs)."""

        def read() -> list[IncidentRecord]:
            with desk.lock:
                return desk.book.incidents()

        space = self.space
        assert space is not None  # once the server runs
        records = await asyncio.get_running_loop().run_in_executor(None, read)
        wall_start = desk.wall_start
        kept = {r.id for r in records}
        for gone in [i for i in space.conditions if i not in kept]:
            rec = space.conditions[gone].record
            await space.drop(dataclasses.replace(rec, state=CLOSED), None, wall_start)
        await space.apply([(r, None, wall_start) for r in records])

    def _evicted_one(self) -> None:
        self.evicted += 1

    async def _poll_status(self) -> None:
        if self.status is None:
            return
        last = None
        while True:
            try:
                status = await asyncio.get_running_loop().run_in_executor(None, self.status)
            except Exception as e:  # the status missing never stops the server
                logger.debug("OPC UA: no status: %s", e)
            else:
                if status != last and self.space is not None:
                    last = status
                    await self.space.write("site/Status", str(status), ua.VariantType.String)
            await asyncio.sleep(STATUS_EVERY_S)

    async def _acknowledge(self, parent: ua.NodeId, *args: ua.Variant) -> ua.StatusCode | list:
        """OPC UA's Acknowledge(EventId, Comment) on a condition: the incident's ack."""
        code = await self._ack(parent, caller(), args)
        if code is not None:
            self.acks_refused += 1
            # asyncua annotates a status code as its own UInt32; it takes an int
            return ua.StatusCode(code)  # pyright: ignore[reportArgumentType]
        self.acks += 1
        return []

    async def _ack(
        self, parent: ua.NodeId, caller: User | None, args: tuple[ua.Variant, ...]
    ) -> int | None:
        space, desk = self.space, self.desk
        assert space is not None  # a method is called once the server runs
        name = getattr(caller, "name", None)
        if name is None or not may_acknowledge(self.users, caller):
            logger.warning(
                "OPC UA: acknowledge refused for %s", repr(name) if name else "an anonymous client"
            )
            return StatusCodes.BadUserAccessDenied
        refused = refusal(space, parent, args)
        if refused is not None:
            return refused
        incident = space.by_node[parent]
        if not desk.running:
            return StatusCodes.BadResourceUnavailable
        text = comment_of(args)
        try:
            rec = await asyncio.get_running_loop().run_in_executor(
                None, desk.acknowledge, incident, name
            )
        except UnknownIncidentError:
            return StatusCodes.BadNodeIdUnknown
        logger.info(
            "OPC UA: incident %d acknowledged by %s%s",
            incident,
            name,
            f" ({text[:200]!r})" if text else "",
        )
        await space.apply([(rec, time.time(), desk.wall_start)])
        return None

    # -- figures ----------------------------------------------------------------------------

    def health(self) -> OutputHealth:
        """Not ok once the server's thread has ended; waiting: the changes queued."""
        with self._lock:
            waiting = len(self._changes)
        if self._closed or self._thread.is_alive():
            return OutputHealth(True, waiting)
        return OutputHealth(False, waiting, "the OPC UA server stopped")

    output_name = "opcua"

    @property
    def label(self) -> str:
        return f"OPC UA {self.settings.endpoint}"

    def queued(self) -> int:
        with self._lock:
            return len(self._changes)

    def figures(self) -> dict:
        """status.json's `opcua`: changes queued and dropped, acknowledgements, logins limited,
        idle connections closed, conditions shown."""
        with self._lock:
            queued = len(self._changes)
        space = self.space
        return {
            "queued": queued,
            "dropped": self.dropped,
            "acknowledged": self.acks,
            "acknowledge_refused": self.acks_refused,
            "logins_limited": self.login_users.limited,
            "idle_closed": self.evicted,
            "conditions": len(space.conditions) if space is not None else 0,
        }
