"""GET /api/live: the push channel (Server-Sent Events) of people, events, zones, cameras and
acknowledgements (site.live). At most the hub's max_clients streams, shared fairly: at
most STREAMS_PER_USER per user, a newer one ending that user's oldest; places kept for
operators and admins, a viewer's oldest stream ending for one when all are held; 503 with
Retry-After when none is free for this user. A stream ended for another gets `event: closed`
(`{"reason"}`) with `retry: ENDED_RETRY_MS`, so its page waits before trying again. A comment
line every HEARTBEAT_S keeps proxies and the browser from closing it; the stream ends when the
session does (logout, expiry, the user removed or changed) and when the service stops.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.responses import StreamingResponse

from stereopose.site.http.api.people import hub_of
from stereopose.site.http.web import Console
from stereopose.web.auth import Viewer, console_parts, request_token
from stereopose.web.users import role_at_least

router = APIRouter(tags=["live"])

HEARTBEAT_S = 15.0
SESSION_CHECK_S = 5.0
ENDED_RETRY_MS = 30_000


@router.get(
    "/api/live",
    response_class=StreamingResponse,
    responses={200: {"content": {"text/event-stream": {}}}, 503: {}},
)
async def live(
    request: Request,
    session: Viewer,
    parts: Console = Depends(console_parts),  # noqa: B008
) -> StreamingResponse:
    """event: people | event | zones | cameras | ack, each with its JSON as data."""
    hub = hub_of(parts)
    privileged = role_at_least(session.role, "operator")
    sub = hub.subscribe(asyncio.get_running_loop(), session.username, privileged)
    if sub is None:
        raise HTTPException(503, "too many live connections", headers={"Retry-After": "5"})
    token, _ = request_token(request)

    async def stream() -> AsyncIterator[bytes]:
        try:
            yield b"retry: 2000\n\n"
            beat = checked = time.monotonic()
            while not hub.closed:
                sub.wake.clear()
                if sub.ended is not None:
                    reason = json.dumps({"reason": sub.ended})
                    yield f"retry: {ENDED_RETRY_MS}\nevent: closed\ndata: {reason}\n\n".encode()
                    return
                messages = sub.take()
                if messages:
                    yield b"".join(messages)
                    beat = time.monotonic()
                else:
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(sub.wake.wait(), timeout=1.0)
                now = time.monotonic()
                if now - checked >= SESSION_CHECK_S:
                    checked = now
                    if parts.sessions.find(token or "") is None:
                        yield b"event: logout\ndata: {}\n\n"
                        return
                if now - beat >= HEARTBEAT_S:
                    beat = now
                    yield b": heartbeat\n\n"
        finally:
            hub.unsubscribe(sub)

    headers = {"Cache-Control": "no-store", "X-Accel-Buffering": "no"}
    return StreamingResponse(stream(), media_type="text/event-stream", headers=headers)
