"""Who asks: whether a request carries a live console session, for the open routes that show
more to a logged-in user than to anyone (the version: health, metrics, the OpenAPI document).

Never refuses: an open route answers everyone, and tells less to an anonymous client.
"""

from __future__ import annotations

import logging

from fastapi import Request

from stereopose.errors import StereoposeError
from stereopose.web.auth import request_token

logger = logging.getLogger(__name__)


def has_session(request: Request) -> bool:
    """Whether the request's bearer token or session cookie names a live session."""
    parts = request.app.state.console
    sessions = None if parts is None else parts.sessions
    if sessions is None:
        return False
    token, _ = request_token(request)
    if not token:
        return False
    try:
        return sessions.find(token) is not None
    except StereoposeError as e:  # users.json damaged: nobody is logged in (said elsewhere)
        logger.debug("session check: %s", e)
        return False
