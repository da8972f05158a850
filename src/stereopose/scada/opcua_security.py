"""Who may do what on serve's OPC UA server: logins, permissions, the caller of a method.

Clients log in as the console's users (web.users: the same names, passwords and argon2
hashes); anonymous clients only when [opcua] allow_anonymous. Every login may browse, read,
subscribe and call methods (ConditionRefresh); nobody may write or change the address space
(asyncua's Admin role is never given). Password guesses are limited as the console's are, by
the same limiter when serve gives it (stereopose.login_limit: per client address, per account):
a login past the limit is refused unchecked. Which user calls a method: `caller()`, set for the
duration of each Call request of a session (asyncua gives a method callback no session).
`trusted_clients(folder)`: only the client certificates in a folder may open a channel.
"""

from __future__ import annotations

import asyncio
import contextvars
import dataclasses
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from asyncua import ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole
from asyncua.server.internal_server import InternalServer
from asyncua.server.internal_session import InternalSession
from asyncua.server.user_managers import UserManager
from asyncua.ua.object_ids import ObjectIds

from stereopose.errors import HashingBusyError, StereoposeError
from stereopose.login_limit import LoginLimiter, TooManyAttemptsError

if TYPE_CHECKING:
    from asyncua.crypto.validator import CertificateValidator
    from asyncua.server.binary_server_asyncio import OPCUAProtocol
    from asyncua.server.server import Server

    from stereopose.web.users import UserStore

__all__ = ["ACK_ROLES", "Login", "LoginServer", "Permissions", "Users", "caller", "trusted_clients"]

logger = logging.getLogger(__name__)

# the console's roles (web.users) that may acknowledge, as its API lets them
ACK_ROLES = ("operator", "admin")
_CALLER: contextvars.ContextVar[User | None] = contextvars.ContextVar("opcua_caller", default=None)
# the client address of the session being activated (asyncua gives get_user no peer)
_PEER: contextvars.ContextVar[str] = contextvars.ContextVar("opcua_peer", default="?")


@dataclasses.dataclass
class Login(User):
    """A session's user: the console user's name and the stamp of its role and password at
    login (web.users.User.stamp), or anonymous (name None)."""

    stamp: str | None = None


class _CallerSession(InternalSession):
    """A session whose method calls know their caller (the Acknowledge needs the user)."""

    async def call(self, params: list[ua.CallMethodRequest]) -> list[ua.CallMethodResult]:
        token = _CALLER.set(self.user)
        try:
            return await super().call(params)
        finally:
            _CALLER.reset(token)

    def activate_session(
        self, params: ua.ActivateSessionParameters, peer_certificate: bytes | None
    ) -> ua.ActivateSessionResult:
        peer = self.name  # asyncua's: the transport's peer name, (host, port)
        host = peer[0] if isinstance(peer, (tuple, list)) and peer else str(peer)
        token = _PEER.set(str(host))
        try:
            return super().activate_session(params, peer_certificate)
        finally:
            _PEER.reset(token)


class LoginServer(InternalServer):
    """asyncua's internal server whose sessions know the caller of their methods."""

    def create_session(
        self,
        name: str,
        user: User = User(role=UserRole.Anonymous),  # noqa: B008
        external: bool = False,
    ) -> InternalSession:
        return _CallerSession(
            self, self.aspace, self.subscription_service, name, user=user, external=external
        )


class Permissions(PermissionRuleset):
    """Logins read, browse, subscribe and call methods; nobody writes or edits nodes."""

    def __init__(self) -> None:
        # asyncua annotates a node id's number as its own Int32; it takes an int
        allowed = {ua.NodeId(n) for n in USER_TYPES}  # pyright: ignore[reportArgumentType]
        write = ObjectIds.WriteRequest_Encoding_DefaultBinary
        allowed.discard(ua.NodeId(write))  # pyright: ignore[reportArgumentType]
        self._allowed = frozenset(allowed)

    def check_validity(self, user: object, action_type: ua.NodeId, body: object) -> bool:
        # a session not yet activated holds asyncua's default user, not a Login
        return isinstance(user, Login) and action_type in self._allowed


