"""The sites enrolled in a control room: the only names it stores. Each enrolled site has its
own login on the central broker (`site-<name>`), kept in the store as the broker's salted hash
(Mosquitto's PBKDF2-SHA512 `$7$` form, never the password), from which `control-room
broker-config` writes the broker's password file and ACL (controlroom.broker_config).

A message under any other name is refused and counted by the intake; it never takes a place.
Upgrading a store made before enrolment keeps every site it already held enrolled (without a
broker login until `sites add` gives it one).

    enrolment = Enrolment(store)
    password = new_password()
    enrolment.add("north", broker_hash(password), time.time())
    "north" in enrolment.names()
"""

from __future__ import annotations

import base64
import hashlib
import re
import secrets
from dataclasses import dataclass
from typing import TYPE_CHECKING

from stereopose.controlroom.schema import SCHEMA_LOCK
from stereopose.errors import ConfigError

if TYPE_CHECKING:
    from stereopose.controlroom.schema import Run
    from stereopose.controlroom.store import ControlStore

__all__ = ["Enrolled", "Enrolment", "broker_hash", "check_name", "login_of", "new_password"]

NAME = re.compile(r"[^\s:]{1,64}")
LOGIN_PREFIX = "site-"
ITERATIONS = 10_000  # PBKDF2 rounds of a broker login's hash (Mosquitto's default is 101)

TABLE = (
    "CREATE TABLE IF NOT EXISTS enrolled (site TEXT PRIMARY KEY, login_hash TEXT, "
    "added {real} NOT NULL)"
)


def check_name(name: str) -> str:
    """`name` when it can be enrolled (1 to 64 printable characters, no space and no `:`: a
    broker login and a bridge's topic as the site's [mqtt] site), else a ConfigError."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or not name.isprintable():
        raise ConfigError(
            f"site name {str(name)[:80]!r}: 1 to 64 printable characters, no space and no ':' "
            "(the site's [mqtt] site)"
        )
    return name


def login_of(site: str) -> str:
    """The site's login on the central broker."""
    return LOGIN_PREFIX + site


def new_password() -> str:
    """A new broker password (32 URL-safe characters, 192 random bits)."""
    return secrets.token_urlsafe(24)


def broker_hash(password: str, *, salt: bytes | None = None, iterations: int = ITERATIONS) -> str:
    """Mosquitto's password-file hash of `password`: `$7$ROUNDS$SALT$HASH` (PBKDF2-HMAC-SHA512,
    a 12-byte salt, both in base64), as `mosquitto_passwd` writes it."""
    salt = secrets.token_bytes(12) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha512", password.encode("utf-8"), salt, iterations)
    b64 = lambda b: base64.b64encode(b).decode("ascii")  # noqa: E731
    return f"$7${iterations}${b64(salt)}${b64(digest)}"


@dataclass(frozen=True)
class Enrolled:
    site: str
    added: float  # Unix time
    has_login: bool  # a broker login was given (kept from an upgrade: none yet)


class Enrolment:
    """The enrolled sites of `store` (a ControlStore): its table made on first use; a store
    that held sites before enrolment keeps them all enrolled."""

    def __init__(self, store: ControlStore) -> None:
        self.store = store
        with store.writing("make the enrolment table") as run:
            if store.postgres:  # several workers starting at once make it one at a time
                run("SELECT pg_advisory_xact_lock(?)", (SCHEMA_LOCK,))
            existed = self._exists(run)
            run(TABLE.format(real="DOUBLE PRECISION" if store.postgres else "REAL"))
            if not existed:  # an upgrade: every site already stored stays enrolled
                run(
                    "INSERT OR IGNORE INTO enrolled(site, login_hash, added) "
                    "SELECT site, NULL, ? FROM sites",
                    (0.0,),
                )

    def _exists(self, run: Run) -> bool:
        if self.store.postgres:
            row = run("SELECT to_regclass('enrolled')").fetchone()  # one row, NULL: none
            return row is not None and row[0] is not None
        sql = "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'enrolled'"
        return run(sql).fetchone() is not None

    def names(self) -> frozenset[str]:
        with self.store.reading("read the enrolled sites") as run:
            return frozenset(r[0] for r in run("SELECT site FROM enrolled").fetchall())

    def list(self) -> list[Enrolled]:
        with self.store.reading("read the enrolled sites") as run:
            rows = run("SELECT site, added, login_hash FROM enrolled ORDER BY site").fetchall()
        return [Enrolled(s, float(a), h is not None) for s, a, h in rows]

    def logins(self) -> list[tuple[str, str]]:
        """(site, its login's hash) of every site with a login, by name."""
        with self.store.reading("read the enrolled sites") as run:
            rows = run(
                "SELECT site, login_hash FROM enrolled WHERE login_hash IS NOT NULL ORDER BY site"
            ).fetchall()
        return [(s, h) for s, h in rows]

    def add(self, site: str, login_hash: str, now: float) -> bool:
        """Enrol `site` with its login's hash (a site enrolled already gets the new login);
        whether it is new."""
        with self.store.writing(f"enrol site {site!r}") as run:
            new = run("SELECT 1 FROM enrolled WHERE site = ?", (site,)).fetchone() is None
            if new:
                run(
                    "INSERT INTO enrolled(site, login_hash, added) VALUES (?, ?, ?)",
                    (site, login_hash, now),
                )
            else:
                run("UPDATE enrolled SET login_hash = ? WHERE site = ?", (login_hash, site))
        return new

    def remove(self, site: str) -> bool:
        """`site` no longer enrolled (what it sent stays stored); whether it was."""
        with self.store.writing(f"remove site {site!r}") as run:
            return run("DELETE FROM enrolled WHERE site = ?", (site,)).rowcount > 0
