"""GET /api/people: the latest frame's people (site.live), for any logged-in user."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import JSONResponse

from stereopose.site.http.web import Console
from stereopose.web.auth import Viewer, console_parts

if TYPE_CHECKING:
    from stereopose.site.live import LiveHub

router = APIRouter(tags=["live"])


def hub_of(parts: Console) -> LiveHub:
    if parts.hub is None:
        raise HTTPException(503, "no live data on this server")
    return parts.hub


@router.get("/api/people")
def people(session: Viewer, parts: Console = Depends(console_parts)) -> JSONResponse:  # noqa: B008
    """{"frame", "t", "wall_t", "people": [{"id", "position", "heading_deg", "joints",
    "zones", "trail", "posture", "flags"}]}; frame null before the first frame."""
    return JSONResponse(hub_of(parts).people(), headers={"Cache-Control": "no-store"})
