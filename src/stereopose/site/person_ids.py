"""Person ids a service gives, each reserved in its event log before it is given.

The tracker takes its ids from `PersonIds` (a tracking.ids.IdSource). Ids are reserved a
block at a time on the log's `persons` high-water mark (io.sinks.eventdb), each block
committed before an id of it is handed out, and the next block is reserved while half of
the current one is still left: a process killed at any moment has reserved every id it
gave, and the next start (site.restart: Resume.next_id) gives ids above all of them, so a
person id names one person for the life of the data folder, whatever retention deleted.

While the log cannot be written (locked by another process for longer than busy_s, a full
disk, a read-only file system), the ids already reserved are given; only when none is left
does `take` answer None (the new person's track stays tentative and asks again on the next
frame, the log tried again after retry_s, doubling to 2 s): an id that could be given again
after a restart is never handed out. The error is logged once per spell.
"""

from __future__ import annotations

import logging
import sqlite3
import time
from pathlib import Path

from stereopose.io.sinks.eventdb import connect_writer, create_schema, raise_marks, take

__all__ = ["PersonIds"]

logger = logging.getLogger(__name__)

MARK = "persons"


class PersonIds:
    """Ids from first_id on, reserved `block` at a time in the event log at `path` (created
    when there is none). reserved_to: every id below it was reserved (committed); error: why
    the last reservation failed (None: it did not)."""

    def __init__(
        self,
        path: str | Path,
        first_id: int = 1,
        *,
        block: int = 1000,
        busy_s: float = 0.2,
        retry_s: float = 0.2,
    ) -> None:
        if first_id < 1:
            raise ValueError(f"first_id must be at least 1, got {first_id}")
        if block < 2:
            raise ValueError(f"block must be at least 2, got {block}")
        self.path, self.block = Path(path), block
        self.busy_s, self.retry_s = busy_s, retry_s
        self.reserved_to = int(first_id)  # the least id a next reservation may start at
        self._ranges: list[list[int]] = []  # reserved, not given yet: [start, end), in order
        self.error: str | None = None
        self._next_try = 0.0
        self._delay = retry_s

    @property
    def left(self) -> int:
        """Ids reserved and not given yet."""
        return sum(end - start for start, end in self._ranges)

    def take(self) -> int | None:
        """The next id, each larger than the last; None while none is reserved."""
        if self.left <= self.block // 2:
            self._reserve()
        if not self._ranges:
            return None
        current = self._ranges[0]
        given = current[0]
        current[0] += 1
        if current[0] >= current[1]:
            self._ranges.pop(0)
        return given

    def _reserve(self) -> None:
        """One more block, committed on the log's mark; a failure logged and tried later."""
        if time.monotonic() < self._next_try:
            return
        try:
            start = self._commit()
        except sqlite3.Error as e:
            if self.error is None:
                logger.error(
                    "%s: cannot reserve person ids (%s); %d left, new people wait for an id "
                    "once they are used",
                    self.path,
                    e,
                    self.left,
                )
            self.error = str(e)
            self._next_try = time.monotonic() + self._delay
            self._delay = min(2 * self._delay, 2.0)
            return
        if self.error is not None:
            logger.warning("%s: person ids reserved again", self.path)
        self.error, self._delay = None, self.retry_s
        end = start + self.block
        if self._ranges and self._ranges[-1][1] == start:
            self._ranges[-1][1] = end  # contiguous: one range
        else:
            self._ranges.append([start, end])
        self.reserved_to = end

    def _commit(self) -> int:
        """The first id of a block reserved and committed (at or above reserved_to)."""
        db = connect_writer(self.path, self.busy_s, create=True)
        try:
            create_schema(db)  # a log not made yet: made as the event sink makes it
            raise_marks(db)
            db.execute("BEGIN IMMEDIATE")
            try:
                start = take(db, MARK, self.block, floor=self.reserved_to)
                db.execute("COMMIT")
            except BaseException:
                if db.in_transaction:
                    db.execute("ROLLBACK")
                raise
        finally:
            db.close()
        return start
