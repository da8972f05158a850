"""GET /api/cameras and /api/cameras/{name}/snapshot.jpg: the cameras on the floor plan, their
health, and each one's newest picture with skeletons and ids drawn."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import JSONResponse, Response

from stereopose.site.http.api.people import hub_of
from stereopose.site.http.web import Console
from stereopose.web.auth import Viewer, console_parts

router = APIRouter(tags=["live"])


@router.get("/api/cameras")
def cameras(session: Viewer, parts: Console = Depends(console_parts)) -> JSONResponse:  # noqa: B008
    """{"cameras": [{"name", "position", "yaw_deg", "hfov_deg", "floor_fov", "image_size",
    "snapshot", "health"}]} (sync: the health probes run in the thread pool)."""
    return JSONResponse(hub_of(parts).cameras(), headers={"Cache-Control": "no-store"})


@router.get(
    "/api/cameras/{name:path}/snapshot.jpg",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}, 404: {}, 503: {}},
)
async def snapshot(name: str, session: Viewer, parts: Console = Depends(console_parts)) -> Response:  # noqa: B008
    """The camera's newest picture (JPEG); 404 for an unknown camera, 503 before a frame. The
    name is one percent-encoded segment; `{name:path}`, since a name may hold a `/`."""
    hub = hub_of(parts)
    if not hub.has_camera(name):
        raise HTTPException(404, "no such camera")
    shot = hub.snapshot(name)
    if shot is None:
        raise HTTPException(503, "no picture from this camera yet", headers={"Retry-After": "1"})
    jpeg, wall_t = shot
    headers = {"Cache-Control": "no-store", "X-Frame-Time": f"{wall_t:.3f}"}
    return Response(jpeg, media_type="image/jpeg", headers=headers)
