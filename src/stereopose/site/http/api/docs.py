"""The OpenAPI page (/docs), served with its own Swagger UI files so it works offline.

FastAPI's default page loads Swagger UI from a CDN, which a closed control-room network cannot
reach. The files come from the fastapi-offline package (Swagger UI 5, which reads the OpenAPI
3.1 that FastAPI writes); the schema stays at /openapi.json, served here rather than by
FastAPI so that its info.version is the service's version only for a request that carries a
session (an anonymous client reads HIDDEN_VERSION).
"""

from __future__ import annotations

from pathlib import Path

import fastapi_offline
from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from stereopose.site.http.api.visitor import has_session

DOCS_URL = "/docs"
OPENAPI_URL = "/openapi.json"
HIDDEN_VERSION = "unpublished"  # info.version is required: a word that names no release
ASSETS_URL = "/docs/assets"
ASSETS_DIR = Path(fastapi_offline.__file__).parent / "static"

router = APIRouter(include_in_schema=False)


@router.get(DOCS_URL)
def swagger_ui(request: Request) -> HTMLResponse:
    """Swagger UI over this app's /openapi.json, every file from this server."""
    root = request.scope.get("root_path", "")
    return get_swagger_ui_html(
        openapi_url=f"{root}{OPENAPI_URL}",
        title=f"{request.app.title} - API",
        swagger_js_url=f"{root}{ASSETS_URL}/swagger-ui-bundle.js",
        swagger_css_url=f"{root}{ASSETS_URL}/swagger-ui.css",
        swagger_favicon_url=f"{root}{ASSETS_URL}/favicon.png",
        oauth2_redirect_url=None,
        # no validator badge: Swagger UI would fetch it from the validator's public site
        swagger_ui_parameters={"validatorUrl": None},
    )


@router.get(OPENAPI_URL)
def openapi(request: Request) -> JSONResponse:
    """The app's OpenAPI document; its version only with a session."""
    spec = request.app.openapi()  # built once, then cached by FastAPI
    if not has_session(request):
        spec = {**spec, "info": {**spec.get("info", {}), "version": HIDDEN_VERSION}}
    return JSONResponse(spec, headers={"Cache-Control": "no-store"})


def mount_docs(app: FastAPI) -> None:
    """The page, its files and /openapi.json on `app` (created with docs_url=None,
    redoc_url=None and openapi_url=None)."""
    app.include_router(router)
    app.mount(ASSETS_URL, StaticFiles(directory=ASSETS_DIR, check_dir=True), name="docs-assets")
