"""GET /api/calibration, POST /api/calibration/{camera}/accept: the rig kept calibrated.

The keeper (site.health.calib_keeper) places a drifted camera again from the people the other
cameras see. GET (any role): whether it runs, the cameras being placed again (samples, tries,
the reason one is not corrected), the poses proposed for an admin (`[serve]
calibration_auto = false`), the corrections made and the corrected file. POST accept (admin):
the proposed pose is applied at the next step; 404 when none is proposed for that camera.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, HTTPException, Path, Request
from fastapi.responses import JSONResponse

from stereopose.site.http.auth import Admin, Viewer

router = APIRouter(tags=["calibration"])

_NAME = Path(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.\-]+$")


def _keeper(request: Request):
    desk = request.app.state.calibration
    return None if desk is None else desk.keeper


@router.get("/api/calibration")
def calibration(session: Viewer, request: Request) -> JSONResponse:
    """{"running": bool, "auto", "cameras", "corrected", "file", "proposals"}."""
    keeper = _keeper(request)
    body = (
        {"running": False}
        if keeper is None
        else {"running": True, **keeper.figures(), "proposals": keeper.proposals()}
    )
    return JSONResponse(body, headers={"Cache-Control": "no-store"})


@router.post("/api/calibration/{camera}/accept", responses={403: {}, 404: {}, 503: {}})
def accept(camera: Annotated[str, _NAME], session: Admin, request: Request) -> dict:
    """Accept the pose proposed for `camera`: applied at the next step."""
    keeper = _keeper(request)
    if keeper is None:
        raise HTTPException(503, "the calibration keeper is not running yet")
    if not keeper.accept(camera, session.username):
        raise HTTPException(404, f"no pose is proposed for camera {camera}")
    return {"accepted": camera, "by": session.username}
