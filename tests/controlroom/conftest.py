"""The control room's tests: a throwaway PostgreSQL cluster for the session (tests/postgres)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def postgres():
    from postgres import Postgres

    cluster = Postgres()
    yield cluster
    cluster.stop(remove=True)
