"""serve's IEC 60870-5-104 outstation (controlled station) over c104's Server (lib60870).

    station = Outstation(Iec104Settings.from_config(cfg.iec104), points_table(site, rig),
                         wall_start=wall_start, status=lambda: state.snapshot().status,
                         acknowledger=desk.acknowledge)  # the commands' way to the book
    station.write(frame)              # a sink of the frame loop: zone, camera, service events
    station.write_changes(changes)    # an incident output (alarms.book.Change)
    station.incidents(records)        # the open incidents at start (a restart restored them)
    station.close()

The points are those of stereopose.scada.points (what `stereopose points` prints), in one
station of common address `common_address`. Each change of a point's value or quality is sent
at once as a spontaneous message (cause 3) carrying the time of the event that changed it
(CP56Time2a, the event's wall time: wall_start + its t, in UTC or the machine's local time as
`time_tags` says); a general interrogation (C_IC_NA_1) returns every monitoring point as it is
now, with the time of its last change. A point is invalid (IV) while one of the cameras that
see what it watches is down, or while the service is stalled; a zone no camera sees is always
invalid. Cameras count as up until the camera watch says otherwise (camera_down), as serve's
health does.

The frame loop never waits on the network: `write` and `write_changes` only append to one
bounded queue (`queue_size`; at the bound the newest item is dropped, counted and logged once
per burst); the outstation's own thread folds the queue into the points, polls the health
answer for `service degraded` once a second and hands the changes to c104, whose threads talk
to the masters.

Clients come in through the guard (scada.iec104_guard), which listens on host:port and passes
the bytes to c104's server on a loopback port: a connection from an address outside
`allowed_clients` is refused (counted, logged once per address); one that has not started data
transfer within `start_within_s` is closed; at most `max_connections` are open together, a
newcomer taking the place of the oldest one not started (else refused). A link silent for
`test_after_s` (t3) is sent a TESTFR and closed when it is not answered within
`answer_within_s` (t1). Whatever a client sends, lib60870
parses it: a malformed frame closes that client's connection only. Clock synchronisation
(C_CS_NA_1): confirmed positively, as the standard asks of a controlled station, and never
applied: the system clock is the machine's (NTP), never set by a master. The master's offset
from it is kept (`figures()["clock_offset_s"]`) and logged as a warning when over
CLOCK_WARN_S, since the time tags would disagree with the master's clock by that much.
Commands (`commands = true`): a single command ON to a zone's or a priority's acknowledge
point acknowledges each of its unacknowledged incidents (as an operator would, by "iec104
master <originator address>"); OFF is refused (negative confirmation). Without `commands` no
command point exists and a command is answered with an unknown address.
"""

from __future__ import annotations

import datetime as dt
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stereopose.alarms import Change, IncidentRecord
from stereopose.errors import StereoposeError
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.sinks.health import OutputHealth
from stereopose.scada.iec104_guard import Guard
from stereopose.scada.iec104_settings import (
    Iec104Error,
    Iec104Settings,
    _free_loopback_port,
    typed_callback,
)
from stereopose.scada.iec104_state import UNACKED, PointState
from stereopose.scada.points import COMMAND, Point, PointsTable

if TYPE_CHECKING:
    from c104 import IncomingMessage, Information, ResponseState
    from c104 import Point as C104Point
    from c104 import Server as C104Server

__all__ = ["CLOCK_WARN_S", "Iec104Settings", "Outstation"]

logger = logging.getLogger(__name__)

CLOCK_WARN_S = 1.0  # a master's clock this far from ours is worth a warning
STATUS_INTERVAL_S = 1.0  # how often the health answer is read for `service degraded`
TICK_MS = 50  # c104's server loop period (its smallest)
GUARD_SPARE = 4  # c104's places beyond max_connections, for the links the guard is closing
MAX_LOGGED_ADDRESSES = 100  # refused addresses logged one by one; beyond, only counted
_SCALED_MAX = 32767  # a scaled value's largest (M_ME_TE_1 holds a 16-bit integer)
FIGURES = (
    "queued_max",
    "dropped",
    "transmitted",
    "refused",
    "commands",
    "commands_refused",
    "clock_syncs",
)


