"""A few places (live streams, clip players) shared fairly among the console's users.

`FairPlaces(total, per_user=..., reserved=...)`: at most `total` places held at once, at most
`per_user` by one user, and `reserved` of them kept for privileged users (operators and
admins): viewers together hold at most total - reserved.

- A user at their own cap who asks again gets a place, and their own oldest is ended (its
  holder told why, through the callback given with it): the newest page is the one they look
  at, and a place left by a page that vanished without closing its connection (a workstation
  that lost its network) never keeps its user out.
- A privileged user finds a free place while any is free (the reserved ones too); when all are
  held, the oldest viewer's place is ended for them. Only when privileged users hold all of
  them is the answer no.
- A viewer finds a place while fewer than total - reserved are viewers' and one is free;
  otherwise no.

Each place is given back once (`give_back`, also after it was ended); callbacks run outside
the lock. Counters: `replaced` (a user's own oldest ended), `bumped` (a viewer's ended for an
operator or admin), `refused`.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

REPLACED = "replaced by a newer one of the same user"
BUMPED = "its place was needed by an operator or admin"


@dataclass(eq=False)
class Place:
    """One place held. ended: why it was ended for another (None while it stands)."""

    user: str
    privileged: bool
    seq: int
    on_end: Callable[[str], None] | None = field(default=None, repr=False)
    ended: str | None = None


class FairPlaces:
    """See the module."""

    def __init__(self, total: int, *, per_user: int, reserved: int = 0) -> None:
        self.total, self.per_user, self.reserved = total, max(1, per_user), reserved
        self._lock = threading.Lock()
        self._held: list[Place] = []  # oldest first
        self._seq = itertools.count()
        self.replaced = self.bumped = self.refused = 0

    def take(
        self, user: str, privileged: bool, on_end: Callable[[str], None] | None = None
    ) -> Place | None:
        """A place for `user`, or None (see the module); on_end(why) is called if it is
        later ended for another."""
        ended: list[Place] = []
        with self._lock:
            own = [p for p in self._held if p.user == user]
            if len(own) >= self.per_user:
                ended.append(self._end(own[0], REPLACED))
                self.replaced += 1
            place = None
            if privileged:
                if len(self._held) >= self.total:
                    viewers = [p for p in self._held if not p.privileged]
                    if viewers:
                        ended.append(self._end(viewers[0], BUMPED))
                        self.bumped += 1
                if len(self._held) < self.total:
                    place = Place(user, True, next(self._seq), on_end)
            else:
                viewers = sum(not p.privileged for p in self._held)
                if viewers < self.total - self.reserved and len(self._held) < self.total:
                    place = Place(user, False, next(self._seq), on_end)
            if place is None:
                self.refused += 1
            else:
                self._held.append(place)
        for p in ended:
            if p.on_end is not None:
                p.on_end(p.ended or "")
        return place

    def _end(self, place: Place, why: str) -> Place:
        self._held.remove(place)
        place.ended = why
        return place

    def give_back(self, place: Place) -> None:
        with self._lock:
            if place in self._held:
                self._held.remove(place)

    def held_by(self, user: str) -> int:
        with self._lock:
            return sum(p.user == user for p in self._held)

    def __len__(self) -> int:
        return len(self._held)
