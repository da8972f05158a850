"""The control room's HTTP API, with the site console's login, roles and hardening.

- `GET /api/health` (open): `{"status", "broker", "sites": {state: n}, "ingest": {...}}`;
  degraded while the broker or the store is out, or the ingest is down or stores nothing of
  the events that come (`ingest.running`, `ingest.trouble`);
- `GET /metrics` (open): `stereopose_controlroom_*` in Prometheus' text format;
- `POST /api/login`, `POST /api/logout`, `GET /api/me`: the site console's (stereopose.web.login),
  over the control room's own `users.json` (`stereopose users add ... --config CONTROL.toml`);
- `GET /api/sites` (viewer): `{"sites": [{"site", "state", "last_seen", "cameras",
  "cameras_up", "people", "open_incidents", "events", "mark"}]}`;
- `GET /api/events?site=S&after_id=N&limit=L` (viewer): `{"events": [{"site", "id", ...}]}`
  in (site, id) order, a page after `after_id`, `"more": true` when the page stopped at
  MAX_PAGE_BYTES of rows before `limit` (ask again after its last id);
- `GET /api/incidents?site=S&state=open|active|acknowledged|cleared|closed&limit=L`
  (viewer): `{"incidents": [...]}`: the sites' incidents (each its site's record with `site`,
  `seq`, `source: "site"` and `ack_pending`: acknowledgements asked and not yet answered),
  then the control room's own (`source: "control_room"`: a site offline, a site's clock off,
  a site's ids beyond what it announced, unknown sites refused); `more` as for events;
- `POST /api/sites/{site}/incidents/{id}/ack` (operator): asks the site to acknowledge its
  incident as this user (`"USER via NAME"` at the site); 202 `{"command", "incident"}` (the
  site's answer comes back with the incident's record), 200 when it is acknowledged already,
  404 for an incident the control room does not hold;
- `POST /api/room-incidents/{id}/ack` (operator): acknowledges a control room's incident;
- `GET /api/sites/{site}/plan` (viewer): the site's zones (from its retained `plan` topic)
  and its people now (its `people` topic, followed while someone looks: a few seconds after
  the last look it is left), `{"site", "plan", "people", "console_url"}`;
- `GET /` and `/console/...`: the control room's console page.

A user limited to some sites (`stereopose users add NAME --sites A,B`) sees and acts on those
only: every list is filtered, and another site's page or incident is 404.

Every answer is JSON; bodies, headers and connections are bounded, and Host names checked, as
the site service's are (web.limits, web.hosts, web.connections).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, Annotated, Literal, Protocol

from fastapi import APIRouter, FastAPI, HTTPException, Path, Query, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from stereopose import __version__
from stereopose.controlroom import page
from stereopose.controlroom.store import MAX_LIMIT, StoreError
from stereopose.site.health.metrics import CONTENT_TYPE, exposition
from stereopose.web import error_answers
from stereopose.web import login as auth
from stereopose.web.auth import Operator, Session, Viewer
from stereopose.web.error_answers import internal_error
from stereopose.web.hosts import HostCheck
from stereopose.web.limits import MAX_BODY_BYTES, RequestLimits

if TYPE_CHECKING:
    from stereopose.controlroom.ingest import Ingest
    from stereopose.controlroom.store import ControlStore
    from stereopose.web.auth import Logins

__all__ = ["create_control_app"]


class Room(Protocol):
    """What the app serves (controlroom.service.ControlRoom): the store, the ingest of the
    sites' messages (None until it runs) and who may log in."""

    @property
    def store(self) -> ControlStore: ...
    @property
    def ingest(self) -> Ingest | None: ...
    @property
    def console(self) -> Logins: ...


STATES = ("live", "offline", "degraded", "unknown")
MAX_PAGE_BYTES = 4 << 20  # an events or incidents page stops at about this many bytes
_I64 = 2**63 - 1

router = APIRouter()


def _room(request: Request) -> Room:
    return request.app.state.room


def _ingest(room: Room) -> Ingest:
    """The room's ingest; 503 in the moment between the server's start and the ingest's."""
    if room.ingest is None:
        raise HTTPException(503, "the control room is starting: try again in a moment")
    return room.ingest


def _allowed(request: Request, session: Session) -> set[str] | None:
    """The sites this session's user may see (None: every site)."""
    user = request.app.state.console.users.get(session.username)
    if user is None or user.sites is None:
        return None if user is not None else set()
    return set(user.sites)


def _check_site(request: Request, session: Session, site: str) -> None:
    allowed = _allowed(request, session)
    if allowed is not None and site not in allowed:
        raise HTTPException(404, f"no site {site!r}")


