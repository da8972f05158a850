"""The console's users over HTTP (admin): GET /api/users, POST /api/users, DELETE
/api/users/{name}, POST /api/users/{name}/password (an admin, or the user with their old
password, which is checked within the same limit on guesses as a login: a wrong one counts as a
failed login for that account and address, 429 beyond). Removing a user or changing a password
ends that user's sessions. New passwords follow web.users' policy (422 otherwise). Every
answer carries `Cache-Control: no-store`.
"""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Depends, HTTPException, Request, Response
from pydantic import BaseModel, Field

from stereopose.site.http.web import Console
from stereopose.web.auth import Admin, Session, Viewer, console_parts
from stereopose.web.login import NoStoreRoute, checked_password
from stereopose.web.users import User, UserError, check_password, role_at_least

router = APIRouter(tags=["users"], route_class=NoStoreRoute)


class UserOut(BaseModel):
    username: str
    role: Literal["viewer", "operator", "admin"]
    created: float
    changed: float


class NewUser(BaseModel):
    username: str = Field(max_length=64)
    password: str = Field(max_length=1024)
    role: Literal["viewer", "operator", "admin"]


class NewPassword(BaseModel):
    password: str = Field(max_length=1024)
    old_password: str | None = Field(default=None, max_length=1024)


def _out(u: User) -> UserOut:
    return UserOut(username=u.name, role=u.role, created=u.created, changed=u.changed)


@router.get("/api/users", response_model=list[UserOut])
def list_users(session: Admin, parts: Console = Depends(console_parts)) -> list[UserOut]:  # noqa: B008
    return [_out(u) for u in parts.users.users()]


@router.post("/api/users", response_model=UserOut, status_code=201, responses={409: {}, 422: {}})
def add_user(body: NewUser, session: Admin, parts: Console = Depends(console_parts)) -> UserOut:  # noqa: B008
    if parts.users.get(body.username) is not None:
        raise HTTPException(409, f"user {body.username!r} already exists")
    try:
        return _out(parts.users.add(body.username, body.password, body.role))
    except UserError as e:
        raise HTTPException(422, str(e)) from None


@router.delete(
    "/api/users/{name}", status_code=204, response_class=Response, responses={404: {}, 409: {}}
)
def remove_user(name: str, session: Admin, parts: Console = Depends(console_parts)) -> Response:  # noqa: B008
    if parts.users.get(name) is None:
        raise HTTPException(404, "no such user")
    admins = [u for u in parts.users.users() if u.role == "admin"]
    if [u.name for u in admins] == [name]:
        raise HTTPException(409, "the last admin cannot be removed")
    try:
        parts.users.remove(name)
    except UserError as e:
        raise HTTPException(404, str(e)) from None
    parts.sessions.end_user(name)
    return Response(status_code=204)


@router.post(
    "/api/users/{name}/password",
    status_code=204,
    response_class=Response,
    responses={403: {}, 404: {}, 422: {}, 429: {}},
)
def change_password(
    name: str,
    body: NewPassword,
    session: Viewer,
    request: Request,
    parts: Console = Depends(console_parts),  # noqa: B008
) -> Response:
    """An admin sets anyone's password; a user sets their own, giving the old one."""
    me: Session = session
    if not role_at_least(me.role, "admin"):
        if me.username != name:
            raise HTTPException(403, "this needs the admin role (or your own name)")
        if body.old_password is None:
            raise HTTPException(403, "the old password is wrong")
        try:
            check_password(body.password)  # a refused new one costs no guess
        except UserError as e:
            raise HTTPException(422, str(e)) from None
        if checked_password(parts, request, name, body.old_password) is None:
            raise HTTPException(403, "the old password is wrong")
    if parts.users.get(name) is None:
        raise HTTPException(404, "no such user")
    try:
        parts.users.set_password(name, body.password)
    except UserError as e:
        raise HTTPException(422, str(e)) from None
    parts.sessions.end_user(name)
    return Response(status_code=204)
