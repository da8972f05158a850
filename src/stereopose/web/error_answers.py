"""Error answers that name no file of the server: the boundary between the library's
messages (which name their files, for the operator at the terminal and in the log) and an
HTTP client, who learns nothing of the server's folders from them.

Two exception handlers of the app: an HTTPException whose detail holds a path (a route
passing on a library error's message, such as the event log's "<path>: cannot read ...") is
answered with the same status, its headers and a generic detail; a StereoposeError that no
route caught is a 503 with a generic detail. Either way the full message goes to the log.
"""

from __future__ import annotations

import logging
import re

from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.responses import JSONResponse, Response
from starlette.exceptions import HTTPException

from stereopose.errors import StereoposeError
from stereopose.web.limits import EXTRA_HEADERS

logger = logging.getLogger(__name__)

# an absolute path (POSIX, home-relative or a Windows drive) starting a word of the text
_PATH = re.compile(r"""(?:^|[\s'"(\[=,])(?:~?/|[A-Za-z]:[\\/])[^\s'"]+""")
REFUSED = "refused (the reason is in the server's log)"
UNAVAILABLE = "the service cannot do this now (the reason is in its log)"


def names_a_path(text: str) -> bool:
    """Whether `text` holds an absolute file path."""
    return _PATH.search(text) is not None


def _generic(status: int) -> str:
    return UNAVAILABLE if status >= 500 else REFUSED


async def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    detail = exc.detail
    if isinstance(detail, str) and names_a_path(detail):
        logger.warning(
            "%s %s: answered %d without its detail: %s",
            request.method,
            request.url.path,
            exc.status_code,
            detail,
        )
        exc = HTTPException(exc.status_code, _generic(exc.status_code), headers=exc.headers)
    return await http_exception_handler(request, exc)


async def _library_error(request: Request, exc: Exception) -> Response:
    logger.error("%s %s: %s", request.method, request.url.path, exc)
    return JSONResponse({"detail": UNAVAILABLE}, status_code=503)


def add_handlers(app: FastAPI) -> None:
    """Both handlers on `app` (see the module)."""
    app.add_exception_handler(HTTPException, _http_error)
    app.add_exception_handler(StereoposeError, _library_error)


async def internal_error(request: Request, exc: Exception) -> JSONResponse:
    """An exception no handler took: 500 with a generic detail (the traceback is uvicorn's to
    log), with the headers every answer carries (web.limits)."""
    # answered outside the middleware (Starlette's outermost layer): its headers added here
    headers = {k.decode(): v.decode() for k, v in EXTRA_HEADERS}
    return JSONResponse({"detail": "internal error"}, status_code=500, headers=headers)
