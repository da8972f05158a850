"""GET /api/calibration, POST /api/calibration/{camera}/accept: the rig kept calibrated; the
surveyed points under /api/survey.

The keeper (site.health.calib_keeper) places a drifted camera again from the people the other
cameras see. GET (any role): whether it runs, the cameras being placed again (samples, tries,
the reason one is not corrected), the poses proposed for an admin (`[serve]
calibration_auto = false`), the corrections made and the corrected file. POST accept (admin):
the proposed pose is applied at the next step; 404 when none is proposed for that camera.

The surveyed points (site.health.survey_desk): `GET /api/survey` (any role) the
points file as JSON and the last solution not accepted; `PUT` (admin) `{"points": {name:
[x, y, z]}, "cameras": {camera: {name: [u, v]}}}` writes it (400 naming the key and the
problem); `POST .../solve` (admin) places every camera from it, on a thread of its own: each
camera's error and move, each click's residual, the cameras it cannot place and why (422 when
none can be); a solve longer than SOLVE_WAIT_S answers 202 and `GET .../solve` (any role)
gives it when done (202 meanwhile); `POST
.../accept` (admin) applies the solved rig at the next step (404: nothing solved; 409: a
running camera it does not place). 503 before the keeper runs.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Annotated

from fastapi import APIRouter, HTTPException, Path, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from stereopose.errors import CalibrationError, StereoposeError
from stereopose.web.auth import Admin, Viewer

if TYPE_CHECKING:
    from stereopose.site.health.calib_keeper import CalibrationKeeper
    from stereopose.site.health.survey_desk import SolveJob, SurveyDesk

router = APIRouter(tags=["calibration"])

_NAME = Path(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.\-]+$")


def _keeper(request: Request) -> CalibrationKeeper | None:
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


class PointsPut(BaseModel):
    """The surveyed points: their site coordinates, and where each camera sees them."""

    points: dict[str, list[float]] = Field(max_length=10_000)
    cameras: dict[str, dict[str, list[float]]] = Field(max_length=1_000)


def _survey(request: Request) -> SurveyDesk:
    desk = request.app.state.calibration
    survey = None if desk is None else desk.survey
    if survey is None:
        raise HTTPException(503, "the calibration keeper is not running yet")
    return survey


@router.get("/api/survey", responses={503: {}})
def points(session: Viewer, request: Request) -> JSONResponse:
    """{"file", "points", "cameras", "solved"}."""
    survey = _survey(request)
    try:
        body = survey.current()
    except CalibrationError as e:  # the file broken by hand: said, the console can save anew
        raise HTTPException(409, str(e)) from None
    return JSONResponse(body, headers={"Cache-Control": "no-store"})


@router.put("/api/survey", responses={400: {}, 403: {}, 503: {}})
def put_points(body: PointsPut, session: Admin, request: Request) -> dict:
    """The points file written: {"saved": true}."""
    try:
        _survey(request).put(body.model_dump())
    except CalibrationError as e:
        raise HTTPException(400, str(e)) from None
    return {"saved": True}


SOLVE_WAIT_S = 3.0  # a solve finished within this answers the POST itself; else 202
_POLL_S = 0.05


@router.post("/api/survey/solve", responses={202: {}, 403: {}, 422: {}, 503: {}})
async def solve_points(session: Admin, request: Request) -> JSONResponse:
    """Every camera placed from the points, on a thread of the desk's own: {"state":
    "solved", "job", "cameras", "residuals_px", "left_out", ...} when done within
    SOLVE_WAIT_S; else 202 {"state": "solving", "job"}, its answer then at GET (no worker
    of the server held meanwhile)."""
    survey = _survey(request)
    try:
        job = survey.start()
    except StereoposeError as e:  # no points file; scipy missing
        raise HTTPException(422, str(e)) from None
    for _ in range(int(SOLVE_WAIT_S / _POLL_S)):
        if job.done.is_set():
            break
        await asyncio.sleep(_POLL_S)
    return _job_answer(job)


@router.get("/api/survey/solve", responses={202: {}, 404: {}, 422: {}, 503: {}})
def solved_points(session: Viewer, request: Request) -> JSONResponse:
    """The last solve: 200 with its answer, 202 while it runs, 422 when it could place no
    camera, 404 when none was begun."""
    job = _survey(request).job()
    if job is None:
        raise HTTPException(404, "no solve begun: POST /api/survey/solve")
    return _job_answer(job)


def _job_answer(job: SolveJob) -> JSONResponse:
    headers = {"Cache-Control": "no-store"}
    if not job.done.is_set():
        return JSONResponse({"state": "solving", "job": job.number}, 202, headers=headers)
    if job.error is not None:
        raise HTTPException(422, job.error)
    summary = job.summary or {}  # a solve that ended without an error has its summary
    return JSONResponse({"state": "solved", "job": job.number, **summary}, headers=headers)


@router.post("/api/survey/accept", responses={403: {}, 404: {}, 409: {}, 503: {}})
def accept_points(session: Admin, request: Request) -> dict:
    """The solved rig applied at the next step: {"cameras", "by"}."""
    try:
        cameras = _survey(request).accept(session.username)
    except LookupError as e:
        raise HTTPException(404, str(e).strip("'")) from None
    except CalibrationError as e:
        raise HTTPException(409, str(e)) from None
    return {"cameras": cameras, "by": session.username}
