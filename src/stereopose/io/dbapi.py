"""What the stores use of a DB-API connection and cursor: sqlite3's and psycopg's alike. A row
is untyped: each store reads its own columns."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from typing import Any, Protocol, cast

Row = Any  # a row of a cursor: sqlite3's tuple or psycopg's


class Cursor(Protocol):
    @property
    def rowcount(self) -> int: ...

    def fetchone(self) -> Row | None: ...

    def fetchall(self) -> list[Row]: ...

    def executemany(self, sql: str, rows: Iterable[Sequence[object]], /) -> object: ...

    def __iter__(self) -> Iterator[Row]: ...


class Connection(Protocol):
    def execute(self, sql: str, params: Sequence[object] = ..., /) -> Cursor: ...

    def cursor(self) -> Cursor: ...

    def commit(self) -> None: ...

    def rollback(self) -> None: ...

    def close(self) -> None: ...


def as_connection(db: object) -> Connection:
    """A driver's connection as the stores use it. psycopg types its queries as literal
    strings, and the stores' queries are built from their own constants (table and column
    names), so its connection is taken as one, as sqlite3's is."""
    return cast(Connection, db)
