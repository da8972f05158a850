"""The site's tickets (stereopose.tickets): GET /api/tickets, GET /api/tickets/{id},
POST /api/tickets (a ticket as its file's keys, JSON, or the ticket file itself, TOML),
POST /api/tickets/{id}/start, POST /api/tickets/{id}/end (body {"aborted": bool}, optional)
and POST /api/tickets/{id}/bind (body {"role": "operator" | "supervisor", "person": id}).
GET /api/tickets/{id}/report: its report, an HTML file (viz.report_ticket).

Reading is for every user; the acts are an operator's or an admin's (a viewer 403). A start
or an end takes effect at the frame loop's next step (`starting` / `ending` until then).
400: a ticket that is not one (the problem named), or naming a zone the site lacks; 404: no
such ticket; 409: an act its state forbids (starting an active one, ending an ended one, a
ticket id taken); 503: no site (no zones: no tickets).
"""

from __future__ import annotations

import json
import logging
import re
import time
from collections.abc import Callable
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Path, Request
from fastapi.responses import HTMLResponse, JSONResponse
from pydantic import BaseModel, Field

from stereopose.config import parse_toml
from stereopose.errors import ConfigError, StereoposeError
from stereopose.site.http.web import Console
from stereopose.site.replay import MAX_WINDOW_S, read_window
from stereopose.tickets import TicketDesk, TicketError, parse_ticket
from stereopose.web.auth import Operator, Viewer, console_parts

router = APIRouter(tags=["tickets"])
logger = logging.getLogger(__name__)

_ID = Path(min_length=1, max_length=200)
_I64 = 2**63 - 1


class Ending(BaseModel):
    aborted: bool = False


class Binding(BaseModel):
    role: Literal["operator", "supervisor"]
    person: int = Field(ge=0, le=_I64)


def _desk(request: Request) -> TicketDesk:
    desk = request.app.state.tickets
    if desk is None:
        raise HTTPException(503, "no site file: tickets need its zones")
    return desk


def _act(act: Callable[[], object]) -> dict:
    try:
        return {"ticket": act()}
    except TicketError as e:
        raise HTTPException(e.status, str(e)) from None
    except ConfigError as e:
        raise HTTPException(400, str(e)) from None


@router.get("/api/tickets")
def tickets(session: Viewer, request: Request) -> JSONResponse:
    """{"tickets": [...]}: every ticket kept, with its state and progress."""
    return JSONResponse(
        {"tickets": _desk(request).tickets()}, headers={"Cache-Control": "no-store"}
    )


@router.get("/api/tickets/{ticket_id}", responses={404: {}})
def ticket(ticket_id: Annotated[str, _ID], session: Viewer, request: Request) -> JSONResponse:
    """{"ticket": ...}: its steps' states, roles, deviations and (ended) its result."""
    return JSONResponse(
        _act(lambda: _desk(request).ticket(ticket_id)), headers={"Cache-Control": "no-store"}
    )


_TOML_TYPES = ("application/toml", "text/plain")


@router.post(
    "/api/tickets",
    status_code=201,
    responses={400: {}, 403: {}, 409: {}, 415: {}},
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {"schema": {"type": "object"}},
                "application/toml": {"schema": {"type": "string"}},
            },
        }
    },
)
async def add(session: Operator, request: Request) -> dict:
    """A new ticket, planned: {"ticket": ...}. The body is the ticket file's keys as JSON, or
    the ticket file itself (Content-Type application/toml or text/plain)."""
    desk = _desk(request)
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    raw = await request.body()
    where = "the posted ticket"
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise HTTPException(400, f"{where}: not UTF-8 text") from None
    if kind in _TOML_TYPES:
        try:
            doc = parse_toml(text, where)
        except ConfigError as e:
            raise HTTPException(400, str(e)) from None
    elif kind in ("application/json", ""):
        try:
            doc = json.loads(text)
        except (ValueError, RecursionError):
            raise HTTPException(400, f"{where}: not valid JSON") from None
        if not isinstance(doc, dict):
            raise HTTPException(400, f"{where}: expected a JSON object of the ticket's keys")
    else:
        raise HTTPException(415, "post the ticket as application/json or application/toml")
    return _act(lambda: desk.add(parse_ticket(doc, where)))


@router.get("/api/tickets/{ticket_id}/report", responses={404: {}})
def report(
    ticket_id: Annotated[str, _ID],
    session: Viewer,
    request: Request,
    parts: Console = Depends(console_parts),  # noqa: B008
) -> HTMLResponse:
    """The ticket's report, one self-contained HTML file (viz.report_ticket): its steps on a
    timeline, who did them, when, how long and where, its deviations and a 3D replay of the
    job from the stored poses. Sent as a download (ticket-<id>.html)."""
    from stereopose.viz.report_ticket import MAX_REPORT_FRAMES, ticket_report

    desk = _desk(request)
    view = _act(lambda: desk.ticket(ticket_id))["ticket"]
    frames: list[dict] = []
    folder = parts.poses_dir
    since, until = view.get("started_wall"), view.get("ended_wall") or time.time()
    if folder is not None and since is not None:
        since = max(since - 1.0, until - MAX_WINDOW_S)  # a long job: its last hours
        try:
            frames = read_window(folder, since, until + 1.0, MAX_REPORT_FRAMES).frames
        except (ValueError, StereoposeError) as e:
            logger.warning("ticket %s: its report without the 3D replay: %s", ticket_id, e)
    text = ticket_report(view, desk.zones, frames, desk.wall_start)
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", ticket_id)[:100]
    return HTMLResponse(
        text,
        headers={
            "Cache-Control": "no-store",
            "Content-Disposition": f'attachment; filename="ticket-{name}.html"',
        },
    )


@router.post("/api/tickets/{ticket_id}/start", responses={403: {}, 404: {}, 409: {}})
def start(ticket_id: Annotated[str, _ID], session: Operator, request: Request) -> dict:
    """Start a planned ticket (active from the next step)."""
    desk = _desk(request)
    return _act(lambda: desk.start(ticket_id, session.username))


@router.post("/api/tickets/{ticket_id}/end", responses={403: {}, 404: {}, 409: {}})
def end(
    ticket_id: Annotated[str, _ID],
    session: Operator,
    request: Request,
    body: Ending | None = None,
) -> dict:
    """End a ticket: completed (its ticket_completed event with the result), or aborted."""
    desk = _desk(request)
    aborted = body.aborted if body is not None else False
    return _act(lambda: desk.end(ticket_id, session.username, aborted))


@router.post("/api/tickets/{ticket_id}/bind", responses={400: {}, 403: {}, 404: {}, 409: {}})
def bind(
    ticket_id: Annotated[str, _ID], body: Binding, session: Operator, request: Request
) -> dict:
    """Bind a role of the ticket to a tracked person (the binding follows the person's id)."""
    desk = _desk(request)
    return _act(lambda: desk.bind(ticket_id, body.role, body.person))
