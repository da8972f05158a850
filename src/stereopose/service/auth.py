"""Who is asking: login sessions, bearer tokens, CSRF, the login rate limit, role checks.

- A login gives a random token (secrets.token_urlsafe) and a CSRF value. The server keeps
  only the token's SHA-256 (in memory, at most MAX_SESSIONS: the oldest goes first); a session
  ends at its absolute expiry (12 h), after IDLE_S without a request, at logout, and as soon
  as its user is removed or their password or role changes (the user's stamp differs).
- Every /api/ route but the open ones asks for a session: the cookie `stereopose_session` or
  `Authorization: Bearer <token>`; 401 otherwise. A state-changing request (POST, PUT, PATCH,
  DELETE) authenticated by the cookie must carry `X-CSRF-Token` equal to the session's CSRF
  value (403 otherwise): another site's page can make the browser send the cookie, never read
  the CSRF cookie. A bearer token is never sent by a browser on its own, so it needs none.
- Login failures are counted per client address and per name over WINDOW_S; MAX_FAILURES of
  either and the next attempt is 429 with Retry-After, before any password is checked.
  Both tables are bounded.
- Nothing secret is logged: neither passwords nor tokens (a session is named by its user).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import math
import secrets
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Request

from stereopose.service.users import ROLES, User, UserError, UserStore, role_at_least

logger = logging.getLogger(__name__)

SESSION_COOKIE = "stereopose_session"
CSRF_COOKIE = "stereopose_csrf"
CSRF_HEADER = "x-csrf-token"
LIFETIME_S = 12 * 3600.0
IDLE_S = 2 * 3600.0
MAX_SESSIONS = 1000
WINDOW_S = 60.0
MAX_FAILURES = 5
MAX_TRACKED = 10_000  # client addresses and names whose failures are counted
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def _digest(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


@dataclass
class Session:
    """One login. token: given once at login, never kept (only its digest, the key)."""

    username: str
    role: str
    stamp: str
    csrf: str
    created: float
    expires_at: float  # Unix time
    last_seen: float
    by_cookie: bool = False  # how this request authenticated (set per request on a copy)


class Sessions:
    """The sessions of one service (see the module). clock: Unix time."""

    def __init__(self, users: UserStore, *, lifetime_s: float = LIFETIME_S,
                 idle_s: float = IDLE_S, max_sessions: int = MAX_SESSIONS,
                 clock: Callable[[], float] = time.time) -> None:  # fmt: skip
        self.users = users
        self.lifetime_s, self.idle_s, self.max_sessions = lifetime_s, idle_s, max_sessions
        self.clock = clock
        self._lock = threading.Lock()
        self._by_digest: OrderedDict[str, Session] = OrderedDict()
        self.evicted = 0

    def create(self, user: User) -> tuple[str, Session]:
        """A new session of `user`: (its token, the session)."""
        token = secrets.token_urlsafe(32)
        now = self.clock()
        session = Session(user.name, user.role, user.stamp, secrets.token_urlsafe(24), now,
                          now + self.lifetime_s, now)  # fmt: skip
        with self._lock:
            self._by_digest[_digest(token)] = session
            while len(self._by_digest) > self.max_sessions:
                self._by_digest.popitem(last=False)
                self.evicted += 1
        logger.info("console: %s logged in (%s)", user.name, user.role)
        return token, session

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
        dead = (now >= session.expires_at or now - session.last_seen > self.idle_s
                or user is None or user.stamp != session.stamp)  # fmt: skip
        with self._lock:
            if dead:
                self._by_digest.pop(key, None)
                return None
            session.last_seen = now
        return session

    def end(self, token: str) -> bool:
        with self._lock:
            session = self._by_digest.pop(_digest(token), None)
        if session is not None:
            logger.info("console: %s logged out", session.username)
        return session is not None

    def end_user(self, username: str) -> int:
        """End every session of `username`; how many."""
        with self._lock:
            keys = [k for k, s in self._by_digest.items() if s.username == username]
            for k in keys:
                del self._by_digest[k]
        return len(keys)

    def __len__(self) -> int:
        return len(self._by_digest)


class LoginLimiter:
    """Login failures per key (a client address, a name) within window_s; at max_failures
    a key is refused until its oldest failure leaves the window."""

    def __init__(self, *, window_s: float = WINDOW_S, max_failures: int = MAX_FAILURES,
                 max_tracked: int = MAX_TRACKED,
                 clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self.window_s, self.max_failures, self.max_tracked = window_s, max_failures, max_tracked
        self.clock = clock
        self._lock = threading.Lock()
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self.refused = 0

    def retry_after(self, *keys: str) -> int | None:
        """Seconds until a login for these keys may be tried again; None: now."""
        now = self.clock()
        wait = 0.0
        with self._lock:
            for key in keys:
                times = self._recent(key, now)
                if times is not None and len(times) >= self.max_failures:
                    wait = max(wait, times[0] + self.window_s - now)
            if wait > 0:
                self.refused += 1
        return max(1, math.ceil(wait)) if wait > 0 else None

    def failed(self, *keys: str) -> None:
        now = self.clock()
        with self._lock:
            for key in keys:
                times = self._recent(key, now)
                if times is None:
                    times = self._failures[key] = deque(maxlen=self.max_failures)
                times.append(now)
                self._failures.move_to_end(key)
            while len(self._failures) > self.max_tracked:
                self._failures.popitem(last=False)

    def succeeded(self, key: str) -> None:
        with self._lock:
            self._failures.pop(key, None)

    def _recent(self, key: str, now: float) -> deque[float] | None:
        times = self._failures.get(key)
        if times is None:
            return None
        while times and times[0] <= now - self.window_s:
            times.popleft()
        if not times:
            del self._failures[key]
            return None
        return times


# -- the routers' dependencies -------------------------------------------------------------


def console_parts(request: Request):
    """The console's running parts (service.web.Console); 503 when the app has none."""
    parts = getattr(request.app.state, "console", None)
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


def authenticated(request: Request, parts=Depends(console_parts)) -> Session:  # noqa: B008
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
