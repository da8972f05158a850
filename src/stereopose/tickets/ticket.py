"""The ticket file (docs/formats.md#tickets): a work or operation ticket's id, title, kind,
the zones it isolates, its roles, and its steps in order, each a position (a zone of the site:
the operator's feet inside it) and a target (a zone: a hand inside it for `hold_s` is the
step's action). Every problem is a ConfigError naming the file, the key and the value."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from stereopose.errors import ConfigError
from stereopose.zones import Zone

__all__ = [
    "KINDS",
    "TICKET_HTML",
    "TICKET_JSON",
    "TICKET_SLOTS",
    "Ticket",
    "TicketStep",
    "check_ticket_site",
    "check_zones",
    "load_ticket",
    "parse_ticket",
]

KINDS = ("operation", "work")
TICKET_JSON = "ticket.json"  # the ticket a run followed, in its folder (the report's)
TICKET_HTML = "ticket.html"  # that ticket's report
TICKET_SLOTS = 8  # active tickets the SCADA sees at once (scada.points: a slot's points each)
POSTURES = ("standing", "walking", "bending", "crouching", "lying")  # behaviour.posture's
MAX_STEPS = 200
MAX_TEXT = 200
_TICKET_KEYS = {
    "id",
    "title",
    "kind",
    "isolated",
    "supervise_m",
    "absent_s",
    "lone_s",
    "roles",
    "steps",
}
_STEP_KEYS = {
    "name",
    "position",
    "target",
    "hold_s",
    "max_s",
    "optional",
    "facing_deg",
    "tolerance_deg",
    "posture",
    "both_hands",
}


@dataclass(frozen=True)
class TicketStep:
    """One step: its action is a hand (both: both_hands) inside `target` for `hold_s`, with the
    operator's feet inside `position`; step_timeout `max_s` after the previous step (None:
    never); facing_deg (degrees counter-clockwise from world +x, within tolerance_deg) and
    posture: optional conditions of the action."""

    name: str
    position: str
    target: str
    hold_s: float = 1.0
    max_s: float | None = 300.0
    optional: bool = False
    facing_deg: float | None = None
    tolerance_deg: float = 45.0
    posture: tuple[str, ...] | None = None
    both_hands: bool = False


@dataclass(frozen=True)
class Ticket:
    """A ticket (see the module). operator, supervisor: "auto" or a person id; supervisor None:
    none required. lone_s: lone_in_room after one person alone this long (None: not checked).
    path: the file it came from ("" when posted over the API)."""

    id: str
    title: str
    kind: str
    steps: tuple[TicketStep, ...]
    isolated: tuple[str, ...] = ()
    operator: str | int = "auto"
    supervisor: str | int | None = None
    supervise_m: float = 3.0
    absent_s: float = 10.0
    lone_s: float | None = 30.0
    path: str = ""

    def zones(self) -> set[str]:
        """Every zone the ticket names."""
        return {*self.isolated, *(s.position for s in self.steps), *(s.target for s in self.steps)}

    def to_dict(self) -> dict:
        """The ticket as its file holds it (the API's body, the report's)."""
        roles: dict[str, object] = {"operator": self.operator}
        if self.supervisor is not None:
            roles["supervisor"] = self.supervisor
        return {
            "id": self.id,
            "title": self.title,
            "kind": self.kind,
            "isolated": list(self.isolated),
            "supervise_m": self.supervise_m,
            "absent_s": self.absent_s,
            "lone_s": self.lone_s if self.lone_s is not None else False,
            "roles": roles,
            "steps": [
                {
                    k: (list(v) if isinstance(v, tuple) else v)
                    for k, v in {**vars(s), "max_s": s.max_s or False}.items()
                    if v is not None
                }
                for s in self.steps
            ],
        }


def load_ticket(path: str | Path) -> Ticket:
    """The ticket of a TOML file; ConfigError naming the file when it cannot be read or is not
    a ticket."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such ticket file") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the ticket: {e.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: not a valid TOML ticket: {e}") from None
    return parse_ticket(doc, str(path))


def parse_ticket(doc: object, where: str = "the ticket") -> Ticket:
    """A ticket from its document (the TOML file's or the API's JSON body)."""
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{where}: a ticket is a table of keys, got {type(doc).__name__}")
    unknown = sorted(set(doc) - _TICKET_KEYS)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}")
    tid = _text(doc.get("id"), f"{where}: id")
    kind = doc.get("kind", "operation")
    if kind not in KINDS:
        raise ConfigError(f"{where}: kind {kind!r}: expected one of {', '.join(KINDS)}")
    roles = doc.get("roles", {})
    if not isinstance(roles, Mapping) or set(roles) - {"operator", "supervisor"}:
        raise ConfigError(f"{where}: [roles] holds operator and supervisor only, got {roles!r}")
    steps = doc.get("steps")
    if not isinstance(steps, list) or not steps or len(steps) > MAX_STEPS:
        raise ConfigError(f"{where}: [[steps]]: 1 to {MAX_STEPS} steps are needed")
    parsed = tuple(_step(s, f"{where}: steps[{k}]") for k, s in enumerate(steps))
    names = [s.name for s in parsed]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"{where}: step name(s) given twice: {', '.join(map(repr, twice))}")
    isolated = doc.get("isolated", [])
    if not isinstance(isolated, list):
        raise ConfigError(f"{where}: isolated: a list of zone names, got {isolated!r}")
    lone = doc.get("lone_s", 30.0)
    return Ticket(
        id=tid,
        title=_text(doc.get("title", tid), f"{where}: title", empty=True),
        kind=kind,
        steps=parsed,
        isolated=tuple(_text(z, f"{where}: isolated") for z in isolated),
        operator=_role(roles.get("operator", "auto"), f"{where}: roles.operator"),
        supervisor=(
            None
            if roles.get("supervisor") is None
            else _role(roles["supervisor"], f"{where}: roles.supervisor")
        ),
        supervise_m=_number(doc.get("supervise_m", 3.0), f"{where}: supervise_m", 0.1, 100.0),
        absent_s=_number(doc.get("absent_s", 10.0), f"{where}: absent_s", 0.0, 86400.0),
        lone_s=None if lone in (None, False) else _number(lone, f"{where}: lone_s", 0.0, 86400.0),
        path=where if where != "the ticket" else "",
    )


