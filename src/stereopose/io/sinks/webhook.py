"""Zone events POSTed as JSON to an HTTP(S) URL, from a background thread that no reply of the
remote end can stop.

Every event ends in exactly one count: `delivered` (a 2xx status came back), `failed` (its
tries ran out, or the receiver refused it with a 4xx status other than 408/425/429) or
`dropped` (the queue was full, or the sink closed before its turn). A try is bounded as a
whole, connecting, sending and reading the reply together, by timeout_s: a receiver that
never answers, or answers one byte at a time, has its connection cut. Whatever a reply is
(a bad status line, a body shorter than announced, a reset, nothing at all), it ends that try
only; the thread goes on with the next. A 2xx status counts as delivered whatever the body.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import logging
import queue
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from stereopose.alarms import Change
from stereopose.errors import StereoposeError
from stereopose.io.records import event_record
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.sinks.health import OutputHealth
from stereopose.io.source import shown_url
from stereopose.types import Event

logger = logging.getLogger(__name__)

RETRY_STATUSES = frozenset({408, 425, 429})  # and every 5xx: the receiver may do better later
BODY_LIMIT = 65536  # bytes of a reply read at most: the body is not ours to judge


@dataclass(eq=False)
class _Item:
    """One event on its way; `outcome` is set once ("delivered", "failed" or "dropped")."""

    event: Event | None
    outcome: str | None = None
    change: dict | None = None  # an incident's change instead of an event (write_changes)


class WebhookSink(ClosesOnce):
    """POSTs events as JSON to a URL from a background thread, never blocking `write`; an
    alarm output (io.sinks.health.AlarmOutput).

    queue_size: events waiting at most; more are dropped. An event whose POST fails (no reply
    within timeout_s, a broken reply, a 5xx, 408, 425 or 429 status) is tried again `retries`
    times, waiting backoff_s, 2 backoff_s, ... (capped at max_backoff_s); then it is counted
    failed. `close` waits up to drain_timeout_s for the queue to empty; the events still
    waiting are dropped. After close, `incomplete` says how many were not delivered (None: all
    were).
    """

    stage = "write"

    def __init__(
        self,
        url: str,
        queue_size: int = 1000,
        retries: int = 4,
        backoff_s: float = 0.5,
        max_backoff_s: float = 4.0,
        timeout_s: float = 5.0,
        drain_timeout_s: float = 10.0,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise StereoposeError(
                f"webhook URL must start with http:// or https://, got {shown_url(url)!r}"
            )
        try:
            self._port = parts.port
        except ValueError:
            raise StereoposeError(
                f"webhook URL {shown_url(url)!r}: the port is not a number"
            ) from None
        self.url = url
        self.shown = shown_url(url)  # for messages: no credentials, no query
        self._https, self._host = parts.scheme == "https", parts.hostname
        self._target = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
        self.retries, self.backoff_s, self.max_backoff_s = retries, backoff_s, max_backoff_s
        self.timeout_s, self.drain_timeout_s = timeout_s, drain_timeout_s
        self.queue: queue.Queue[_Item | None] = queue.Queue(maxsize=queue_size)
        self.delivered = self.dropped = self.failed = self.retried = 0
        self.incomplete: str | None = None
        self._lock = threading.Lock()
        self._current: _Item | None = None
        self._failing = False  # within a spell of failures: logged once, not per event
        self._last_try: str | None = None  # why the last try failed; None: it delivered
        self._stop = threading.Event()
        self._sleep = sleep or self._stop.wait
        self._thread = threading.Thread(target=self._run, name="webhook", daemon=True)
        self._thread.start()

    @property
    def sent(self) -> int:
        """The events delivered (the older name)."""
        return self.delivered

    def write(self, frame: FrameResult) -> None:
        self.write_events(frame.events)

    def write_events(self, events: Iterable[Event]) -> None:
        for e in events:
            try:
                self.queue.put_nowait(_Item(e))
            except queue.Full:
                with self._lock:
                    self.dropped += 1

    def write_changes(self, changes: Iterable[Change]) -> None:
        """Incident changes (alarms.Change), each POSTed as {"incident_change": true,
        "type": "incident_change", "kind": "incident", ...Change.to_dict()}: a receiver tells
        them from events by that key, and one that reads every body as an event sees a type
        it does not know (never a body without `type`). Queued, counted and dropped like the
        events."""
        for c in changes:
            body = {
                "incident_change": True,
                "type": "incident_change",
                "kind": "incident",
                **c.to_dict(),
            }
            try:
                self.queue.put_nowait(_Item(None, change=body))
            except queue.Full:
                with self._lock:
                    self.dropped += 1

    def _settle(self, item: _Item, outcome: str) -> None:
        """Count `item` once, in `outcome`'s count."""
        with self._lock:
            if item.outcome is not None:
                return
            item.outcome = outcome
            setattr(self, outcome, getattr(self, outcome) + 1)

    # -- the sending thread ----------------------------------------------------------------

    def _post(self, body: bytes) -> int:
        """One try: the reply's status. The whole exchange is cut after timeout_s."""
        cls = http.client.HTTPSConnection if self._https else http.client.HTTPConnection
        conn = cls(self._host, self._port, timeout=self.timeout_s)
        cut = threading.Event()

        def cut_off() -> None:  # wakes a read blocked on a silent or dripping receiver
            cut.set()
            sock = conn.sock
            if sock is not None:
                with contextlib.suppress(OSError):  # already closed: nothing to wake
                    sock.shutdown(socket.SHUT_RDWR)

        timer = threading.Timer(self.timeout_s, cut_off)
        timer.daemon = True
        timer.start()
        try:
            headers = {"Content-Type": "application/json", "Connection": "close"}
            conn.request("POST", self._target, body=body, headers=headers)
            resp = conn.getresponse()
            try:
                resp.read(BODY_LIMIT)
            except Exception as e:  # a short or broken body: the status already came
                logger.debug("webhook %s: reply body: %r", self.shown, e)
            return resp.status
        except Exception as e:
            if cut.is_set():
                raise TimeoutError(f"no complete reply within {self.timeout_s:g} s") from e
            raise
        finally:
            timer.cancel()
            conn.close()

    def _deliver(self, item: _Item) -> str:
        """Tries `item` until it is delivered, refused or out of tries; the outcome."""
        doc = item.change if item.event is None else event_record(item.event)
        body = json.dumps(doc).encode()
        delay = self.backoff_s
        for attempt in range(self.retries + 1):
            try:
                status = self._post(body)
            except Exception as e:  # whatever the reply was, it ends this try only
                why, again = f"{type(e).__name__}: {e}", True
                self._last_try = type(e).__name__  # for health: never the URL or its host
            else:
                if 200 <= status < 300:
                    self._last_try = None
                    if self._failing:
                        logger.warning("webhook %s: delivering again", self.shown)
                    self._failing = False
                    return "delivered"
                why, again = f"HTTP {status}", status in RETRY_STATUSES or status >= 500
                self._last_try = why
            if not again or attempt == self.retries or self._stop.is_set():
                self._log_failure(item, attempt + 1, why)
                return "failed"
            self.retried += 1
            self._sleep(delay)
            delay = min(2 * delay, self.max_backoff_s)
        return "failed"  # not reached: the last try returns above

    def _log_failure(self, item: _Item, tries: int, why: str) -> None:
        log = logger.debug if self._failing else logger.warning
        if item.event is not None:
            what = f"event of frame {item.event.frame}"
        else:
            assert item.change is not None  # an item is an event or a change
            what = f"change of incident {item.change['incident']['id']}"
        log(
            "webhook %s: %s not delivered after %d tr%s: %s",
            self.shown,
            what,
            tries,
            "y" if tries == 1 else "ies",
            why,
        )
        self._failing = True

    def _run(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            with self._lock:
                self._current = item
            try:
                outcome = self._deliver(item)
            except Exception:  # never: _deliver catches a try's errors; the thread lives on
                logger.exception("webhook %s: sending an event failed", self.shown)
                outcome = "failed"
            self._settle(item, outcome)
            with self._lock:
                self._current = None

    output_name = "webhook"

    @property
    def label(self) -> str:
        return self.shown

    def queued(self) -> int:
        return self.queue.qsize()

    def figures(self) -> dict:
        """status.json's `webhook`: delivered, failed, dropped, retried, queued."""
        return {
            "delivered": self.delivered,
            "failed": self.failed,
            "dropped": self.dropped,
            "retried": self.retried,
            "queued": self.queued(),
        }

    def health(self) -> OutputHealth:
        """Not ok from a failed try until the next delivery; waiting: queued and on the wire."""
        with self._lock:
            waiting = self.queue.qsize() + (self._current is not None)
            last = self._last_try
        if last is None:
            return OutputHealth(True, waiting)
        return OutputHealth(False, waiting, f"the receiver is not taking events ({last})")

    # -- closing ---------------------------------------------------------------------------

    def _busy(self) -> bool:
        with self._lock:
            return not self.queue.empty() or self._current is not None

    def _close(self) -> list[Path]:
        deadline = time.monotonic() + self.drain_timeout_s
        while self._busy() and time.monotonic() < deadline:
            time.sleep(0.02)
        self._stop.set()  # retries stop waiting; what is still queued is dropped
        while True:
            try:
                item = self.queue.get_nowait()
            except queue.Empty:
                break
            if item is not None:
                self._settle(item, "dropped")
        self.queue.put(None)  # room: the queue was just emptied, and nothing else adds
        self._thread.join(timeout=self.timeout_s + 1.0)
        with self._lock:
            current = self._current
        if current is not None:  # still on the wire: given up, counted once all the same
            self._settle(current, "dropped")
        counts = (
            f"{self.delivered} delivered, {self.failed} failed, {self.dropped} dropped "
            "(queue full or closing)"
        )
        if self.failed or self.dropped:
            self.incomplete = f"{self.failed + self.dropped} event(s) not delivered: {counts}"
            logger.warning("webhook %s: %s", self.shown, counts)
        else:
            logger.info("webhook %s: %s", self.shown, counts)
        return []
