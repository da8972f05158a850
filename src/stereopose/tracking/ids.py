"""Where the tracker's person ids come from.

The tracker asks an `IdSource` for each new id (`take`). A plain count (`CountingIds`) gives
every id asked for; a service gives them from ids reserved in its event log
(site.person_ids), each committed before it is given, and may answer None when none is
reserved: the track then stays tentative (no id, not output) and asks again next frame, so
no id is ever seen anywhere that a restart could give again.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

__all__ = ["CountingIds", "IdSource", "id_source"]


@runtime_checkable
class IdSource(Protocol):
    def take(self) -> int | None:
        """The next id (each larger than the last), or None when none may be given now."""
        ...


class CountingIds:
    """first, first + 1, ...: every id asked for."""

    def __init__(self, first: int = 1) -> None:
        if first < 1:
            raise ValueError(f"first_id must be at least 1, got {first}")
        self.next = int(first)

    def take(self) -> int:
        given, self.next = self.next, self.next + 1
        return given


def id_source(first_id: int | IdSource) -> IdSource:
    """An IdSource from a first id (a plain count) or the source itself."""
    if isinstance(first_id, IdSource):
        return first_id
    return CountingIds(int(first_id))
