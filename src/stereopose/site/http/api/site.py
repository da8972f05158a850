"""The site over the API: its zones, rules and postures read by anyone logged in, changed by an
admin, taken by the running service at its next step (site.site_desk).

- `GET /api/site` (any role): `{"version", "site"}`, `site` the site file's keys as JSON.
- `PUT /api/site` (admin; a cookie session sends its CSRF header) with `{"version", "site"}`:
  200 `{"version"}` once written and handed to the frame loop; 400 naming the key and the
  problem, nothing changed; 409 when `version` is not the current one.
- `GET /api/site/history`: the versions kept, newest first (`version`, `by`, `at`);
  `GET /api/site/history/{version}`: one of them with its site (404 when not kept).
- `POST /api/site/views` (any role) with `{"site"}` (optional: the running site): each zone's
  prism in every camera's picture (site.site_views), so a draft is seen before it is saved.
- `POST /api/site/floor` (any role) with `{"camera", "x", "y", "z"}` (x, y fractions of the
  picture; z metres, 0 the floor): `{"x", "y"}` where that ray meets the plane; 422 when it
  never does in front of the camera, 404 for an unknown camera.

- `GET /api/site/background` (any role): the plan's background drawing (PNG or JPEG; 404:
  none), `GET /api/site/background/placement`: `{"drawing": true, "points": [[u, v, x, y],
  [u, v, x, y]], "size": [w, h]}`, two points of the drawing (pixels) and where they are on
  the site (metres), or `{"drawing": false}` when the plan has none (a normal state);
  `PUT /api/site/background?points=u1,v1,x1,y1,u2,v2,x2,y2` (admin) with the image as the body
  (`image/png` or `image/jpeg`, at most 1 MiB): 400 naming the problem, nothing kept;
  `DELETE /api/site/background` (admin).

503 while the service has no site file to edit (serve without a site).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from stereopose.errors import ConfigError
from stereopose.fence.site import parse_site
from stereopose.site.site_desk import SiteConflictError, SiteDesk
from stereopose.site.site_views import floor_point, views
from stereopose.web.auth import Admin, Viewer

router = APIRouter(tags=["site"])

_VERSION = Path(min_length=1, max_length=64, pattern=r"^[0-9a-f]+$")


class SitePut(BaseModel):
    """A new site, and the version it was edited from."""

    version: str = Field(min_length=1, max_length=64)
    site: dict[str, Any]


class ViewsPost(BaseModel):
    """A site (None: the running one) to see in the cameras' pictures."""

    site: dict[str, Any] | None = None


class FloorPost(BaseModel):
    """A point of a camera's picture (fractions) and the height of the plane it lands on."""

    camera: str = Field(min_length=1, max_length=200)
    x: float = Field(ge=-1.0, le=2.0)
    y: float = Field(ge=-1.0, le=2.0)
    z: float = Field(default=0.0, ge=-100.0, le=100.0)


def _desk(request: Request) -> SiteDesk:
    desk = request.app.state.site
    if desk is None:
        raise HTTPException(503, "this service has no site file to edit")
    return desk


@router.get("/api/site")
def get_site(session: Viewer, request: Request) -> JSONResponse:
    """{"version", "site"}: the running site."""
    return JSONResponse(_desk(request).current(), headers={"Cache-Control": "no-store"})


@router.put("/api/site", responses={400: {}, 403: {}, 409: {}, 503: {}})
def put_site(body: SitePut, session: Admin, request: Request) -> dict:
    """The new site, written and taken at the next step: {"version"}."""
    desk = _desk(request)
    try:
        version = desk.put(body.site, body.version, session.username)
    except SiteConflictError as e:
        raise HTTPException(409, str(e)) from None
    except ConfigError as e:
        raise HTTPException(400, str(e)) from None
    except OSError as e:
        raise HTTPException(503, f"the site file cannot be written: {e.strerror}") from None
    return {"version": version}


@router.get("/api/site/history")
def history(session: Viewer, request: Request) -> dict:
    """{"versions": [{"version", "by", "at"}, ...]}, newest first."""
    return {"versions": _desk(request).history()}


@router.get("/api/site/history/{version}", responses={404: {}})
def one_version(version: Annotated[str, _VERSION], session: Viewer, request: Request) -> dict:
    """{"version", "by", "at", "site"}."""
    found = _desk(request).at_version(version)
    if found is None:
        raise HTTPException(404, f"version {version} is not kept")
    return found


@router.post("/api/site/views", responses={400: {}, 503: {}})
def site_views(body: ViewsPost, session: Viewer, request: Request) -> dict:
    """{"cameras": [{"name", "size", "zones": [{"name", "kind", "lines"}]}]}."""
    desk = _desk(request)
    if desk.rig is None:
        raise HTTPException(503, "this service has no cameras to show the site in")
    try:
        site = parse_site(body.site) if body.site is not None else desk.site
    except ConfigError as e:
        raise HTTPException(400, str(e)) from None
    return views(site, desk.rig)


@router.post("/api/site/floor", responses={404: {}, 422: {}, 503: {}})
def site_floor(body: FloorPost, session: Viewer, request: Request) -> dict:
    """{"x", "y"}: where the picture's point lands at height z."""
    desk = _desk(request)
    camera = next((c for c in desk.rig or () if c.name == body.camera), None)
    if camera is None:
        raise HTTPException(404, "no such camera")
    point = floor_point(camera, body.x, body.y, body.z)
    if point is None:
        raise HTTPException(422, "that point of the picture never reaches the plane in front")
    return {"x": round(point[0], 4), "y": round(point[1], 4)}


@router.get("/api/site/background", responses={404: {}, 503: {}})
def background(session: Viewer, request: Request) -> Response:
    """The plan's background drawing."""
    found = _desk(request).background.image()
    if found is None:
        raise HTTPException(404, "the plan has no background drawing")
    data, media = found
    return Response(data, media_type=media, headers={"Cache-Control": "no-store"})


@router.get("/api/site/background/placement", responses={503: {}})
def background_placement(session: Viewer, request: Request) -> dict:
    """{"drawing": true, "points": [[u, v, x, y], [u, v, x, y]], "size": [w, h]}; a plan
    with no drawing (the usual state, not an error): {"drawing": false}."""
    found = _desk(request).background.placement()
    if found is None:
        return {"drawing": False}
    return {"drawing": True, **found}


@router.put("/api/site/background", responses={400: {}, 403: {}, 503: {}})
async def put_background(
    session: Admin, request: Request, points: Annotated[str, Query(max_length=400)]
) -> dict:
    """The drawing (the body) and where it lies: its placement."""
    desk = _desk(request)
    try:
        numbers = [float(v) for v in points.split(",")]
    except ValueError:
        raise HTTPException(400, "points: 8 numbers separated by commas") from None
    try:
        return desk.background.put(await request.body(), numbers)
    except ConfigError as e:
        raise HTTPException(400, str(e)) from None


@router.delete("/api/site/background", responses={403: {}, 404: {}, 503: {}})
def delete_background(session: Admin, request: Request) -> dict:
    """The drawing taken away."""
    if not _desk(request).background.delete():
        raise HTTPException(404, "the plan has no background drawing")
    return {"deleted": True}
