"""The site over the API: its zones, rules and postures read by anyone logged in, changed by an
admin, taken by the running service at its next step (site.site_desk).

- `GET /api/site` (any role): `{"version", "site"}`, `site` the site file's keys as JSON.
- `PUT /api/site` (admin; a cookie session sends its CSRF header) with `{"version", "site"}`:
  200 `{"version"}` once written and handed to the frame loop; 400 naming the key and the
  problem, nothing changed; 409 when `version` is not the current one.
- `GET /api/site/history`: the versions kept, newest first (`version`, `by`, `at`);
  `GET /api/site/history/{version}`: one of them with its site (404 when not kept).

503 while the service has no site file to edit (serve without a site).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from stereopose.errors import ConfigError
from stereopose.site.http.auth import Admin, Viewer
from stereopose.site.site_desk import SiteConflictError, SiteDesk

router = APIRouter(tags=["site"])

_VERSION = Path(min_length=1, max_length=64, pattern=r"^[0-9a-f]+$")


class SitePut(BaseModel):
    """A new site, and the version it was edited from."""

    version: str = Field(min_length=1, max_length=64)
    site: dict[str, Any]


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
