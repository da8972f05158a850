"""POST /api/login, POST /api/logout, GET /api/me: the console's sessions (web.auth).

A login answers the token (for `Authorization: Bearer`) and sets two cookies: the session
(HttpOnly, SameSite=Strict; Secure under TLS) and the CSRF value (readable by the page, which
sends it back as X-CSRF-Token on state-changing requests). A wrong name and a wrong password
get the same 401; too many failed attempts from one address, or for one name from an address
that failed for it, 429 with Retry-After (stereopose.login_limit). Every answer of these routes
(and of the users' routes) carries `Cache-Control: no-store`: they hold users and sessions.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Coroutine
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Request, Response
from fastapi.routing import APIRoute
from pydantic import BaseModel, Field

from stereopose.errors import HashingBusyError
from stereopose.web.auth import (
    CSRF_COOKIE,
    SESSION_COOKIE,
    LoginParts,
    Session,
    SessionsFullError,
    TooManyAttemptsError,
    Viewer,
    authenticated,
    console_parts,
    request_token,
)
from stereopose.web.users import Role, User, UserError

logger = logging.getLogger(__name__)


class NoStoreRoute(APIRoute):
    """A route whose every answer, an error too, carries `Cache-Control: no-store`."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def no_store(request: Request) -> Response:
            try:
                response = await handler(request)
            except HTTPException as e:
                e.headers = {**(e.headers or {}), "Cache-Control": "no-store"}
                raise
            response.headers["Cache-Control"] = "no-store"
            return response

        return no_store


router = APIRouter(tags=["login"], route_class=NoStoreRoute)


class Login(BaseModel):
    username: str = Field(max_length=64)
    password: str = Field(max_length=1024)


class LoginAnswer(BaseModel):
    """token: for `Authorization: Bearer`; csrf: the X-CSRF-Token value of this session."""

    token: str
    username: str
    role: Role
    expires_at: float
    csrf: str


class Me(BaseModel):
    username: str
    role: Role
    expires_at: float


def client_address(request: Request) -> str:
    return request.client.host if request.client else "unknown"


def _set_cookies(response: Response, request: Request, token: str, session: Session) -> None:
    secure = request.url.scheme == "https"
    max_age = max(1, int(session.expires_at - session.created))
    response.set_cookie(
        SESSION_COOKIE,
        token,
        max_age=max_age,
        path="/",
        secure=secure,
        httponly=True,
        samesite="strict",
    )
    response.set_cookie(
        CSRF_COOKIE,
        session.csrf,
        max_age=max_age,
        path="/",
        secure=secure,
        httponly=False,
        samesite="strict",
    )


_LOGIN_ERRORS: dict[int | str, dict[str, object]] = {
    401: {"description": "wrong name or password"},
    429: {"description": "too many failed logins; see Retry-After"},
    503: {
        "description": "no session place, too many logins under way (see "
        "Retry-After), or the users unreadable"
    },
}


def checked_password(parts: LoginParts, request: Request, name: str, password: str) -> User | None:
    """The user when `password` is `name`'s, else None, within the limit on guesses (429
    when over it: nothing checked); 503 when the users cannot be read."""
    try:
        attempt = parts.limiter.begin(f"address:{client_address(request)}", name)
    except TooManyAttemptsError as e:
        raise HTTPException(
            429, f"{e.why}; try again later", headers={"Retry-After": str(e.retry_after)}
        ) from None
    not_failed = False
    try:
        user = parts.users.verify_admitted(name, password)
        not_failed = user is not None
    except HashingBusyError:
        not_failed = True  # nothing was checked: no failure counted against anyone
        raise HTTPException(
            503, "too many logins under way; try again in a moment", headers={"Retry-After": "2"}
        ) from None
    except UserError as e:
        not_failed = True  # the users cannot be read: no password was tried
        logger.error("console: %s", e)
        raise HTTPException(503, "the console's users cannot be read (see the log)") from None
    finally:
        parts.limiter.end(attempt, not_failed)
    return user


@router.post("/api/login", response_model=LoginAnswer, responses=_LOGIN_ERRORS)
def login(
    body: Login,
    request: Request,
    response: Response,
    parts: LoginParts = Depends(console_parts),  # noqa: B008
) -> LoginAnswer:
    """Log in (sync: the password hash runs in the thread pool)."""
    user = checked_password(parts, request, body.username, body.password)
    if user is None:
        raise HTTPException(401, "wrong user name or password")
    try:
        token, session = parts.sessions.create(user)
    except SessionsFullError as e:
        logger.warning("console: %s not logged in: %s", user.name, e)
        raise HTTPException(
            503, "no session place is free now; try again later", headers={"Retry-After": "60"}
        ) from None
    _set_cookies(response, request, token, session)
    return LoginAnswer(
        token=token,
        username=user.name,
        role=user.role,
        expires_at=session.expires_at,
        csrf=session.csrf,
    )


@router.post("/api/logout", status_code=204, response_class=Response)
def logout(
    request: Request,
    session: Annotated[Session, Depends(authenticated)],
    parts: LoginParts = Depends(console_parts),  # noqa: B008
) -> Response:
    """End this session; its cookies are cleared."""
    token, _ = request_token(request)
    if token:
        parts.sessions.end(token)
    response = Response(status_code=204)
    for name in (SESSION_COOKIE, CSRF_COOKIE):
        response.delete_cookie(
            name,
            path="/",
            samesite="strict",
            secure=request.url.scheme == "https",
            httponly=name == SESSION_COOKIE,
        )
    return response


@router.get("/api/me", response_model=Me)
def me(session: Viewer) -> Me:
    """Who this session is."""
    return Me(username=session.username, role=session.role, expires_at=session.expires_at)