class Users(UserManager):
    """asyncua's user manager over the console's users (see the module); limiter: the
    console's (a login here counts against the same address and account), or its own."""

    def __init__(
        self, users: UserStore, allow_anonymous: bool, limiter: LoginLimiter | None = None
    ) -> None:
        self.users, self.allow_anonymous = users, allow_anonymous
        self.limiter = limiter if limiter is not None else LoginLimiter()
        self.limited = 0  # logins refused unchecked by the limiter
        self._warned_at = -1e9

    def get_user(
        self,
        iserver: object,
        username: str | None = None,
        password: str | None = None,
        certificate: bytes | None = None,
    ) -> User | None:
        if username is None:
            return Login(role=UserRole.Anonymous) if self.allow_anonymous else None
        name, address = str(username)[:200], _PEER.get()
        try:
            attempt = self.limiter.begin(address, name)
        except TooManyAttemptsError as e:
            self.limited += 1
            now = time.monotonic()
            if now - self._warned_at >= 10.0:  # a guesser fills no log
                self._warned_at = now
                logger.warning(
                    "OPC UA: login of %r from %s refused unchecked: %s (%d so far)",
                    name[:40],
                    address,
                    e.why,
                    self.limited,
                )
            return None
        user = None
        try:
            user = self._check(name, password)
        finally:
            self.limiter.end(attempt, user is not None)
        return user

    def _check(self, name: str, password: str | None) -> User | None:
        check = getattr(self.users, "verify_admitted", self.users.verify)
        try:
            user = check(name, password if isinstance(password, str) else "")
        except StereoposeError as e:  # the users file unreadable
            logger.error("OPC UA: cannot check a login: %s", e)
            return None
        except HashingBusyError:  # a flood of logins: refused unchecked, the server goes on
            logger.warning(
                "OPC UA: login of %r refused: too many password checks at once", name[:40]
            )
            return None
        if user is None:
            logger.warning("OPC UA: login refused for %r", name[:40])
            return None
        logger.info("OPC UA: %s logged in (%s)", user.name, user.role)
        return Login(role=UserRole.User, name=user.name, stamp=user.stamp)


def caller() -> User | None:
    """The user of the session whose method call runs now (None outside a call)."""
    return _CALLER.get()


async def trusted_clients(folder: Path) -> CertificateValidator:
    """Only the client certificates in `folder` (and those their CAs there signed)."""
    from asyncua.crypto.truststore import TrustStore
    from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

    store = TrustStore([folder], [])
    await store.load()
    opts = (
        CertificateValidatorOptions.BASIC_VALIDATION
        | CertificateValidatorOptions.TRUSTED
        | CertificateValidatorOptions.PEER_CLIENT
    )
    return CertificateValidator(opts, store)


MIN_IDLE_S = 1.0  # a socket without a session is closed, when places run out, once this old
SWEEP_S = 0.25  # how often the sockets are looked at


async def sweep_idle(server: Server, on_evict: Callable[[], None]) -> None:
    """While fewer than two places are free, the oldest socket without an activated session
    (older than MIN_IDLE_S; a silent one before one with a secure channel open) is closed
    (on_evict() counts it): a client that logs in finds a place and keeps it. Runs until
    cancelled; a failure to look is logged, never ends the server."""
    loop = asyncio.get_running_loop()
    first_seen: dict[int, float] = {}
    while True:
        await asyncio.sleep(SWEEP_S)
        try:
            clients = list(getattr(server.bserver, "clients", []) or [])
            now = loop.time()
            first_seen = {id(c): first_seen.get(id(c), now) for c in clients}
            free = server.iserver.max_connections - len(clients)
            old = [c for c in clients if now - first_seen[id(c)] >= MIN_IDLE_S]
            # the silent ones make way first, oldest first; one that opened a secure channel
            # (it speaks: a client logging in) only when no silent one is left
            idle = sorted(
                (_spoke(c), first_seen[id(c)], id(c), c) for c in old if not _activated(c)
            )
            for *_, c in idle[: max(0, 2 - free)]:
                transport = getattr(c, "transport", None)
                if transport is not None:
                    transport.close()
                    on_evict()
        except Exception:  # never ends the server
            logger.exception("OPC UA: looking at the connections failed")


def _spoke(protocol: OPCUAProtocol) -> bool:
    """Whether an asyncua connection has opened a secure channel (said Hello and more)."""
    processor = getattr(protocol, "processor", None)
    return bool(getattr(getattr(processor, "_connection", None), "_open", False))


def _activated(protocol: OPCUAProtocol) -> bool:
    """Whether an asyncua connection has an activated session."""
    processor = getattr(protocol, "processor", None)
    session = getattr(processor, "session", None)
    try:
        return session is not None and bool(session.is_activated())
    except Exception:
        return False