@router.get("/api/health")
def health(request: Request, response: Response) -> dict:
    room = _room(request)
    f = _ingest(room).figures()
    try:
        by_state = {s: 0 for s in STATES}
        for row in room.store.sites():
            by_state[row.state if row.state in by_state else "unknown"] += 1
        store_ok = True
    except StoreError:
        by_state, store_ok = {}, False
    ok = f["connected"] and store_ok and f["running"]
    response.headers["Cache-Control"] = "no-store"
    return {
        "status": "ok" if ok else "degraded",
        "broker": f["connected"],
        "store": store_ok,
        "sites": by_state,
        "ingest": f,
    }


@router.get("/api/sites")
def sites(request: Request, session: Viewer) -> dict:
    room = _room(request)
    try:
        rows = room.store.sites(_allowed(request, session))
        open_counts = room.store.open_counts()
    except StoreError as e:
        raise HTTPException(503, "the control room's store cannot be read") from e
    out, offsets = [], _ingest(room).clock_offsets
    for r in rows:
        h = r.health or {}
        state = r.state
        if state == "live" and h.get("status") in ("degraded", "down"):
            state = "degraded"
        by = open_counts.get(r.site, {})
        out.append(
            {
                "site": r.site,
                "state": state,
                "last_seen": r.last_seen,
                "cameras": h.get("cameras"),
                "cameras_up": h.get("cameras_up"),
                "people": h.get("people"),
                "open_incidents": sum(by.values()),
                "open_by_priority": by,
                "status": h.get("status"),
                "events": r.events,
                "mark": r.mark,
                "clock_offset_s": offsets.get(r.site, h.get("clock_offset_s")),
            }
        )
    return {"sites": out}


@router.get("/api/events")
def events(
    request: Request,
    session: Viewer,
    site: Annotated[str | None, Query(max_length=200)] = None,
    after_id: Annotated[int, Query(ge=0, le=_I64)] = 0,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 100,
) -> dict:
    try:
        rows = _room(request).store.events(site, after_id, limit, sites=_allowed(request, session))
    except StoreError as e:
        raise HTTPException(503, "the control room's store cannot be read") from e
    kept = _within(rows)
    return {"events": kept, "more": len(kept) < len(rows)}


@router.get("/api/incidents")
def incidents(
    request: Request,
    session: Viewer,
    site: Annotated[str | None, Query(max_length=200)] = None,
    state: Annotated[
        Literal["open", "active", "acknowledged", "cleared", "closed"] | None, Query()
    ] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 100,
) -> JSONResponse:
    try:
        found = _room(request).store.incidents(site, state, _allowed(request, session), limit)
    except StoreError as e:
        raise HTTPException(503, "the control room's store cannot be read") from e
    kept = _within(found)
    return JSONResponse(
        {"incidents": kept, "more": len(kept) < len(found)}, headers={"Cache-Control": "no-store"}
    )


def _within(rows: list[dict], max_bytes: int = MAX_PAGE_BYTES) -> list[dict]:
    """The first rows whose JSON together stays within max_bytes (at least one): a page's
    size is bounded whatever the rows hold; `more` tells the client to ask on."""
    total = 0
    for i, r in enumerate(rows):
        total += len(json.dumps(r, default=str)) + 1
        if total > max_bytes and i > 0:
            return rows[:i]
    return rows


@router.post(
    "/api/sites/{site}/incidents/{incident_id}/ack",
    status_code=202,
    responses={200: {}, 403: {}, 404: {}},
)
def ack(
    site: Annotated[str, Path(max_length=200)],
    incident_id: Annotated[int, Path(ge=0, le=_I64)],
    session: Operator,
    request: Request,
    response: Response,
) -> dict:
    """Ask the site to acknowledge its incident as this user (see the module)."""
    _check_site(request, session, site)
    room = _room(request)
    try:
        rec = room.store.incident(site, incident_id)
        if rec is None:
            raise HTTPException(404, f"site {site!r} has no incident {incident_id} here")
        if rec.get("acked_by"):
            response.status_code = 200
            return {"command": None, "incident": rec}
        command = _ingest(room).ask_ack(site, incident_id, session.username)
    except StoreError as e:
        raise HTTPException(503, "the control room's store cannot be written") from e
    return {"command": command, "incident": rec}


