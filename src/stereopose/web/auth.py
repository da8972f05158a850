"""Who is asking: login sessions, bearer tokens, CSRF, role checks (the login rate limit is
stereopose.login_limit's).

- A login gives a random token (secrets.token_urlsafe) and a CSRF value. The server keeps
  only the token's SHA-256 (in memory, at most SESSIONS_PER_USER per user, their own oldest
  ending first, and MAX_SESSIONS in all, shared fairly: see Sessions); a session ends at its
  absolute expiry (12 h), after IDLE_S without a request, at logout, and as soon as its user
  is removed or their password or role changes (the user's stamp differs).
- Every /api/ route but the open ones asks for a session: the cookie `stereopose_session` or
  `Authorization: Bearer <token>`; 401 otherwise. A state-changing request (POST, PUT, PATCH,
  DELETE) authenticated by the cookie must carry `X-CSRF-Token` equal to the session's CSRF
  value (403 otherwise): another site's page can make the browser send the cookie, never read
  the CSRF cookie. A bearer token is never sent by a browser on its own, so it needs none.
- Password guesses are limited by client address first, then per account, each attempt
  counted before its password is checked (stereopose.login_limit.LoginLimiter).
- Nothing secret is logged: neither passwords nor tokens (a session is named by its user).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Protocol

from fastapi import Depends, HTTPException, Request

from stereopose.login_limit import LoginLimiter, TooManyAttemptsError
from stereopose.web.users import ROLES, Role, User, UserError, UserStore, role_at_least

__all__ = [
    "LoginLimiter",
    "Logins",
    "Session",
    "Sessions",
    "SessionsFullError",
    "TooManyAttemptsError",
    "authenticated",
    "console_parts",
    "request_token",
    "require",
]

logger = logging.getLogger(__name__)

SESSION_COOKIE = "stereopose_session"
CSRF_COOKIE = "stereopose_csrf"
CSRF_HEADER = "x-csrf-token"
LIFETIME_S = 12 * 3600.0
IDLE_S = 2 * 3600.0
MAX_SESSIONS = 1000
SESSIONS_PER_USER = 10
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


@dataclass
class Session:
    """One login. token: given once at login, never kept (only its digest, the key)."""

    username: str
    role: Role
    stamp: str
    csrf: str
    created: float
    expires_at: float  # Unix time
    last_seen: float
    by_cookie: bool = False  # how this request authenticated (set per request on a copy)


class SessionsFullError(Exception):
    """No session can be made for this user now (the table is full of sessions of users of a
    higher role); the login is answered 503."""


@dataclass
class Logins:
    """Who may log in to an app: its users, their sessions, the failed logins' limit. An app
    puts them (or a console's parts that hold them: site.http.web.Console) in
    `app.state.console`, where the login routes (web.login) and `authenticated` find them."""

    users: UserStore
    sessions: Sessions
    limiter: LoginLimiter = field(default_factory=LoginLimiter)


class LoginParts(Protocol):
    """What the login routes and `authenticated` use of `app.state.console`: Logins, or a
    console's parts that hold the same (site.http.web.Console)."""

    @property
    def users(self) -> UserStore: ...
    @property
    def sessions(self) -> Sessions: ...
    @property
    def limiter(self) -> LoginLimiter: ...


def _privileged(role: str) -> bool:
    return role_at_least(role, "operator")


class Sessions:
    """The sessions of one service (see the module). clock: Unix time.

    Fair among users: at most per_user sessions of one user (their new login ends their own
    oldest one, never another user's), at most max_sessions in all. When the table is full, the
    dead sessions (expired, idle) go first; then the user holding the most sessions loses their
    oldest, a viewer's before an operator's or admin's, and a viewer's login never ends an
    operator's or an admin's session (SessionsFullError instead)."""

    def __init__(
        self,
        users: UserStore,
        *,
        lifetime_s: float = LIFETIME_S,
        idle_s: float = IDLE_S,
        max_sessions: int = MAX_SESSIONS,
        per_user: int = SESSIONS_PER_USER,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.users = users
        self.lifetime_s, self.idle_s, self.max_sessions = lifetime_s, idle_s, max_sessions
        self.per_user = max(1, per_user)
        self.clock = clock
        self._lock = threading.Lock()
        self._by_digest: dict[str, Session] = {}
        self._by_user: dict[str, OrderedDict[str, None]] = {}  # name -> its keys, oldest first
        self.evicted = 0  # live sessions ended to make room
        self.refused = 0  # logins refused for a full table

    def create(self, user: User) -> tuple[str, Session]:
        """A new session of `user`: (its token, the session); SessionsFullError when there is no
        room for it (see the class)."""
        token = secrets.token_urlsafe(32)
        now = self.clock()
        session = Session(
            user.name,
            user.role,
            user.stamp,
            secrets.token_urlsafe(24),
            now,
            now + self.lifetime_s,
            now,
        )
        key = _digest(token)
        with self._lock:
            own = self._by_user.get(user.name)
            if own is not None and len(own) >= self.per_user:
                self._drop(next(iter(own)))
                self.evicted += 1
            elif len(self._by_digest) >= self.max_sessions:
                self._make_room(now, _privileged(user.role))
            self._by_digest[key] = session
            self._by_user.setdefault(user.name, OrderedDict())[key] = None
        logger.info("console: %s logged in (%s)", user.name, user.role)
        return token, session

    def _make_room(self, now: float, privileged: bool) -> None:
        """One place in a full table (under the lock): see the class."""
        for key in [k for k, s in self._by_digest.items() if self._dead(s, now)]:
            self._drop(key)
        if len(self._by_digest) < self.max_sessions:
            return
        # (their role, how many they hold, their name, their oldest session's key)
        holders = [
            (_privileged(self._by_digest[oldest].role), -len(keys), name, oldest)
            for name, keys in self._by_user.items()
            for oldest in [next(iter(keys))]
        ]
        holders = [h for h in holders if privileged or not h[0]]
        if not holders:
            self.refused += 1
            raise SessionsFullError("every session place is held by operators and admins")
        _, _, name, oldest = min(holders)  # a viewer's first, then whoever holds the most
        self._drop(oldest)
        self.evicted += 1
        logger.info("console: the oldest session of %s ended to make room", name)

    def _dead(self, session: Session, now: float) -> bool:
        return now >= session.expires_at or now - session.last_seen > self.idle_s

    def _drop(self, key: str) -> Session | None:
        """Forget one session (under the lock)."""
        session = self._by_digest.pop(key, None)
        if session is not None:
            own = self._by_user.get(session.username)
            if own is not None:
                own.pop(key, None)
                if not own:
                    del self._by_user[session.username]
        return session

    def find(self, token: str) -> Session | None:
        """The live session of `token` (its last use now), or None (unknown, expired, idle,
        or its user removed or changed since)."""
        if not token or len(token) > 256:
            return None
        key = _digest(token)
        now = self.clock()
        with self._lock:
            session = self._by_digest.get(key)
        if session is None:
            return None
        user = self.users.get(session.username)
        dead = self._dead(session, now) or user is None or user.stamp != session.stamp
        with self._lock:
            if dead:
                self._drop(key)
                return None
            session.last_seen = now
        return session

    def end(self, token: str) -> bool:
        with self._lock:
            session = self._drop(_digest(token))
        if session is not None:
            logger.info("console: %s logged out", session.username)
        return session is not None

    def end_user(self, username: str) -> int:
        """End every session of `username`; how many."""
        with self._lock:
            keys = list(self._by_user.get(username, ()))
            for k in keys:
                self._drop(k)
        return len(keys)

    def count(self, username: str) -> int:
        """How many sessions `username` holds."""
        with self._lock:
            return len(self._by_user.get(username, ()))

    def __len__(self) -> int:
        return len(self._by_digest)


# -- the routers' dependencies -------------------------------------------------------------


def console_parts(request: Request) -> LoginParts:
    """The app's logins and the console's running parts (Logins, or site.http.web.Console);
    503 when the app has none."""
    parts = request.app.state.console
    if parts is None:
        raise HTTPException(503, "the console is not available on this server")
    return parts


def request_token(request: Request) -> tuple[str | None, bool]:
    """(the request's token, whether it came by cookie): the Authorization header's bearer
    token first, else the session cookie."""
    auth = request.headers.get("authorization", "")
    scheme, _, value = auth.partition(" ")
    if scheme.lower() == "bearer" and value.strip():
        return value.strip(), False
    cookie = request.cookies.get(SESSION_COOKIE)
    return (cookie, True) if cookie else (None, False)


_UNAUTHORIZED = {"WWW-Authenticate": "Bearer"}


def authenticated(request: Request, parts: LoginParts = Depends(console_parts)) -> Session:  # noqa: B008
    """The request's session; 401 without a live one; 403 when a cookie-authenticated
    state-changing request lacks the CSRF header."""
    token, by_cookie = request_token(request)
    try:
        session = parts.sessions.find(token) if token else None
    except UserError as e:  # users.json damaged by hand: nobody gets in, and it says why
        logger.error("console: %s", e)
        raise HTTPException(503, "the console's users cannot be read (see the log)") from None
    if session is None:
        raise HTTPException(401, "not logged in (or the session ended)", headers=_UNAUTHORIZED)
    if by_cookie and request.method not in SAFE_METHODS:
        sent = request.headers.get(CSRF_HEADER, "")
        if not sent or not hmac.compare_digest(sent.encode(), session.csrf.encode()):
            raise HTTPException(403, f"missing or wrong {CSRF_HEADER} header")
    copy = Session(**{**session.__dict__, "by_cookie": by_cookie})
    request.state.session = copy
    return copy


def require(role: str) -> Callable[..., Session]:
    """A dependency: the session, if its role is `role` or above (403 otherwise)."""
    if role not in ROLES:
        raise ValueError(f"unknown role {role!r}")

    def check(session: Annotated[Session, Depends(authenticated)]) -> Session:
        if not role_at_least(session.role, role):
            raise HTTPException(403, f"this needs the {role} role (you are {session.role})")
        return session

    check.__name__ = f"require_{role}"
    return check


Viewer = Annotated[Session, Depends(require("viewer"))]
Operator = Annotated[Session, Depends(require("operator"))]
Admin = Annotated[Session, Depends(require("admin"))]
