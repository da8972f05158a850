"""The limit on password guesses: by client address first, then by account, counted before
the password is checked, so that a guesser is slowed and nobody else is locked out.

A login (or an own-password change, which checks the old password) asks `begin(address,
name)` for an attempt before the hash is checked, and tells `end(attempt, ok)` how it went:

- Address: at most MAX_FAILURES failed or unfinished attempts per client address within
  WINDOW_S (whatever the names); beyond, 429 with Retry-After. An attempt holds its place from
  `begin`, so a parallel burst from one address gets MAX_FAILURES checks, the rest 429. A
  success frees its own place only: logging into one's own account does not forgive guesses.
- Account: a token bucket per name, ACCOUNT_BURST deep, refilled at ACCOUNT_PER_HOUR: about
  that many checked passwords per account per hour, from all addresses together. A token is
  taken at `begin` and given back on success.
- Nobody else locked out: when a name's bucket is empty, an address that has not failed for
  that name within PAIR_S still gets its password checked (one attempt at a time: it is marked
  at `begin`, unmarked on success); only addresses that failed for the name wait for a token.
  So the right password from a clean address always gets in; a guesser gets one try per
  fresh address per name per PAIR_S beyond the account's budget.
- Names are not told apart: an unknown name is limited as a known one (a 429 never says that
  a name exists). Bounded: at most MAX_TRACKED addresses, names and (address, name) pairs, the
  least recently used forgotten first (a forgotten bucket is a full one, which an attacker
  needs MAX_TRACKED other names' failures within the bucket's refill time to bring about).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass

WINDOW_S = 60.0
MAX_FAILURES = 5  # per client address within WINDOW_S
ACCOUNT_PER_HOUR = 100.0  # checked passwords per account, in the long run
ACCOUNT_BURST = 20  # of them at once
PAIR_S = 3600.0  # how long an address's failure for a name is remembered
MAX_TRACKED = 10_000  # client addresses, names and pairs


class TooManyAttemptsError(Exception):
    """Too many attempts: retry_after seconds (at least 1) before the next may be checked."""

    def __init__(self, retry_after: float, why: str) -> None:
        super().__init__(why)
        self.retry_after = max(1, math.ceil(retry_after))
        self.why = why


@dataclass
class Attempt:
    """One attempt let through by `begin`: what it holds until `end`."""

    address: str
    name: str
    at: float
    token: bool  # took one of the account's tokens (else it came in as a clean address)


class LoginLimiter:
    """See the module. clock: monotonic seconds."""

    def __init__(
        self,
        *,
        window_s: float = WINDOW_S,
        max_failures: int = MAX_FAILURES,
        per_hour: float = ACCOUNT_PER_HOUR,
        burst: int = ACCOUNT_BURST,
        pair_s: float = PAIR_S,
        max_tracked: int = MAX_TRACKED,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.window_s, self.max_failures = window_s, max_failures
        self.rate, self.burst, self.pair_s = per_hour / 3600.0, float(burst), pair_s
        self.max_tracked = max_tracked
        self.clock = clock
        self._lock = threading.Lock()
        self._addresses: OrderedDict[str, deque[float]] = OrderedDict()
        self._buckets: OrderedDict[str, list[float]] = OrderedDict()  # name -> [tokens, at]
        self._pairs: OrderedDict[tuple[str, str], float] = OrderedDict()  # -> last failure
        self.checked = 0  # attempts let through
        self.refused = 0  # attempts answered 429
        self.clean = 0  # of those let through, by a clean address past an empty bucket

    def begin(self, address: str, name: str) -> Attempt:
        """An attempt for `name` from `address`, its places taken; TooManyAttemptsError when it must
        wait (nothing is taken then)."""
        now = self.clock()
        with self._lock:
            times = self._recent(address, now)
            if len(times) >= self.max_failures:
                self.refused += 1
                wait = times[0] + self.window_s - now
                raise TooManyAttemptsError(wait, "too many failed attempts from this address")
            bucket = self._bucket(name, now)
            pair = (address, name)
            if bucket[0] >= 1.0:
                bucket[0] -= 1.0
                token = True
            elif self._failed_lately(pair, now):
                self.refused += 1
                wait = (1.0 - bucket[0]) / self.rate
                raise TooManyAttemptsError(wait, "too many failed attempts for this account")
            else:
                token = False  # a clean address: checked, one at a time
                self._mark(pair, now)
                self.clean += 1
            times.append(now)
            self._track(self._addresses, address)
            self.checked += 1
        return Attempt(address, name, now, token)

    def end(self, attempt: Attempt, ok: bool) -> None:
        """How the attempt went: a failure keeps its places (the address's and the account's)
        and marks the address for the name; a success gives them back."""
        now = self.clock()
        pair = (attempt.address, attempt.name)
        with self._lock:
            if not ok:
                self._mark(pair, now)
                return
            times = self._addresses.get(attempt.address)
            if times is not None:
                with contextlib.suppress(ValueError):  # already out of the window
                    times.remove(attempt.at)
            bucket = self._buckets.get(attempt.name)
            if attempt.token and bucket is not None:
                bucket[0] = min(self.burst, bucket[0] + 1.0)
            self._pairs.pop(pair, None)

    def _recent(self, address: str, now: float) -> deque[float]:
        times = self._addresses.get(address)
        if times is None:
            times = self._addresses[address] = deque()
        while times and times[0] <= now - self.window_s:
            times.popleft()
        return times

    def _bucket(self, name: str, now: float) -> list[float]:
        bucket = self._buckets.get(name)
        if bucket is None:
            bucket = self._buckets[name] = [self.burst, now]
        else:
            bucket[0] = min(self.burst, bucket[0] + (now - bucket[1]) * self.rate)
            bucket[1] = now
        self._track(self._buckets, name)
        return bucket

    def _failed_lately(self, pair: tuple[str, str], now: float) -> bool:
        at = self._pairs.get(pair)
        if at is not None and now - at >= self.pair_s:
            del self._pairs[pair]
            return False
        return at is not None

    def _mark(self, pair: tuple[str, str], now: float) -> None:
        self._pairs[pair] = now
        self._track(self._pairs, pair)

    def _track(self, table: OrderedDict, key: object) -> None:
        table.move_to_end(key)
        while len(table) > self.max_tracked:
            table.popitem(last=False)
