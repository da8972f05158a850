"""Speakers' health: RTP over UDP is never answered, so a speaker is known to be up only where
it has a `health_url` (its web page or API; answered 2xx while it is up). Each is asked every
CHECK_S on a thread of its own; a speaker without one is "not verifiable".

    checks = SpeakerChecks(on_health=lambda name, up, why: ...)
    checks.watch(speaker_specs)           # at start and at each new site
    checks.state("bay1_pa")               # "up" | "down" | "unknown" | "not verifiable"
    checks.close()

`on_health(name, False, why)` once when it stops answering, `on_health(name, True, "")` when
it answers again (as onsite.modbus's signals). Its password never reaches a log or a message.
"""

from __future__ import annotations

import base64
import logging
import threading
import urllib.error
import urllib.request
from collections.abc import Callable, Sequence
from urllib.parse import unquote, urlsplit, urlunsplit

from stereopose.onsite.settings import SpeakerSpec
from stereopose.secrets import redact

__all__ = ["SpeakerChecks"]

logger = logging.getLogger(__name__)

CHECK_S = 10.0
TIMEOUT_S = 2.0


def _request(url: str) -> urllib.request.Request:
    """A GET of `url`, its user:password@ (if any) sent as HTTP basic authentication."""
    parts = urlsplit(url)
    if parts.username is None:
        return urllib.request.Request(url)
    host = parts.hostname or ""
    netloc = (f"[{host}]" if ":" in host else host) + (f":{parts.port}" if parts.port else "")
    login = f"{unquote(parts.username)}:{unquote(parts.password or '')}"
    request = urllib.request.Request(urlunsplit(parts._replace(netloc=netloc)))
    request.add_header("Authorization", "Basic " + base64.b64encode(login.encode()).decode())
    return request


def _ask(url: str, timeout_s: float) -> str:
    """'' when `url` answers 2xx; else why not."""
    try:
        with urllib.request.urlopen(_request(url), timeout=timeout_s) as r:
            return "" if 200 <= r.status < 300 else f"answered HTTP {r.status}"
    except urllib.error.HTTPError as e:
        return f"answered HTTP {e.code}"
    except (urllib.error.URLError, OSError, ValueError) as e:
        reason = getattr(e, "reason", e)
        return f"no answer ({type(reason).__name__})"


class SpeakerChecks:
    """See the module. on_health(name, up, why): a speaker's health changed."""

    def __init__(
        self,
        on_health: Callable[[str, bool, str], None],
        check_s: float = CHECK_S,
        timeout_s: float = TIMEOUT_S,
    ) -> None:
        self.on_health, self.check_s, self.timeout_s = on_health, check_s, timeout_s
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._urls: dict[str, str | None] = {}
        self._up: dict[str, bool | None] = {}
        self._thread: threading.Thread | None = None

    def watch(self, speakers: Sequence[SpeakerSpec]) -> None:
        """These speakers checked from now on (a changed URL: unknown until asked again)."""
        with self._lock:
            urls = {s.name: s.health_url for s in speakers}
            self._up = {
                n: self._up.get(n) if self._urls.get(n) == u else None for n, u in urls.items()
            }
            self._urls = urls
        if any(urls.values()) and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="speaker health", daemon=True)
            self._thread.start()
        self._wake.set()

    def state(self, name: str) -> str:
        with self._lock:
            if self._urls.get(name) is None:
                return "not verifiable"
            up = self._up.get(name)
        return "unknown" if up is None else "up" if up else "down"

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.clear()
            with self._lock:
                urls = {n: u for n, u in self._urls.items() if u}
            for name, url in urls.items():
                if self._stop.is_set():
                    return
                why = _ask(url, self.timeout_s)
                up = not why
                with self._lock:
                    if self._urls.get(name) != url:
                        continue  # changed meanwhile
                    before, self._up[name] = self._up.get(name), up
                if (before is None and not up) or (before is not None and before != up):
                    if why:
                        logger.warning("speaker %s (%s): %s", name, redact(url), why)
                    self.on_health(name, up, why)
            self._wake.wait(self.check_s)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(self.timeout_s + 1.0)
