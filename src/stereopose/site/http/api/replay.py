"""GET /api/poses?since=&until=&max_frames=: the 3D poses of a past time window (Unix
seconds; at most site.replay.MAX_WINDOW_S long), thinned to at most `max_frames` frames
(default 600, at most site.replay.MAX_FRAMES), for the console's 3D replay of a ticket, a step
or any History window. For every logged-in user; 400 for a window that is not one, 503 where
the server keeps no poses."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi.responses import JSONResponse

from stereopose.errors import StereoposeError
from stereopose.site.http.web import Console
from stereopose.site.replay import MAX_FRAMES, read_window
from stereopose.web.auth import Viewer, console_parts

router = APIRouter(tags=["events"])

_TIME = Query(ge=0.0, le=2.0**33)


@router.get("/api/poses", responses={400: {}, 503: {}})
def poses(
    session: Viewer,
    since: Annotated[float, _TIME],
    until: Annotated[float, _TIME],
    max_frames: Annotated[int, Query(ge=1, le=MAX_FRAMES)] = 600,
    parts: Console = Depends(console_parts),  # noqa: B008
) -> JSONResponse:
    """{"since", "until", "frames": [{"wall_t", "t", "people": [{"id", "joints",
    "position", "posture"}]}], "skipped", "thinned"}."""
    folder = parts.poses_dir
    if folder is None:
        raise HTTPException(503, "this server keeps no 3D poses")
    try:
        window = read_window(folder, since, until, max_frames)
    except ValueError as e:
        raise HTTPException(400, str(e)) from None
    except StereoposeError as e:
        raise HTTPException(503, str(e)) from None
    return JSONResponse(window.as_dict(), headers={"Cache-Control": "no-store"})