@router.post("/api/room-incidents/{incident_id}/ack", responses={403: {}, 404: {}})
def ack_room(
    incident_id: Annotated[int, Path(ge=0, le=_I64)], session: Operator, request: Request
) -> dict:
    """Acknowledge one of the control room's own incidents (a site offline, its clock off)."""
    room = _room(request)
    allowed = _allowed(request, session)
    try:
        rec = room.store.room_incident(incident_id)
        if rec is not None and (allowed is None or rec["site"] in allowed):
            rec = room.store.ack_room_incident(incident_id, session.username, time.time())
        else:
            rec = None
    except StoreError as e:
        raise HTTPException(503, "the control room's store cannot be written") from e
    if rec is None:
        raise HTTPException(404, f"no control-room incident {incident_id}")
    return {"incident": rec}


@router.get("/api/sites/{site}/plan")
def plan(
    site: Annotated[str, Path(max_length=200)], session: Viewer, request: Request
) -> JSONResponse:
    """The site's zones and people now (see the module)."""
    _check_site(request, session, site)
    room = _room(request)
    try:
        known = site in _ingest(room).known_sites() or any(
            r.site == site for r in room.store.sites([site])
        )
    except StoreError as e:
        raise HTTPException(503, "the control room's store cannot be read") from e
    if not known:
        raise HTTPException(404, f"no site {site!r}")
    found = _ingest(room).watch(site)
    return JSONResponse({"site": site, **found}, headers={"Cache-Control": "no-store"})


@router.get("/metrics", response_class=Response)
def metrics(request: Request) -> Response:
    return Response(
        exposition(request.app.state.metrics_registry),
        media_type=CONTENT_TYPE,
        headers={"Cache-Control": "no-store"},
    )


class _Collector:
    def __init__(self, room: Room) -> None:
        self.room = room

    def collect(self) -> Iterator[GaugeMetricFamily | CounterMetricFamily]:
        ingest = self.room.ingest
        if ingest is None:  # scraped before the ingest runs: nothing of it yet
            return
        f = ingest.figures()
        g = GaugeMetricFamily("stereopose_controlroom_sites", "sites by state", labels=["state"])
        counts = {s: 0 for s in STATES}
        try:
            for row in self.room.store.sites():
                counts[row.state if row.state in counts else "unknown"] += 1
        except StoreError:
            pass
        for s, n in counts.items():
            g.add_metric([s], n)
        yield g
        yield GaugeMetricFamily(
            "stereopose_controlroom_messages_per_second",
            "messages in per second (recent)",
            value=f["messages_per_s"],
        )
        for name, key, doc in (
            ("events_stored", "stored", "events stored"),
            ("duplicates_dropped", "duplicates", "events received again and not stored twice"),
            ("gaps", "gaps", "events whose prev showed some lost on the way"),
            ("replays", "replays", "replays asked of sites"),
            ("malformed", "malformed", "messages that were not events"),
            (
                "dropped",
                "dropped",
                "messages dropped at the queue's bound (sent again by their sites)",
            ),
            ("incident_changes", "incident_changes", "incident changes stored"),
            (
                "commands_sent",
                "commands_sent",
                "acknowledgements sent to sites (again until answered)",
            ),
            ("commands_done", "commands_done", "acknowledgements answered by sites"),
            (
                "room_incidents",
                "room_incidents",
                "incidents raised by the control room (a site offline, its clock off)",
            ),
        ):
            yield CounterMetricFamily(f"stereopose_controlroom_{name}", doc, value=f[key])
        lag = GaugeMetricFamily(
            "stereopose_controlroom_lag_seconds",
            "seconds since each site's last message",
            labels=["site"],
        )
        for site, s in ingest.lag_s().items():
            lag.add_metric([site], s)
        yield lag

    def describe(self) -> list:
        return []


def create_control_app(
    room: Room,
    *,
    allowed_hosts: Iterable[str] | None = None,
    max_body_bytes: int = MAX_BODY_BYTES,
) -> FastAPI:
    """The app over `room` (its `store`, `ingest` and `console`: web.auth.Logins, who may log
    in)."""
    app = FastAPI(
        title="stereopose control room",
        version=__version__,
        debug=False,
        docs_url=None,
        redoc_url=None,
        openapi_url=None,
        swagger_ui_oauth2_redirect_url=None,
    )
    app.state.room = room
    app.state.console = room.console
    registry = CollectorRegistry(auto_describe=False)
    registry.register(_Collector(room))
    app.state.metrics_registry = registry
    app.state.started = time.time()
    app.add_exception_handler(Exception, internal_error)
    error_answers.add_handlers(app)
    if allowed_hosts is not None:
        app.add_middleware(HostCheck, allowed=tuple(allowed_hosts))
    app.add_middleware(RequestLimits, max_body_bytes=max_body_bytes)
    app.include_router(router)
    app.include_router(auth.router)
    page.mount_page(app)
    return app
