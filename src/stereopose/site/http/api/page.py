"""The console's page: GET / and /login (its index.html), GET /console/... (its files, from
the package's site/console folder), /console/plotly.min.js (from the plotly package). Open
without login: the page logs in through /api/login.

Every answer carries Content-Security-Policy `default-src 'self'` (no inline script, no other
site), X-Frame-Options DENY and Referrer-Policy no-referrer. A path that leaves the folder
(.., encoded or not, an absolute path, a link out) is 404.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI, HTTPException
from fastapi.responses import FileResponse, HTMLResponse, Response

from stereopose.web.pages import PAGE_HEADERS, ConsoleFiles

CONSOLE_DIR = Path(__file__).resolve().parent.parent / "console"
CONSOLE_URL = "/console"
PLACEHOLDER = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>stereopose console</title></head>
<body><h1>stereopose</h1><p>The console's page is not installed. The API is at
<a href="/docs">/docs</a>.</p></body></html>
"""

router = APIRouter(include_in_schema=False)


def plotly_js() -> Path | None:
    try:
        import plotly
    except ImportError:
        return None
    path = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
    return path if path.is_file() else None


def _index() -> Response:
    index = CONSOLE_DIR / "index.html"
    if index.is_file():
        return FileResponse(index, media_type="text/html; charset=utf-8", headers=PAGE_HEADERS)
    return HTMLResponse(PLACEHOLDER, headers=PAGE_HEADERS)


@router.get("/")
def root() -> Response:
    return _index()


@router.get("/login")
def login_page() -> Response:
    return _index()


@router.get(f"{CONSOLE_URL}/plotly.min.js")
def plotly_min_js() -> Response:
    path = plotly_js()
    if path is None:
        raise HTTPException(404, "plotly is not installed")
    return FileResponse(
        path,
        media_type="text/javascript; charset=utf-8",
        headers={**PAGE_HEADERS, "Cache-Control": "max-age=86400"},
    )


def mount_page(app: FastAPI) -> None:
    app.include_router(router)
    app.mount(
        CONSOLE_URL,
        ConsoleFiles(directory=CONSOLE_DIR, check_dir=False, follow_symlink=False),
        name="console",
    )
