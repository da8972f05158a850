"""A throwaway PostgreSQL cluster for tests: `initdb` and `pg_ctl` of Debian's postgresql,
run as the `postgres` user when the tests run as root (the server refuses root), listening
on 127.0.0.1 at a free port with password (scram-sha-256) logins only. Skipped without
PostgreSQL or psycopg, unless CI requires it (STEREOPOSE_REQUIRE_POSTGRES=1)."""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

from brokers import free_port

PASSWORD = "cluster-test-pw"


def _tool(name: str) -> str | None:
    found = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return found[-1] if found else shutil.which(name)


def _missing(why: str) -> None:
    if os.environ.get("STEREOPOSE_REQUIRE_POSTGRES") == "1":
        pytest.fail(f"{why}; install Debian's postgresql package and psycopg")
    pytest.skip(why)


class Postgres:
    """One cluster in a private folder; `url` for its `stereopose` database (owner
    `stereopose`, password PASSWORD). `stop()` removes it."""

    def __init__(self) -> None:
        initdb, pg_ctl = _tool("initdb"), _tool("pg_ctl")
        if initdb is None or pg_ctl is None:
            _missing("PostgreSQL not installed (Debian package postgresql)")
        try:
            import psycopg  # noqa: F401
        except ImportError:
            _missing("psycopg not installed (the postgresql extra)")
        self.pg_ctl = pg_ctl
        self.root = os.geteuid() == 0
        self.folder = Path(tempfile.mkdtemp(prefix="stereopose-pg-"))
        self.data = self.folder / "data"
        pwfile = self.folder / "pw"
        pwfile.write_text(PASSWORD + "\n")
        if self.root:
            shutil.chown(self.folder, "postgres", "postgres")
            shutil.chown(pwfile, "postgres", "postgres")
        self.port = free_port()
        self._run(
            [
                initdb,
                "-D",
                str(self.data),
                "-U",
                "stereopose",
                "--auth=scram-sha-256",
                f"--pwfile={pwfile}",
                "-E",
                "UTF8",
                "--no-instructions",
            ]
        )
        self.start()
        self.url = f"postgresql://stereopose:{PASSWORD}@127.0.0.1:{self.port}/postgres"

    def _run(self, cmd: list[str]) -> None:
        if self.root:  # util-linux's runuser, in /usr/sbin
            runuser = shutil.which("runuser", path=f"{os.environ.get('PATH', '')}:/usr/sbin:/sbin")
            cmd = [runuser or "runuser", "-u", "postgres", "--", *cmd]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=self.folder)
        if r.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)}: {r.stderr or r.stdout}")

    def start(self) -> Postgres:
        opts = (
            f"-c listen_addresses=127.0.0.1 -c port={self.port} "
            f"-c unix_socket_directories={self.folder} -c fsync=off"
        )
        self._run(
            [
                self.pg_ctl,
                "-D",
                str(self.data),
                "-o",
                opts,
                "-l",
                str(self.folder / "server.log"),
                "-w",
                "-t",
                "60",
                "start",
            ]
        )
        return self

    def stop(self, remove: bool = False) -> None:
        with contextlib.suppress(RuntimeError):  # stopped already
            self._run([self.pg_ctl, "-D", str(self.data), "-m", "fast", "-w", "stop"])
        if remove:
            shutil.rmtree(self.folder, ignore_errors=True)

    def database(self, name: str) -> str:
        """A fresh database `name`; its URL."""
        import psycopg

        with psycopg.connect(self.url, autocommit=True) as db:
            db.execute(f'CREATE DATABASE "{name}"')
        return self.url.rsplit("/", 1)[0] + f"/{name}"
