"""The control room's console page: GET / and /login (its index.html), /room/... (its own
files, from this package's controlroom/console folder) and /console/... (the site console's
style sheet, API calls and icon, so both consoles look and log in alike), with the site
console's headers (Content-Security-Policy `default-src 'self'`, X-Frame-Options DENY)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse, Response

from stereopose.site.http.api.page import CONSOLE_DIR, CONSOLE_URL
from stereopose.web.pages import PAGE_HEADERS, ConsoleFiles

__all__ = ["ROOM_DIR", "mount_page"]

ROOM_DIR = Path(__file__).resolve().parent / "console"
ROOM_URL = "/room"

router = APIRouter(include_in_schema=False)


def _index() -> Response:
    return FileResponse(
        ROOM_DIR / "index.html", media_type="text/html; charset=utf-8", headers=PAGE_HEADERS
    )


@router.get("/")
def root() -> Response:
    return _index()


@router.get("/login")
def login_page() -> Response:
    return _index()


def mount_page(app: FastAPI) -> None:
    app.include_router(router)
    for url, folder, name in ((ROOM_URL, ROOM_DIR, "room"), (CONSOLE_URL, CONSOLE_DIR, "console")):
        app.mount(
            url, ConsoleFiles(directory=folder, check_dir=False, follow_symlink=False), name=name
        )
