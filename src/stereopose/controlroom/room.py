"""The control room's own incidents about its sites: a site offline, a site's clock off, bad
messages of a kind (cleared once none came for QUIET_S)."""

from __future__ import annotations

import logging
import time

from stereopose.controlroom.store import ControlStore, StoreError

logger = logging.getLogger(__name__)

QUIET_S = 600.0  # a control-room incident about bad messages clears after this long without


class RoomIncidents:
    """Raises and clears the control room's incidents in the store (the ingest's thread).
    counts: the ingest's figures (room_incidents, store_errors)."""

    def __init__(
        self, store: ControlStore, counts: dict[str, int], clock_tolerance_s: float = 5.0
    ) -> None:
        self.store, self.counts = store, counts
        self.clock_tolerance_s = float(clock_tolerance_s)
        # (site, kind) -> when a bad message of that kind last came (the incident's clearing)
        self._bad_at: dict[tuple[str, str], float] = {}
        self._clock_off: set[str] = set()  # sites with an active clock incident

    def bad(self, site: str, kind: str, detail: str, priority: int = 2) -> None:
        """A control-room incident of `kind` about `site` (one while active), cleared once no
        such thing came for QUIET_S."""
        self._bad_at[(site, kind)] = time.monotonic()
        self._raise(site, kind, priority, detail[:500])

    def clear_quiet(self) -> None:
        now = time.monotonic()
        for (site, kind), at in list(self._bad_at.items()):
            if now - at > QUIET_S and self._clear(site, kind):
                del self._bad_at[(site, kind)]

    def clock(self, site: str, offset: float) -> None:
        """An incident while the site's clock is off by more than the bound."""
        off = abs(offset) > self.clock_tolerance_s
        if off and site not in self._clock_off:
            self._clock_off.add(site)
            detail = f"the site's clock is {offset:+.1f} s from the control room's"
            self._raise(site, "site_clock", 3, detail)
        elif not off and site in self._clock_off:
            self._clock_off.discard(site)
            self._clear(site, "site_clock")

    def site_state(self, site: str, state: str) -> bool:
        """The site's state in the store; offline raises an incident, live clears it. False
        when the store failed (logged, counted)."""
        now = time.time()
        try:
            self.store.set_site(site, state=state, last_seen=now)
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
            return False
        if state == "offline":
            return self._raise(site, "site_offline", 2, "the site is offline")
        return self._clear(site, "site_offline")

    def _raise(self, site: str, kind: str, priority: int, detail: str) -> bool:
        try:
            raised = self.store.raise_room_incident(site, kind, priority, detail, time.time())
            if raised is not None:
                self.counts["room_incidents"] += 1
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
            return False
        return True

    def _clear(self, site: str, kind: str) -> bool:
        try:
            self.store.clear_room_incidents(site, kind, time.time())
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
            return False
        return True
