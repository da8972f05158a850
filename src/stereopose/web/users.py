"""The console's users: `<output>/users.json`, beside the event log.

One JSON document {"version": 1, "users": {name: {"role", "hash", "created", "changed"}}}
(and "sites": [names] for a control room's user limited to some sites: see
stereopose.controlroom),
written atomically (a temporary file renamed over it) and readable by its owner only (0600).
Passwords are argon2id hashes (argon2-cffi); the plain password is never stored or logged.
Changes (`stereopose users ...` while the service runs) are made under an exclusive lock of
`users.json.lock`, and a running service sees them at its next look: the file is read again
whenever its size, time or inode changed.

Names: 1 to 32 characters, letters, digits, '_', '.', '-', starting with a letter or digit.
Passwords: 12 to 1024 characters, not a common one (`common_passwords.txt` of this package,
compared in lower case, also with the digits and punctuation around it stripped, so
`Password2024!` is one), and at least 5 different characters. The policy applies when a
password is set (`stereopose users add|passwd`, the API); a user whose password was set
before still logs in with it. Roles: viewer (sees), operator (also acknowledges alarms),
admin (also manages users).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import re
import string
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from hashlib import sha256
from importlib import resources
from pathlib import Path
from typing import Literal

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError, VerifyMismatchError

from stereopose.errors import HashingBusyError, StereoposeError
from stereopose.io.datafolder import USERS_FILE

__all__ = [
    "MIN_PASSWORD",
    "ROLES",
    "Role",
    "User",
    "UserError",
    "UserStore",
    "check_name",
    "check_password",
    "check_site",
    "common_passwords",
    "role_at_least",
]

logger = logging.getLogger(__name__)

Role = Literal["viewer", "operator", "admin"]
ROLES: tuple[Role, ...] = ("viewer", "operator", "admin")
MIN_PASSWORD = 12
MIN_DISTINCT = 5  # different characters in a password
COMMON_PASSWORDS = "common_passwords.txt"  # beside this module
MAX_PASSWORD = 1024
MAX_USERS = 1000
# One hash at a time, on one thread (64 MiB, 3 passes): a flood of logins takes one core at
# most and waits its turn, never the frame loop's cores or the memory.
HASHING_AT_ONCE = 1
# password checks let in at once, the one hashing and those waiting their turn: beyond them a
# check is refused at once (HashingBusyError), so a flood of logins holds a few of the HTTP
# threads, never all of them (health and the logged-in consoles answer meanwhile)
CHECKS_ADMITTED = 8
TIME_COST, MEMORY_KIB, PARALLELISM = 3, 64 * 1024, 1
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,31}")


class UserError(StereoposeError):
    """A user cannot be added, changed or removed (bad name or password, unknown, taken)."""


@dataclass(frozen=True)
class User:
    """One user as stored. stamp: changes whenever the password or the role changes (a
    session made before no longer counts)."""

    name: str
    role: Role
    created: float
    changed: float
    stamp: str
    sites: tuple[str, ...] | None = None  # a control room's user: only these sites (None: all)


def check_name(name: object) -> str:
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise UserError(
            f"user name {name!r}: 1 to 32 letters, digits, '_', '.' or '-', starting with a "
            "letter or a digit"
        )
    return name


_AROUND = string.digits + string.punctuation + string.whitespace


@functools.cache
def common_passwords() -> frozenset[str]:
    """The common passwords shipped in the package (lower case); see the module."""
    text = resources.files("stereopose.web").joinpath(COMMON_PASSWORDS).read_text("utf-8")
    return frozenset(
        line.strip().lower()
        for line in text.splitlines()
        if line.strip() and not line.startswith("# ")
    )


def check_password(password: object) -> str:
    """`password` when it may be set (see the module), else a UserError saying why."""
    if not isinstance(password, str) or not password:
        raise UserError("the password is empty")
    if len(password) < MIN_PASSWORD:
        raise UserError(f"the password is too short: at least {MIN_PASSWORD} characters")
    if len(password) > MAX_PASSWORD:
        raise UserError(f"the password is too long: at most {MAX_PASSWORD} characters")
    lower = password.lower()
    core = lower.strip(_AROUND)
    common = common_passwords()
    if lower in common or (len(core) >= 4 and core in common):
        raise UserError(
            "the password is too common (on the list of common passwords, perhaps "
            "with digits or punctuation around it): choose another"
        )
    if len(set(password)) < MIN_DISTINCT:
        raise UserError(f"the password is too simple: at least {MIN_DISTINCT} different characters")
    return password


def check_role(role: object) -> Role:
    for known in ROLES:
        if role == known:
            return known
    raise UserError(f"role {role!r}: expected one of {', '.join(ROLES)}")


def role_at_least(role: str, needed: str) -> bool:
    """Whether `role` may do what `needed` may (viewer < operator < admin)."""
    return role in ROLES and ROLES.index(role) >= ROLES.index(needed)


def check_site(name: object) -> str:
    """A site's name as a user's limit: 1 to 200 printable characters."""
    if not isinstance(name, str) or not 0 < len(name) <= 200 or not name.isprintable():
        raise UserError(f"site {name!r}: expected 1 to 200 printable characters")
    return name


def _stamp(record: dict) -> str:
    text = f"{record['role']}\0{record['hash']}"
    if record.get("sites") is not None:
        text += "\0" + "\0".join(record["sites"])
    return sha256(text.encode()).hexdigest()[:32]


class UserStore:
    """The users of one output folder (see the module). Thread-safe; several processes may
    change the file, each change under the lock file."""

    def __init__(self, path: str | Path, hasher: PasswordHasher | None = None) -> None:
        self.path = Path(path)
        self.hasher = hasher or PasswordHasher(
            time_cost=TIME_COST, memory_cost=MEMORY_KIB, parallelism=PARALLELISM
        )
        self._lock = threading.Lock()
        self._seen: tuple[int, int, int] | None = None  # (inode, size, mtime_ns) read
        self._users: dict[str, dict] = {}
        self._dummy: str | None = None
        self._hashing = threading.BoundedSemaphore(HASHING_AT_ONCE)
        self._admitted = threading.BoundedSemaphore(CHECKS_ADMITTED)
        self.checks_refused = 0  # password checks refused as over the bound

    @classmethod
    def in_folder(cls, out_dir: str | Path, hasher: PasswordHasher | None = None) -> UserStore:
        return cls(Path(out_dir) / USERS_FILE, hasher)

    # -- reading ---------------------------------------------------------------------------

    def _fresh(self) -> dict[str, dict]:
        """The users as the file holds them now (read again when it changed)."""
        try:
            st = self.path.stat()
        except FileNotFoundError:
            with self._lock:
                self._seen, self._users = None, {}
            return {}
        except OSError as e:
            raise UserError(f"{self.path}: cannot read the users: {e.strerror}") from None
        key = (st.st_ino, st.st_size, st.st_mtime_ns)
        with self._lock:
            if key == self._seen:
                return self._users
        users = self._read()
        with self._lock:
            self._seen, self._users = key, users
        return users

    def _read(self) -> dict[str, dict]:
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return {}
        except OSError as e:
            raise UserError(f"{self.path}: cannot read the users: {e.strerror}") from None
        except UnicodeDecodeError:
            raise UserError(f"{self.path}: not UTF-8 text") from None
        try:
            doc = json.loads(text)
            users = doc["users"]
            if not isinstance(users, dict):
                raise TypeError("users is not a table")
            for name, rec in users.items():
                check_name(name)
                check_role(rec["role"])
                if not isinstance(rec["hash"], str):
                    raise TypeError(f"{name}: hash is not text")
                sites = rec.get("sites")
                if sites is not None and not (
                    isinstance(sites, list) and all(isinstance(x, str) for x in sites)
                ):
                    raise TypeError(f"{name}: sites is not a list of names")
        except (ValueError, KeyError, TypeError, UserError) as e:
            raise UserError(f"{self.path}: not a users file ({e})") from None
        return users

    def users(self) -> list[User]:
        """Every user, by name."""
        return [self._user(n, r) for n, r in sorted(self._fresh().items())]

    def get(self, name: str) -> User | None:
        rec = self._fresh().get(name)
        return None if rec is None else self._user(name, rec)

    def count(self) -> int:
        return len(self._fresh())

    @staticmethod
    def _user(name: str, rec: dict) -> User:
        sites = rec.get("sites")
        return User(
            name,
            rec["role"],
            float(rec.get("created", 0.0)),
            float(rec.get("changed", 0.0)),
            _stamp(rec),
            None if sites is None else tuple(sites),
        )

    def verify_admitted(self, name: str, password: str) -> User | None:
        """`verify` within the bound on password checks waiting at once (CHECKS_ADMITTED);
        HashingBusyError, at once and with nothing checked, when it is full."""
        if not self._admitted.acquire(blocking=False):
            self.checks_refused += 1
            raise HashingBusyError("too many password checks at once")
        try:
            return self.verify(name, password)
        finally:
            self._admitted.release()

    def verify(self, name: str, password: str) -> User | None:
        """The user when `password` is theirs, else None. An unknown name costs one hash as a
        known one does, so the answer's time does not tell which names exist."""
        rec = self._fresh().get(name) if isinstance(name, str) else None
        if not isinstance(password, str) or len(password) > MAX_PASSWORD:
            password = ""
        with self._hashing:
            dummy = self._dummy_hash()  # made at the first login, whoever it is for
            if rec is None:
                with contextlib.suppress(VerificationError, InvalidHashError):
                    self.hasher.verify(dummy, password or "x")
                return None
            try:
                self.hasher.verify(rec["hash"], password)
            except (VerifyMismatchError, VerificationError, InvalidHashError):
                return None
        return self._user(name, rec)

    def _dummy_hash(self) -> str:
        if self._dummy is None:
            self._dummy = self.hasher.hash(os.urandom(16).hex())
        return self._dummy

    def _hash(self, password: str) -> str:
        with self._hashing:
            return self.hasher.hash(password)

    # -- changing --------------------------------------------------------------------------

    def add(
        self, name: str, password: str, role: str, sites: tuple[str, ...] | None = None
    ) -> User:
        """sites: the only sites a control room shows this user (None: every site)."""
        check_name(name)
        if sites is not None:
            sites = tuple(check_site(x) for x in sites)
        check_role(role)
        check_password(password)
        hashed = self._hash(password)
        with self._changing() as users:
            if name in users:
                raise UserError(
                    f"user {name!r} already exists (`stereopose users passwd` changes a password)"
                )
            if len(users) >= MAX_USERS:
                raise UserError(f"{self.path}: at most {MAX_USERS} users")
            now = time.time()
            users[name] = {"role": role, "hash": hashed, "created": now, "changed": now}
            if sites is not None:
                users[name]["sites"] = sorted(set(sites))
            rec = users[name]
        logger.info("users: %s added (%s)", name, role)
        return self._user(name, rec)

    def set_password(self, name: str, password: str) -> User:
        check_password(password)
        hashed = self._hash(password)
        with self._changing() as users:
            if name not in users:
                raise UserError(f"no user {name!r}")
            users[name] = {**users[name], "hash": hashed, "changed": time.time()}
            rec = users[name]
        logger.info("users: the password of %s changed", name)
        return self._user(name, rec)

    def remove(self, name: str) -> None:
        with self._changing() as users:
            if name not in users:
                raise UserError(f"no user {name!r}")
            del users[name]
        logger.info("users: %s removed", name)

    @contextlib.contextmanager
    def _changing(self) -> Iterator[dict[str, dict]]:
        """The users to change, under the lock file; written back atomically (0600)."""
        import fcntl

        folder = self.path.parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
            lock_fd = os.open(folder / (self.path.name + ".lock"), os.O_RDWR | os.O_CREAT, 0o600)
        except OSError as e:
            raise UserError(f"{self.path}: cannot change the users: {e.strerror}") from None
        try:
            fcntl.flock(lock_fd, fcntl.LOCK_EX)
            users = dict(self._read())
            yield users
            self._write(users)
        finally:
            os.close(lock_fd)

    def _write(self, users: dict[str, dict]) -> None:
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        text = json.dumps({"version": 1, "users": users}, indent=1, sort_keys=True) + "\n"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                os.fchmod(f.fileno(), 0o600)
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except OSError as e:
            with contextlib.suppress(OSError):
                tmp.unlink()
            raise UserError(f"{self.path}: cannot write the users: {e.strerror}") from None
