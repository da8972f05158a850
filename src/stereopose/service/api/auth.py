"""POST /api/login, POST /api/logout, GET /api/me: the console's sessions (service.auth).

A login answers the token (for `Authorization: Bearer`) and sets two cookies: the session
(HttpOnly, SameSite=Strict; Secure under TLS) and the CSRF value (readable by the page, which
sends it back as X-CSRF-Token on state-changing requests). A wrong name and a wrong password
get the same 401; too many failures from one address or for one name, 429 with Retry-After.
"""

from __future__ import annotations

import logging
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Request, Response
from pydantic import BaseModel, Field

from stereopose.service.auth import (
    CSRF_COOKIE,
    SESSION_COOKIE,
    Session,
    Viewer,
    authenticated,
    console_parts,
    request_token,
)
from stereopose.service.users import UserError

logger = logging.getLogger(__name__)

router = APIRouter(tags=["login"])


class Login(BaseModel):
    username: str = Field(max_length=64)
    password: str = Field(max_length=1024)


class LoginAnswer(BaseModel):
    """token: for `Authorization: Bearer`; csrf: the X-CSRF-Token value of this session."""

    token: str
    username: str
    role: Literal["viewer", "operator", "admin"]
    expires_at: float
    csrf: str


class Me(BaseModel):
    username: str
    role: Literal["viewer", "operator", "admin"]
    expires_at: float


def client_address(request: Request) -> str:
    return request.client.host if request.client else "unknown"


def _set_cookies(response: Response, request: Request, token: str, session: Session) -> None:
    secure = request.url.scheme == "https"
    max_age = max(1, int(session.expires_at - session.created))
    response.set_cookie(SESSION_COOKIE, token, max_age=max_age, path="/", secure=secure,
                        httponly=True, samesite="strict")  # fmt: skip
    response.set_cookie(CSRF_COOKIE, session.csrf, max_age=max_age, path="/", secure=secure,
                        httponly=False, samesite="strict")  # fmt: skip


_LOGIN_ERRORS = {401: {"description": "wrong name or password"},
                 429: {"description": "too many failed logins; see Retry-After"}}  # fmt: skip


@router.post("/api/login", response_model=LoginAnswer, responses=_LOGIN_ERRORS)
def login(body: Login, request: Request, response: Response,
          parts=Depends(console_parts)) -> LoginAnswer:  # noqa: B008  # fmt: skip
    """Log in (sync: the password hash runs in the thread pool)."""
    address, name = f"address:{client_address(request)}", f"name:{body.username}"
    wait = parts.limiter.retry_after(address, name)
    if wait is not None:
        raise HTTPException(429, "too many failed logins; try again later",
                            headers={"Retry-After": str(wait)})  # fmt: skip
    try:
        user = parts.users.verify(body.username, body.password)
    except UserError as e:
        logger.error("console: %s", e)
        raise HTTPException(503, "the console's users cannot be read (see the log)") from None
    if user is None:
        parts.limiter.failed(address, name)
        raise HTTPException(401, "wrong user name or password")
    parts.limiter.succeeded(name)
    token, session = parts.sessions.create(user)
    _set_cookies(response, request, token, session)
    response.headers["Cache-Control"] = "no-store"
    return LoginAnswer(token=token, username=user.name, role=user.role,
                       expires_at=session.expires_at, csrf=session.csrf)  # fmt: skip


@router.post("/api/logout", status_code=204, response_class=Response)
def logout(request: Request, session: Annotated[Session, Depends(authenticated)],
           parts=Depends(console_parts)) -> Response:  # noqa: B008  # fmt: skip
    """End this session; its cookies are cleared."""
    token, _ = request_token(request)
    if token:
        parts.sessions.end(token)
    response = Response(status_code=204)
    for name in (SESSION_COOKIE, CSRF_COOKIE):
        response.delete_cookie(name, path="/", samesite="strict",
                               secure=request.url.scheme == "https",
                               httponly=name == SESSION_COOKIE)  # fmt: skip
    return response


@router.get("/api/me", response_model=Me)
def me(session: Viewer) -> Me:
    """Who this session is."""
    return Me(username=session.username, role=session.role, expires_at=session.expires_at)
