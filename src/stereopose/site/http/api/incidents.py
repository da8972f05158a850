"""GET /api/incidents, POST /api/incidents/{id}/ack, POST /api/incidents/{id}/shelve.

The list is read from the event log's `incidents` table (io.sinks.incidents, a read-only
connection), newest first, so closed incidents are there too: each with its record's fields
(state, priority, occurrences, first_t / last_t, acked_by / acked_at, shelved_until, ...) and
their wall times (first_wall_t, last_wall_t, acked_wall_at, shelved_wall_until: the run's
wall_start + t). Filters: state, priority, zone, person, since, until (Unix seconds or ISO
8601, on the wall times), limit (default 100, at most 1000).

The acts (operator or admin; a viewer 403) reach the incident book of the running service
(pipeline.incidents.IncidentStep, through the app's incident desk: site.desk) and answer with
the resulting record; the change is stored and published with the next step. 404: no open
incident with that id (never raised, or closed and forgotten); 422: a bad shelving (reason,
duration).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from stereopose.alarms import UnknownIncidentError
from stereopose.alarms.incident import MAX_SHELVE_S, IncidentError
from stereopose.io.sinks.incidents import MAX_LIMIT, IncidentFilters, query_incidents
from stereopose.site.http.api.events import query_times
from stereopose.site.http.web import Console
from stereopose.web.auth import Operator, Viewer, console_parts

if TYPE_CHECKING:
    from stereopose.alarms import IncidentRecord
    from stereopose.pipeline.incidents import IncidentStep

router = APIRouter(tags=["incidents"])

_I64 = 2**63 - 1
_TIME = Query(max_length=64, description="Unix seconds or ISO 8601")


class Shelving(BaseModel):
    reason: str = Field(min_length=1, max_length=500)
    duration_s: float = Field(gt=0, le=MAX_SHELVE_S)


def filters(
    state: Annotated[Literal["active", "acknowledged", "cleared", "closed"] | None, Query()] = None,
    priority: Annotated[int | None, Query(ge=1, le=4)] = None,
    zone: Annotated[str | None, Query(max_length=200)] = None,
    person: Annotated[int | None, Query(ge=-_I64, le=_I64)] = None,
    since: Annotated[str | None, _TIME] = None,
    until: Annotated[str | None, _TIME] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 100,
) -> IncidentFilters:
    times = query_times(since, until)
    return IncidentFilters(
        state=state,
        priority=priority,
        zone=zone or None,
        person=person,
        since=times.get("since"),
        until=times.get("until"),
        limit=limit,
    )


@router.get("/api/incidents")
def incidents(
    session: Viewer,
    f: Annotated[IncidentFilters, Depends(filters)],
    parts: Console = Depends(console_parts),  # noqa: B008
) -> JSONResponse:
    """{"incidents": [...]}, newest first (see the module)."""
    log = parts.log
    found: list[dict] = []
    if log is not None:
        try:
            found = query_incidents(log.path, f)
        except sqlite3.Error as e:
            raise HTTPException(503, f"cannot read the incidents: {e}") from None
    return JSONResponse({"incidents": found}, headers={"Cache-Control": "no-store"})


def _desk(request: Request) -> IncidentStep:
    desk = request.app.state.incidents.step
    if desk is None:
        raise HTTPException(503, "the incident book is not running yet")
    return desk


def _answer(desk: IncidentStep, act: Callable[[], IncidentRecord]) -> dict:
    try:
        rec = act()
    except UnknownIncidentError as e:
        raise HTTPException(404, str(e)) from None
    except IncidentError as e:
        raise HTTPException(422, str(e)) from None
    return {"incident": rec.to_dict(desk.wall_start)}


@router.post("/api/incidents/{incident_id}/ack", responses={403: {}, 404: {}})
def ack(
    incident_id: Annotated[int, Path(ge=0, le=_I64)], session: Operator, request: Request
) -> dict:
    """Acknowledge the incident as this user; {"incident": its record}."""
    desk = _desk(request)
    return _answer(desk, lambda: desk.acknowledge(incident_id, session.username))


@router.post("/api/incidents/{incident_id}/shelve", responses={403: {}, 404: {}, 422: {}})
def shelve(
    incident_id: Annotated[int, Path(ge=0, le=_I64)],
    body: Shelving,
    session: Operator,
    request: Request,
) -> dict:
    """Shelve the incident's hazard for duration_s (at most 8 h) with a reason."""
    desk = _desk(request)
    return _answer(
        desk, lambda: desk.shelve(incident_id, session.username, body.reason, body.duration_s)
    )


@router.get("/api/alarm-rates")
def alarm_rates(session: Viewer, request: Request) -> JSONResponse:
    """The operator's alarm load now (alarms.rates): notifications in the last 10 minutes
    and hour against the flood line, chattering and standing incidents, the open incidents
    by priority and state; `running` false (and no figures) before the incident book runs."""
    desk = request.app.state.incidents.step
    body = {"running": False} if desk is None else {"running": True, **desk.figures()}
    return JSONResponse(body, headers={"Cache-Control": "no-store"})