def check_zones(ticket: Ticket, zones: Mapping[str, str], where: str = "") -> None:
    """ConfigError unless every zone the ticket names is a zone of the site (`zones`: name ->
    kind) and every isolated zone an energized one."""
    at = where or ticket.path or f"ticket {ticket.id}"
    missing = sorted(ticket.zones() - set(zones))
    if missing:
        raise ConfigError(
            f"{at}: zone(s) {', '.join(map(repr, missing))} not in the site file "
            f"(its zones: {', '.join(sorted(zones)) or 'none'})"
        )
    live = [z for z in ticket.isolated if zones[z] != "energized"]
    if live:
        raise ConfigError(f"{at}: isolated zone(s) {', '.join(map(repr, live))}: not energized")


class ZonedSite(Protocol):
    """A site's zones (fence.site.Site)."""

    @property
    def zones(self) -> Sequence[Zone]: ...


def check_ticket_site(ticket: Ticket | None, site: ZonedSite | None) -> None:
    """ConfigError when a ticket is given without a site file, or names zones it lacks."""
    if ticket is None:
        return
    where = ticket.path or f"ticket {ticket.id}"
    if site is None:
        raise ConfigError(f"{where}: a ticket needs a site file (--site, or `site` in the config)")
    check_zones(ticket, {z.name: z.kind for z in site.zones}, where)


def _step(doc: object, where: str) -> TicketStep:
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{where}: a step is a table of keys, got {type(doc).__name__}")
    unknown = sorted(set(doc) - _STEP_KEYS)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}")
    posture = doc.get("posture")
    if posture is not None:
        posture = (posture,) if isinstance(posture, str) else posture
        if not isinstance(posture, list | tuple) or not set(posture) <= set(POSTURES):
            raise ConfigError(f"{where}: posture {posture!r}: expected some of {POSTURES}")
        posture = tuple(posture)
    max_s = doc.get("max_s", 300.0)
    facing = doc.get("facing_deg")
    for key in ("optional", "both_hands"):
        if not isinstance(doc.get(key, False), bool):
            raise ConfigError(f"{where}: {key} is true or false, got {doc[key]!r}")
    return TicketStep(
        name=_text(doc.get("name"), f"{where}: name"),
        position=_text(doc.get("position"), f"{where}: position"),
        target=_text(doc.get("target"), f"{where}: target"),
        hold_s=_number(doc.get("hold_s", 1.0), f"{where}: hold_s", 0.0, 3600.0),
        max_s=None if max_s is False else _number(max_s, f"{where}: max_s", 0.1, 86400.0),
        optional=bool(doc.get("optional", False)),
        facing_deg=None if facing is None else _number(facing, f"{where}: facing_deg", -360, 360),
        tolerance_deg=_number(doc.get("tolerance_deg", 45.0), f"{where}: tolerance_deg", 0, 180),
        posture=posture,
        both_hands=bool(doc.get("both_hands", False)),
    )


def _text(v: object, where: str, empty: bool = False) -> str:
    if not isinstance(v, str) or (not v.strip() and not empty) or len(v) > MAX_TEXT:
        raise ConfigError(f"{where}: a name of 1 to {MAX_TEXT} characters is needed, got {v!r}")
    if not v.isprintable():
        raise ConfigError(f"{where}: {v!r} holds characters that cannot be shown")
    return v


def _number(v: object, where: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}: a number is needed, got {v!r}")
    if not lo <= v <= hi:
        raise ConfigError(f"{where}: {v} is outside [{lo}, {hi}]")
    return float(v)


def _role(v: object, where: str) -> str | int:
    if v == "auto":
        return "auto"
    if isinstance(v, int) and not isinstance(v, bool) and v >= 0:
        return int(v)
    raise ConfigError(f'{where}: "auto" or a person id is needed, got {v!r}')
