"""GET /api/zones: each zone of the site, its state (free, occupied, alarm) and occupants."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse

from stereopose.site.http.api.people import hub_of
from stereopose.site.http.web import Console
from stereopose.web.auth import Viewer, console_parts

router = APIRouter(tags=["live"])


@router.get("/api/zones")
def zones(session: Viewer, parts: Console = Depends(console_parts)) -> JSONResponse:  # noqa: B008
    """{"zones": [{"name", "kind", "polygon", "z", "margin_m", "state", "occupants"}]}."""
    return JSONResponse(hub_of(parts).zones(), headers={"Cache-Control": "no-store"})
