"""Hostile requests at the door: an ASGI middleware bounding request bodies and adding the
headers every answer carries.

uvicorn bounds the request line and headers (h11's incomplete-event limit, see
web.server); nothing bounds a body, so this does: a Content-Length above the limit is
answered 413 before the app runs, and a body without one (chunked) is counted as it is read.
"""

from __future__ import annotations

import json

from fastapi import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

MAX_BODY_BYTES = 1 << 20  # no route takes more than a small JSON document

# nosniff: a browser never runs an answer as another type; no-referrer: nothing of the
# service's URLs leaks to another site.
EXTRA_HEADERS = [(b"x-content-type-options", b"nosniff"), (b"referrer-policy", b"no-referrer")]
# over HTTPS: a browser that saw the console once never tries it in clear again for a year
HSTS = (b"strict-transport-security", b"max-age=31536000")


async def _answer(send: Send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", b"%d" % len(body))]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


def _content_length(scope: Scope) -> int | str | None:
    """The request's Content-Length; None without one; "bad" when it is not a number."""
    values = [v for k, v in scope.get("headers", []) if k == b"content-length"]
    if not values:
        return None
    text = values[0].decode("latin-1").strip()
    if len(values) > 1 or not text.isdigit() or len(text) > 19:
        return "bad"
    return int(text)


class RequestLimits:
    """Bodies above max_body_bytes refused with 413; EXTRA_HEADERS on every answer, and HSTS
    on every answer over HTTPS."""

    def __init__(self, app: ASGIApp, max_body_bytes: int = MAX_BODY_BYTES) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = _content_length(scope)
        if length == "bad":
            await _answer(send, 400, "Content-Length must be one decimal number")
            return
        if isinstance(length, int) and length > self.max_body_bytes:
            await _answer(send, 413, f"request body over {self.max_body_bytes} bytes")
            return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_body_bytes:  # caught by the app's exception handling
                    raise HTTPException(413, f"request body over {self.max_body_bytes} bytes")
            return message

        extra = [*EXTRA_HEADERS, HSTS] if scope.get("scheme") == "https" else EXTRA_HEADERS

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        await self.app(scope, limited_receive, send_with_headers)
