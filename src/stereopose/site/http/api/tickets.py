"""The site's tickets (stereopose.tickets): GET /api/tickets, GET /api/tickets/{id},
POST /api/tickets (a ticket as its file's keys, JSON), POST /api/tickets/{id}/start,
POST /api/tickets/{id}/end (body {"aborted": bool}, optional) and
POST /api/tickets/{id}/bind (body {"role": "operator" | "supervisor", "person": id}).

Reading is for every user; the acts are an operator's or an admin's (a viewer 403). A start
or an end takes effect at the frame loop's next step (`starting` / `ending` until then).
400: a ticket that is not one (the problem named), or naming a zone the site lacks; 404: no
such ticket; 409: an act its state forbids (starting an active one, ending an ended one, a
ticket id taken); 503: no site (no zones: no tickets).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, HTTPException, Path, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from stereopose.errors import ConfigError
from stereopose.site.http.auth import Operator, Viewer
from stereopose.tickets import TicketDesk, TicketError, parse_ticket

router = APIRouter(tags=["tickets"])

_ID = Path(min_length=1, max_length=200)
_I64 = 2**63 - 1


class Ending(BaseModel):
    aborted: bool = False


class Binding(BaseModel):
    role: Literal["operator", "supervisor"]
    person: int = Field(ge=0, le=_I64)


def _desk(request: Request) -> TicketDesk:
    desk = getattr(request.app.state, "tickets", None)
    if desk is None:
        raise HTTPException(503, "no site file: tickets need its zones")
    return desk


def _act(act) -> dict:
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


@router.post("/api/tickets", status_code=201, responses={400: {}, 403: {}, 409: {}})
def add(body: Annotated[dict[str, Any], Body()], session: Operator, request: Request) -> dict:
    """A new ticket, planned: {"ticket": ...}."""
    desk = _desk(request)
    return _act(lambda: desk.add(parse_ticket(body, "the posted ticket")))


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
