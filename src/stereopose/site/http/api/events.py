"""GET /api/events, GET /api/events.csv, POST /api/events/{id}/ack: the event log, newest
first, filtered; acknowledging an event (operator or admin) records who and when.

Filters: since, until (Unix seconds or ISO 8601, on the events' wall time), person, zone,
type, limit (default 100, at most 1000), before_id / after_id (paging by id). A bad value is
422 naming the parameter.
"""

from __future__ import annotations

import csv
import io
import sqlite3
from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Query, Request
from fastapi.responses import JSONResponse, Response

from stereopose.alarms.incident import IncidentError
from stereopose.io.sinks.incidents import incident_of_event
from stereopose.site.acks import AckError
from stereopose.site.eventlog import MAX_LIMIT, Filters, LogError, parse_time
from stereopose.site.http.web import Console
from stereopose.web.auth import Operator, Viewer, console_parts

router = APIRouter(tags=["events"])

_I64 = 2**63 - 1
CSV_COLUMNS = (
    "id",
    "time",
    "wall_t",
    "t",
    "frame",
    "person",
    "zone",
    "kind",
    "type",
    "level",
    "camera",
    "joint",
    "distance_m",
    "duration_s",
    "x",
    "y",
    "allowed",
    "lost",
    "restart",
    "ack_by",
    "ack_at",
    "clips",
)


_TIME = Query(max_length=64, description="Unix seconds or ISO 8601")


def query_times(since: str | None, until: str | None) -> dict[str, float]:
    """The since/until query values as Unix seconds (those given); 422 for a bad one."""
    times = {}
    for name, value in (("since", since), ("until", until)):
        if value is not None and value.strip():
            try:
                times[name] = parse_time(value, name)
            except ValueError as e:
                raise HTTPException(422, str(e)) from None
    return times


def page(
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 100,
    before_id: Annotated[int | None, Query(ge=0, le=_I64)] = None,
    after_id: Annotated[int | None, Query(ge=0, le=_I64)] = None,
) -> tuple[int, int | None, int | None]:
    """(limit, before_id, after_id) of a page of events."""
    return limit, before_id, after_id


def filters(
    since: Annotated[str | None, _TIME] = None,
    until: Annotated[str | None, _TIME] = None,
    person: Annotated[int | None, Query(ge=-_I64, le=_I64)] = None,
    zone: Annotated[str | None, Query(max_length=200)] = None,
    type: Annotated[str | None, Query(max_length=64)] = None,
    ticket: Annotated[str | None, Query(max_length=200)] = None,
    paged: Annotated[tuple[int, int | None, int | None], Depends(page)] = (100, None, None),
) -> Filters:
    times = query_times(since, until)
    limit, before_id, after_id = paged
    return Filters(
        since=times.get("since"),
        until=times.get("until"),
        person=person,
        zone=zone or None,
        type=type or None,
        ticket=ticket or None,
        limit=limit,
        before_id=before_id,
        after_id=after_id,
    )


def _query(parts: Console, f: Filters) -> list[dict]:
    if parts.log is None:
        return []
    try:
        return parts.log.query(f)
    except LogError as e:
        raise HTTPException(503, str(e)) from None


@router.get("/api/events")
def events(
    session: Viewer,
    f: Annotated[Filters, Depends(filters)],
    parts: Console = Depends(console_parts),  # noqa: B008
) -> JSONResponse:
    """{"events": [...]}, newest first: each with id, t, wall_t, frame, person, zone, kind,
    type, level (alarm, warning, info), camera, ack ({"by", "at"} or null) and clips."""
    return JSONResponse({"events": _query(parts, f)}, headers={"Cache-Control": "no-store"})


def _cell(value: object) -> object:
    if value is None:
        return ""
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, str) and value[:1] in ("=", "+", "-", "@", "\t", "\r"):
        return "'" + value  # never a formula in a spreadsheet
    return value


@router.get(
    "/api/events.csv", response_class=Response, responses={200: {"content": {"text/csv": {}}}}
)
def events_csv(
    session: Viewer,
    f: Annotated[Filters, Depends(filters)],
    parts: Console = Depends(console_parts),  # noqa: B008
) -> Response:
    """The same events as CSV (an attachment)."""
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(CSV_COLUMNS)
    for e in _query(parts, f):
        ack = e.get("ack") or {}
        row = {
            **e,
            "ack_by": ack.get("by"),
            "ack_at": ack.get("at"),
            "clips": " ".join(e.get("clips", [])),
        }
        writer.writerow([_cell(row.get(c)) for c in CSV_COLUMNS])
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    return Response(
        out.getvalue(),
        media_type="text/csv; charset=utf-8",
        headers={
            "Content-Disposition": f'attachment; filename="events-{stamp}.csv"',
            "Cache-Control": "no-store",
        },
    )


@router.post("/api/events/{event_id}/ack", responses={403: {}, 404: {}})
def ack(
    event_id: Annotated[int, Path(ge=0, le=_I64)],
    session: Operator,
    request: Request,
    parts: Console = Depends(console_parts),  # noqa: B008
) -> dict:
    """Acknowledge the event as this user (operator or admin); an event acknowledged before
    answers with its first acknowledgement. Its incident is acknowledged too (`incident`: its
    record; null when the event has none or it is no longer open)."""
    if parts.acks is None:
        raise HTTPException(404, "no such event")
    try:
        done = parts.acks.ack(event_id, session.username)
    except AckError as e:
        raise HTTPException(503, str(e)) from None
    if done is None:
        raise HTTPException(404, "no such event")
    record, made = done
    body = {
        "id": event_id,
        "ack": record,
        "incident": _ack_incident(request, parts, event_id, session.username),
    }
    if made and parts.hub is not None:
        parts.hub.publish("ack", body)
    return body


def _ack_incident(request: Request, parts: Console, event_id: int, by: str) -> dict | None:
    """The event's incident acknowledged in the running service's book (its record)."""
    desk = request.app.state.incidents.step
    log = parts.log
    if desk is None or log is None:
        return None
    try:
        incident = incident_of_event(log.path, event_id)
        return None if incident is None else desk.acknowledge(incident, by).to_dict()
    except (IncidentError, sqlite3.Error):  # closed and forgotten, or the log unreadable now
        return None
