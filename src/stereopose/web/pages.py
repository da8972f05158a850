"""A console page's answers: the headers every page and file carries (Content-Security-Policy
`default-src 'self'`: no inline script, no other site; X-Frame-Options DENY), and the console's
static files served with them (`ConsoleFiles`: no directory listings, no links followed out).
Used by the site's console (site.http.api.page) and the control room's (controlroom.page)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fastapi.staticfiles import StaticFiles
from starlette.types import Receive, Scope, Send

if TYPE_CHECKING:
    from starlette.types import Message

__all__ = ["CSP", "PAGE_HEADERS", "ConsoleFiles"]

CSP = (
    "default-src 'self'; img-src 'self' data: blob:; media-src 'self' blob:; "
    "style-src 'self'; script-src 'self'; connect-src 'self'; object-src 'none'; "
    "frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
)
# Referrer-Policy and nosniff: on every answer (web.limits)
PAGE_HEADERS = {
    "Content-Security-Policy": CSP,
    "X-Frame-Options": "DENY",
    "Cache-Control": "no-cache",
}


class ConsoleFiles(StaticFiles):
    """StaticFiles with the page's headers; no directory listings, no links followed out."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                extra = [(k.lower().encode(), v.encode()) for k, v in PAGE_HEADERS.items()]
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        await super().__call__(scope, receive, with_headers)