class Outstation(ClosesOnce):
    """See the module. settings: Iec104Settings; table: the points (scada.points);
    wall_start: the Unix time of the events' t = 0; status(): the health answer's status
    ("ok", "degraded", "down"), read on the outstation's thread, or None (never degraded);
    acknowledger(incident_id, by): the incident book's acknowledge (commands; None: each
    command refused).
    Starts serving at once; an Iec104Error when the port cannot be taken."""

    stage = "write"

    def __init__(
        self,
        settings: Iec104Settings,
        table: PointsTable,
        *,
        wall_start: float,
        status: Callable[[], str] | None = None,
        acknowledger: Callable[[int, str], Any] | None = None,
        status_interval_s: float = STATUS_INTERVAL_S,
    ) -> None:
        try:
            import c104
        except ImportError:
            raise Iec104Error(
                "the IEC 60870-5-104 outstation ([iec104]) needs c104: "
                "pip install 'stereopose[scada]'"
            ) from None
        self._c104 = c104
        self.settings, self.table, self.wall_start = settings, table, float(wall_start)
        self.status, self.acknowledger = status, acknowledger
        self.status_interval_s = float(status_interval_s)
        cams = {p.name: True for p in table if p.kind == "camera_up" and p.name is not None}
        zones: dict[str, set[int]] = {
            p.name: set() for p in table if p.kind == "zone_occupied" and p.name is not None
        }
        self._state = PointState(zones, cams)
        self._queue: deque[tuple[str, Any]] = deque()
        self._cond = threading.Condition()
        self._stopping = False
        self._sent: dict[int, tuple[Any, bool]] = {}  # ioa -> (value, invalid) last set
        self._last_people = 0
        self._burst = 0
        self._figures = dict.fromkeys(FIGURES, 0)
        self._clock_offset_s: float | None = None
        self._refused_logged: set[str] = set()
        upstream = _free_loopback_port()
        self._server = self._make_server(c104, upstream)
        self._points = self._make_points(c104)
        self._set_all(time.time())
        self._guard = Guard(
            settings.host,
            settings.port,
            upstream,
            max_connections=settings.max_connections,
            start_within_s=settings.start_within_s,
            allows=settings.allows,
            refused=self._refuse,
        )
        try:
            self._guard.start()
        except OSError as e:
            raise Iec104Error(
                f"IEC 60870-5-104 on {settings.host}:{settings.port}: cannot "
                f"listen ({e.strerror or e})"
            ) from None
        try:
            self._server.start()
        except RuntimeError as e:
            self._guard.close()
            raise Iec104Error(
                f"IEC 60870-5-104: the outstation cannot listen on loopback port {upstream} ({e})"
            ) from None
        self._thread = threading.Thread(target=self._run, name="iec104", daemon=True)
        self._thread.start()
        logger.info(
            "IEC 60870-5-104 outstation on %s:%d, common address %d, %d points",
            settings.host,
            settings.port,
            settings.common_address,
            len(table),
        )

    def __repr__(self) -> str:
        return f"Outstation({self.settings.host}:{self.settings.port})"

    # --- the frame loop's side: only appends to the bounded queue ---------------------------

    def write(self, frame: FrameResult) -> None:
        wall = self.wall_start + float(frame.t)
        if frame.events:
            self._put("events", tuple(frame.events))
        n = len(frame.people3d.ids)
        if n != self._last_people:
            self._last_people = n
            self._put("people", (wall, n))

    def write_changes(self, changes: Sequence[Change]) -> None:
        """An incident output: each step's changes (alarms.book.Change)."""
        if changes:
            self._put("changes", tuple(changes))

    def incidents(self, records: Iterable[IncidentRecord]) -> None:
        """The incidents open now (IncidentRecord), e.g. restored at a restart."""
        self._put("records", tuple(records))

    def _put(self, kind: str, item: object) -> None:
        with self._cond:
            if len(self._queue) >= self.settings.queue_size:
                self._figures["dropped"] += 1
                if self._burst == 0:
                    logger.warning(
                        "IEC 60870-5-104: %d changes waiting, the bound: dropping "
                        "new ones until the outstation catches up",
                        self.settings.queue_size,
                    )
                self._burst += 1
                return
            self._queue.append((kind, item))
            self._figures["queued_max"] = max(self._figures["queued_max"], len(self._queue))
            self._cond.notify()

    # --- the outstation's thread -------------------------------------------------------------

    def _run(self) -> None:
        next_status = 0.0
        while True:
            with self._cond:
                if not self._queue and not self._stopping:
                    self._cond.wait(timeout=max(0.0, next_status - time.monotonic()))
                items = list(self._queue)
                self._queue.clear()
                stopping = self._stopping
                if not items and self._burst:
                    logger.warning(
                        "IEC 60870-5-104: %d changes were dropped while the queue was full",
                        self._burst,
                    )
                    self._burst = 0
            for kind, item in items:
                try:
                    self._apply(kind, item)
                except Exception:  # a bad item never stops the outstation
                    logger.exception("IEC 60870-5-104: cannot apply a %s update", kind)
            if time.monotonic() >= next_status:
                next_status = time.monotonic() + self.status_interval_s
                self._poll_status()
            if stopping:
                return

    def _apply(self, kind: str, item: object) -> None:
        assert isinstance(item, (list, tuple))  # what put() queued for `kind`
        s = self._state
        if kind == "events":
            for e in item:
                s.event(e)
                self._refresh(self.wall_start + float(e.t))
        elif kind == "people":
            wall, s.people = item
            self._refresh(wall)
        elif kind == "changes":
            for c in item:
                s.record(c.incident)
                self._refresh(self.wall_start + float(c.t))
        elif kind == "records":
            for r in item:
                s.record(r)
            self._refresh(time.time())

    def _poll_status(self) -> None:
        if self.status is None:
            return
        try:
            degraded = self.status() != "ok"
        except Exception as e:  # the health answer failing is no reason to stop
            logger.debug("IEC 60870-5-104: cannot read the health state: %s", e)
            return
        if degraded != self._state.degraded:
            self._state.degraded = degraded
            self._refresh(time.time())

    # --- points ------------------------------------------------------------------------------

    def _refresh(self, wall_t: float) -> None:
        """Set and send spontaneously every point whose value or quality changed, tagged at
        wall_t (the time of what changed it)."""
        for ioa, vq in self._state.values(self.table).items():
            if self._sent.get(ioa) != vq:
                self._set(ioa, vq, wall_t)
                try:
                    self._points[ioa].transmit(cause=self._c104.Cot.SPONTANEOUS)
                except Exception as e:  # c104 refusing one message never stops the others
                    logger.warning("IEC 60870-5-104: cannot send point %d: %s", ioa, e)
                self._figures["transmitted"] += 1

    def _set_all(self, wall_t: float) -> None:
        for ioa, vq in self._state.values(self.table).items():
            self._set(ioa, vq, wall_t)

    def _set(self, ioa: int, vq: tuple[Any, bool], wall_t: float) -> None:
        c104 = self._c104
        value, invalid = vq
        quality = c104.Quality.Invalid if invalid else c104.Quality()
        stamp = self.settings.stamp(wall_t)
        point = self._points[ioa]
        if point.type == c104.Type.M_ME_TE_1:
            n = max(-_SCALED_MAX, min(_SCALED_MAX, int(value)))
            point.info = c104.ScaledInfo(actual=c104.Int16(n), quality=quality, recorded_at=stamp)
        else:
            point.info = c104.SingleInfo(on=bool(value), quality=quality, recorded_at=stamp)
        self._sent[ioa] = vq

    # --- c104's side: the server, its callbacks (c104's threads) -----------------------------

    def _make_server(self, c104: Any, port: int) -> Any:
        s = self.settings
        # on loopback, behind the guard (which holds max_connections; a little room here for
        # the links the guard is closing)
        server = c104.Server(
            ip="127.0.0.1",
            port=port,
            tick_rate_ms=TICK_MS,
            max_connections=s.max_connections + GUARD_SPARE,
        )
        # t3 and t1: a socket that never answers a TESTFR is closed within their sum, so
        # idle sockets hold the master's places for less long (t1 stays above the masters'
        # acknowledgement delay t2; ours, t2, below t1)
        params = server.protocol_parameters
        params.keep_alive_interval = s.test_after_s
        params.message_timeout = s.answer_within_s
        params.confirm_interval = min(params.confirm_interval, s.answer_within_s - 1)

        def on_connect(server: C104Server, ip: str) -> bool:
            return ip.rsplit(":", 1)[0] == "127.0.0.1"  # the guard's links only

        def on_clock_sync(server: C104Server, ip: str, date_time: dt.datetime) -> ResponseState:
            self._clock_sync(ip, date_time)
            return c104.ResponseState.SUCCESS

        server.on_connect(callable=typed_callback(on_connect, server=c104.Server, ip=str, ret=bool))
        server.on_clock_sync(
            callable=typed_callback(
                on_clock_sync,
                server=c104.Server,
                ip=str,
                date_time=dt.datetime,
                ret=c104.ResponseState,
            )
        )
        return server

    def _make_points(self, c104: Any) -> dict[int, Any]:
        station = self._server.add_station(common_address=self.settings.common_address)
        types = {
            "M_SP_TB_1": c104.Type.M_SP_TB_1,
            "M_ME_TE_1": c104.Type.M_ME_TE_1,
            "C_SC_NA_1": c104.Type.C_SC_NA_1,
        }
        points = {}
        for p in self.table:
            point = station.add_point(io_address=p.ioa, type=types[p.type])
            if point is None:
                raise Iec104Error(f"IEC 60870-5-104: point {p.ioa} cannot be made")
            if p.type == COMMAND:
                point.on_receive(callable=self._command_handler(c104, p))
            points[p.ioa] = point
        return points

    def _command_handler(self, c104: Any, p: Point) -> Callable:
        def on_command(
            point: C104Point, previous_info: Information, message: IncomingMessage
        ) -> ResponseState:
            try:
                ok = bool(point.value) and self._acknowledge(p, message.originator_address)
            except Exception:  # a failing acknowledgement is a negative confirmation
                logger.exception("IEC 60870-5-104: command to point %d failed", p.ioa)
                ok = False
            self._figures["commands" if ok else "commands_refused"] += 1
            return c104.ResponseState.SUCCESS if ok else c104.ResponseState.FAILURE

        return typed_callback(
            on_command,
            point=c104.Point,
            previous_info=c104.Information,
            message=c104.IncomingMessage,
            ret=c104.ResponseState,
        )

    def _acknowledge(self, p: Point, originator: int) -> bool:
        """Acknowledge the unacknowledged incidents of the command's zone or priority."""
        ack = self.acknowledger
        if ack is None:
            return False
        records = self._state.open_records()
        if p.kind == "ack_zone":
            ids = [r.id for r in records if r.state in UNACKED and r.zone == p.name]
        else:
            ids = [r.id for r in records if r.state in UNACKED and str(r.priority) == p.name]
        by = f"iec104 master {originator}"
        for i in ids:
            try:
                ack(i, by)
            except StereoposeError as e:  # closed meanwhile: nothing left to acknowledge
                logger.info("IEC 60870-5-104: incident %d: %s", i, e)
        logger.info(
            "IEC 60870-5-104: %s acknowledged %d incident(s) by point %d", by, len(ids), p.ioa
        )
        return True

    def _refuse(self, ip: str) -> None:
        self._figures["refused"] += 1
        host = ip.rsplit(":", 1)[0]
        if host not in self._refused_logged and len(self._refused_logged) < MAX_LOGGED_ADDRESSES:
            self._refused_logged.add(host)
            logger.warning(
                "IEC 60870-5-104: connection from %s refused: not in iec104.allowed_clients", host
            )

    def _clock_sync(self, ip: str, fields: dt.datetime) -> None:
        try:
            offset = self.settings.unix(fields) - time.time()
        except (ValueError, OverflowError, OSError):
            return
        self._figures["clock_syncs"] += 1
        first = self._clock_offset_s is None
        self._clock_offset_s = offset
        if abs(offset) > CLOCK_WARN_S and (first or self._figures["clock_syncs"] % 100 == 1):
            logger.warning(
                "IEC 60870-5-104: the master at %s is %+.1f s from this machine's "
                "clock (not applied: the time tags keep this machine's clock; "
                "check NTP, and iec104.time_tags)",
                ip.rsplit(":", 1)[0],
                offset,
            )

    # --- reading, closing --------------------------------------------------------------------

    output_name = "iec104"  # an alarm output (io.sinks.health.AlarmOutput)

    @property
    def label(self) -> str:
        return f"IEC 60870-5-104 {self.settings.host}:{self.settings.port}"

    def figures(self) -> dict:
        """Connections open (and of them started), refused, points sent, commands, clock
        syncs, the queue."""
        with self._cond:
            queued = len(self._queue)
        f: dict[str, object] = {**self._figures}
        f.update(
            queued=queued,
            clock_offset_s=self._clock_offset_s,
            connections=self._guard.connections(),
            started_connections=self._guard.started(),
            active_connections=self._server.active_connection_count,
            **self._guard.counts,
        )
        return f

    def queued(self) -> int:
        with self._cond:
            return len(self._queue)

    @property
    def dropped(self) -> int:
        return self._figures["dropped"]

    def health(self) -> OutputHealth:
        """Not ok once the server or the outstation's thread has stopped; waiting: the
        changes not yet folded into the points (a master not connected is no fault here: the
        master connects to the outstation, and interrogates once it does)."""
        waiting = self.queued()
        if not self._thread.is_alive() or not self._server.is_running or not self._guard.running:
            return OutputHealth(False, waiting, "the IEC 60870-5-104 outstation stopped")
        return OutputHealth(True, waiting)

    def _close(self) -> list[Path]:
        with self._cond:
            self._stopping = True
            self._cond.notify()
        self._thread.join(timeout=5.0)
        if self._thread.is_alive():
            logger.warning("IEC 60870-5-104: the outstation's thread did not stop; left behind")
        else:
            self._state.running = False  # the masters see the service stop
            self._refresh(time.time())
            time.sleep(2 * TICK_MS / 1000)  # c104 sends on its next ticks
        self._server.stop()
        self._guard.close()
        f = self.figures()
        logger.log(
            logging.WARNING if f["dropped"] else logging.INFO,
            "IEC 60870-5-104 closed: %d points sent, %d dropped, %d refused connections, "
            "%d commands",
            f["transmitted"],
            f["dropped"],
            f["refused"],
            f["commands"],
        )
        return []
