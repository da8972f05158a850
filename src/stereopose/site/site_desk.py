"""The running site, edited while the service runs: `GET /api/site` and `PUT /api/site`
(site.http.api.site), SIGHUP (the file edited by hand).

A new site is checked as `load_site` checks a file (and against the tickets, which name zones),
then written over the site file atomically (a temporary file renamed over it), keeping its
comments where its tables stay (tomlkit: a zone's table kept and its keys changed in place; a new
zone appended; a removed one taken out), and handed to the frame loop, which takes it at its next
step (`take`): no restart, no camera reconnected, no track lost. Every version is kept in
`<data>/site-history/` (its TOML text, who made it and when; the latest MAX_HISTORY kept), so an
earlier one can be read and restored. A PUT names the version it edits: another admin's change
since is a conflict (409), never overwritten. A state source's endpoint is shown with its
password hidden (user:***@host) and given its password back when it comes back so. Nothing is
half-applied: a site that does not check, or a file that cannot be written, leaves the running
site, the file and the version as they were.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stereopose.errors import ConfigError, StereoposeError
from stereopose.fence.site import Site, format_site, load_site, parse_site, site_doc, site_version
from stereopose.secrets import redact
from stereopose.site.plan_background import Background
from stereopose.types import Rig

__all__ = ["SiteChange", "SiteConflictError", "SiteDesk"]

logger = logging.getLogger(__name__)

MAX_HISTORY = 200  # versions kept in the history folder
MAX_SWITCHES = 100  # zone switches waiting for the next step, at most
INDEX = "index.jsonl"


class SiteConflictError(StereoposeError):
    """The version edited is not the current one (another change came first)."""


@dataclass(frozen=True)
class SiteChange:
    """A new site for the frame loop: the one it replaces, who made it and its version."""

    old: Site
    new: Site
    by: str
    version: str


class SiteDesk:
    """See the module. check(site): a ConfigError when the running service cannot take
    `site` (a ticket naming a zone it removes); None: nothing more to check. rig: the
    cameras, for the zones seen in their pictures (site.site_views)."""

    def __init__(
        self,
        path: Path,
        site: Site,
        history_dir: Path,
        check: Callable[[Site], None] | None = None,
        rig: Rig | None = None,
        started: bool = True,
    ) -> None:
        self.path, self.history_dir, self.check = Path(path), Path(history_dir), check
        self.rig = rig  # the cameras (the Site tab's views of the zones; None: none)
        self.background = Background(self.history_dir.parent / "site-plan")  # the plan's drawing
        self.site, self.version = site, site_version(site)
        self._lock = threading.Lock()
        self._pending: SiteChange | None = None
        self._notes: list[tuple[str, str]] = []  # (event type, text) for the next step
        # zones switched off or on (zone, on, by), for the next step; at most MAX_SWITCHES
        self._switches: deque[tuple[str, bool, str]] = deque(maxlen=MAX_SWITCHES)
        self.switches_dropped = 0  # switches not taken in time: the oldest went
        self._broken = False  # the file did not load at the last reload
        self.changes = 0  # sites taken since the start
        # the site as the service starts with it, kept in the history by start()
        self._first: tuple[str, str] | None = (self.version, self.path.read_text(encoding="utf-8"))
        if started:
            self.start()

    def start(self) -> None:
        """The site the service started with, kept in the history: once the service's start
        succeeded (started=False at construction), so that a refused start leaves no file."""
        first, self._first = self._first, None
        if first is not None:
            self._remember(*first, "the site file")

    def set_rig(self, rig: Rig) -> None:
        """The cameras placed again (the calibration keeper, the surveyed points): the zones
        drawn in their pictures from now on."""
        self.rig = rig

    # -- reading -----------------------------------------------------------------------------

    def current(self) -> dict[str, object]:
        with self._lock:
            return {"version": self.version, "site": _hidden(site_doc(self.site))}

    def history(self) -> list[dict[str, object]]:
        """The versions kept, newest first: {"version", "by", "at"} (at: Unix time)."""
        return list(reversed(self._index()))

    def at_version(self, version: str) -> dict[str, object] | None:
        """A version kept: {"version", "by", "at", "site"}; None when not kept."""
        row = next((r for r in self._index() if r["version"] == version), None)
        path = self.history_dir / f"{version}.toml"
        if row is None or not path.is_file():
            return None
        try:
            site = load_site(path)
        except ConfigError as e:  # a kept file damaged: as if not kept, and said
            logger.warning("site: version %s unreadable: %s", version, e)
            return None
        return {**row, "site": _hidden(site_doc(site))}

    # -- changing ----------------------------------------------------------------------------

    def put(self, doc: object, version: str, by: str) -> str:
        """The new site `doc` (the site file's keys), edited from `version`: its version once
        written and handed to the frame loop. SiteConflictError when `version` is not the current
        one; ConfigError naming the key when it does not check."""
        with self._lock:
            if version != self.version:
                raise SiteConflictError(
                    f"the site changed since version {version} (now {self.version}): reload it"
                )
            new = parse_site(_with_passwords(doc, site_doc(self.site)), self.path)
            return self._apply(new, _merged(self.path, new), by)

    def reload(self, by: str = "the site file (SIGHUP)") -> str | None:
        """The site file read again (edited by hand): its version, or None when unchanged or
        when it does not load: then the running site stays, and the next step raises
        `site_invalid` naming the file and the error (`site_valid` once it loads again)."""
        with self._lock:
            try:
                new = load_site(self.path)
                version = None if site_version(new) == self.version else self._apply(new, None, by)
            except ConfigError as e:
                logger.error("site: %s; the running site kept (version %s)", e, self.version)
                self._notes.append(("site_invalid", str(e)))
                self._broken = True
                return None
            if self._broken:
                self._broken = False
                self._notes.append(("site_valid", f"{self.path}: loads again"))
            return version

    def take_notes(self) -> list[tuple[str, str]]:
        """(event type, text) of the reloads since the last step (the frame loop's thread)."""
        with self._lock:
            notes, self._notes = self._notes, []
            return notes

    def switch_zone(self, zone: str, on: bool, by: str) -> None:
        """`zone` switched off (its events stop; who is in it exits) or on again, at the next
        step. Not written to the file: a restart has every zone on. ConfigError when the
        running site (or the one waiting) has no such zone."""
        with self._lock:
            site = self._pending.new if self._pending is not None else self.site
            if zone not in {z.name for z in site.zones}:
                raise ConfigError(f"zone {zone[:80]!r}: no such zone in the site")
            self.switches_dropped += len(self._switches) == MAX_SWITCHES
            self._switches.append((zone, bool(on), by))

    def take_switches(self) -> list[tuple[str, bool, str]]:
        """(zone, on, by) of the switches since the last step, in order (the frame loop's
        thread)."""
        with self._lock:
            out = list(self._switches)
            self._switches.clear()
            return out

    def take(self) -> SiteChange | None:
        """The change waiting for the frame loop, once (the frame loop's thread)."""
        with self._lock:
            change, self._pending = self._pending, None
            return change

    def _apply(self, new: Site, text: str | None, by: str) -> str:
        """(under the lock) `new` checked against the service, written (text: the file's new
        text; None: the file already holds it), remembered, and waiting for the frame loop."""
        if self.check is not None:
            self.check(new)
        version = site_version(new)
        if version == self.version:
            return version
        if text is not None:
            _write_atomic(self.path, text)
        else:
            text = self.path.read_text(encoding="utf-8")
        old = self._pending.old if self._pending is not None else self.site
        self.site, self.version = new, version
        self._pending = SiteChange(old, new, by, version)
        self.changes += 1
        self._remember(version, text, by)
        logger.info("site: version %s by %s, taken at the next step", version, by)
        return version

    # -- history -----------------------------------------------------------------------------

    def _index(self) -> list[dict[str, object]]:
        path = self.history_dir / INDEX
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except OSError:
            return []
        rows = []
        for line in lines:
            try:
                row = json.loads(line)
            except ValueError:
                continue  # a line cut by a crash: the others stand
            if isinstance(row, dict) and isinstance(row.get("version"), str):
                rows.append(row)
        return rows

    def _remember(self, version: str, text: str, by: str) -> None:
        """The version's text and who made it, kept (the oldest beyond MAX_HISTORY pruned);
        a history that cannot be written is logged, never stops the change."""
        self.start()  # a change before the start: the first version kept before it
        try:
            self.history_dir.mkdir(parents=True, exist_ok=True)
            rows = [r for r in self._index() if r["version"] != version]
            rows.append({"version": version, "by": by, "at": time.time()})
            for gone in rows[:-MAX_HISTORY]:
                (self.history_dir / f"{gone['version']}.toml").unlink(missing_ok=True)
            rows = rows[-MAX_HISTORY:]
            _write_atomic(self.history_dir / f"{version}.toml", text)
            _write_atomic(self.history_dir / INDEX, "".join(json.dumps(r) + "\n" for r in rows))
        except OSError as e:
            logger.warning("site: the history in %s not written: %s", self.history_dir, e)


def _merged(path: Path, new: Site) -> str:
    """The site file's text holding `new`, its comments kept where its tables stay; the plain
    text of the site (format_site) when the file cannot be merged into."""
    import tomlkit

    doc = site_doc(new)
    try:
        old = tomlkit.parse(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        logger.warning("site: %s rewritten without its comments: %s", path, e)
        return format_site(new)
    for key in list(old):
        if key not in doc:
            del old[key]
    for key, value in doc.items():
        tables = old.get(key)
        if key in ("zones", "rules") and isinstance(tables, list) and isinstance(value, list):
            _merge_tables(tables, value)
        else:
            old[key] = value
    text = tomlkit.dumps(old)
    try:  # what was merged must read back as the site: else the plain text
        if site_version(parse_site(tomlkit.parse(text).unwrap(), path)) == site_version(new):
            return text
    except (ConfigError, ValueError) as e:
        logger.warning("site: %s merged wrongly (%s); written without its comments", path, e)
    return format_site(new)


def _merge_tables(tables: list, items: list[dict[str, object]]) -> None:
    """The file's zone (or rule) tables made `items`: one of the same name kept (its keys
    changed in place, their comments with them), a new one appended, a removed one taken out,
    in `items`' order."""
    import tomlkit

    by_name = {str(t.get("name")): t for t in tables}
    kept = []
    for item in items:
        table = by_name.get(str(item.get("name")))
        fresh = table is None
        if table is None:
            table = tomlkit.table()
        for key in list(table):
            if key not in item:
                del table[key]
        for key, value in item.items():
            if table.get(key) != value:
                table[key] = value
        if fresh:
            table.add(tomlkit.nl())
        kept.append(table)
    while len(tables):
        tables.pop()
    for table in kept:
        tables.append(table)


def _write_atomic(path: Path, text: str) -> None:
    """`text` into `path` by a temporary file beside it renamed over it (its mode kept)."""
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _endpoints(value: object, change: Callable[[str], str]) -> Any:
    """`value` (a site's keys) with every state source's `endpoint` changed by `change`."""
    if isinstance(value, dict):
        return {
            k: change(v) if k == "endpoint" and isinstance(v, str) else _endpoints(v, change)
            for k, v in value.items()
        }
    if isinstance(value, list):
        return [_endpoints(v, change) for v in value]
    return value


def _hidden(doc: dict[str, object]) -> dict[str, object]:
    """The site's keys as the API shows them: an endpoint's password as *** (secrets.redact)."""
    return _endpoints(doc, redact)


def _with_passwords(doc: object, current: dict[str, object]) -> Any:
    """A site sent back with its endpoints' passwords hidden: each hidden endpoint given the
    running site's password again; one that hides a password the running site does not hold
    is a ConfigError (its password is never written as ***)."""
    known: dict[str, str] = {}
    _endpoints(current, lambda e: known.setdefault(redact(e), e))

    def restore(endpoint: str) -> str:
        if ":***@" not in endpoint:  # not hidden: as given
            return endpoint
        if endpoint in known:
            return known[endpoint]
        raise ConfigError(
            f"endpoint {redact(endpoint)}: its password is hidden and not the running site's; "
            "give it again"
        )

    return _endpoints(doc, restore)
