"""The warnings on site (stereopose.onsite): what sounds now, and an admin's hand on them.

GET /api/warnings: {"outputs": [...], "warnings": [...], "calls": [...], "silenced": [...]},
each speaker and signal with its health ("up", "down", "unknown", "not verifiable"), its
silence and what it gives now; every user (all empty without warnings on site).

POST /api/warnings/{output}/silence, body {"minutes": 1-1440, "reason": "..."}: the output
silent for that time (admin). DELETE /api/warnings/{output}/silence: silent no more (admin).
POST /api/warnings/{output}/test: a speaker says "this is a test", a signal pulses its coils
(admin). Each act is logged as an event at the next step (onsite.control). 404: no such
output; 409: a test while the output warns or is silenced; 503: no warnings on this site (the
acts).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from stereopose.onsite.control import MAX_REASON, ControlError
from stereopose.onsite.service import OnSite
from stereopose.site.handover import Handover
from stereopose.web.auth import Admin, Viewer

router = APIRouter(tags=["warnings"])

_NAME = Path(min_length=1, max_length=200)


class Silencing(BaseModel):
    minutes: float = Field(gt=0, le=1440)
    reason: str = Field(min_length=1, max_length=MAX_REASON)


class WarningsDesk(Handover[OnSite]):
    """The API's way to the running service's warnings on site: attached once the frame loop
    has built them (None until then, or without a site; site.handover)."""

    @property
    def onsite(self) -> OnSite | None:
        """The warnings on site running (None: not yet, none, or closed)."""
        return self.current


def _onsite(request: Request) -> OnSite:
    desk = request.app.state.warnings
    onsite = desk.onsite if desk is not None else None
    if onsite is None:
        raise HTTPException(503, "no warnings on site: the site file has no [warnings]")
    return onsite


def _act(act: Callable[[], dict]) -> dict:
    try:
        return act()
    except ControlError as e:
        raise HTTPException(e.status, str(e)) from None


@router.get("/api/warnings")
def warnings(session: Viewer, request: Request) -> JSONResponse:
    """What warns on site now, and each output's state (see the module); all empty where
    the site has no warnings on site."""
    desk = request.app.state.warnings
    onsite = desk.onsite if desk is not None else None
    doc = (
        {"outputs": onsite.outputs(), **onsite.now()}
        if onsite is not None
        else {"outputs": [], "warnings": [], "calls": [], "silenced": []}
    )
    return JSONResponse(doc, headers={"Cache-Control": "no-store"})


@router.post("/api/warnings/{output}/silence", responses={403: {}, 404: {}, 503: {}})
def silence(
    output: Annotated[str, _NAME], body: Silencing, session: Admin, request: Request
) -> dict:
    """Silence a speaker or a signal for `minutes`, with a reason: {"silenced": ...}."""
    onsite = _onsite(request)
    return _act(
        lambda: {
            "silenced": onsite.controls.silence(
                output, body.minutes * 60.0, body.reason, session.username
            ).as_dict()
        }
    )


@router.delete("/api/warnings/{output}/silence", responses={403: {}, 404: {}, 503: {}})
def lift(output: Annotated[str, _NAME], session: Admin, request: Request) -> dict:
    """End a silence now: {"lifted": ...}."""
    onsite = _onsite(request)
    return _act(lambda: {"lifted": onsite.controls.lift(output, session.username).as_dict()})


@router.post("/api/warnings/{output}/test", status_code=202, responses={403: {}, 404: {}, 409: {}})
def test(output: Annotated[str, _NAME], session: Admin, request: Request) -> dict:
    """Test a speaker (the test message, once) or a signal (its coils pulsed) at the next
    step: {"tested": name}."""
    onsite = _onsite(request)
    return _act(lambda: (onsite.test(output, session.username), {"tested": output})[1])
