"""The site file's warnings on site: `[warnings]`, `[[speakers]]` (IP speakers by RTP) and
`[[signals]]` (beacons, sirens and relays: coils of a Modbus TCP IO module).

    [warnings]
    language = "en"                       # en | zh (Mandarin): the spoken messages' language
    repeat_s = 4.0                        # a lasting hazard's message said again this often
    priorities = [1, 2]                   # energized-zone alarms of these priorities warn
    calls = ["person_down", "step_wrong_position"]   # the other alarms said on site
    templates = { approach = "Stop. {voltage} {zone}, {distance}, {direction}." }
    recordings = { test = "test.wav" }    # the site's own WAV for a message (KIND or ZONE.KIND)

    [[speakers]]
    name = "bay1_pa"
    url = "rtp://239.10.0.1:5004"         # multicast, or rtp://HOST:PORT
    codec = "pcmu"                        # pcmu (G.711 mu-law, default) | pcma (A-law)
    zones = ["overhead_busbar"]           # the zones it covers
    ttl = 4                               # optional: multicast hops
    health_url = "http://10.0.0.5/"       # optional: answered 2xx while it is up
    position = [1.0, -2.0]                # optional: where it hangs, metres (the plan)

    [[signals]]
    name = "bay1_tower"
    host = "10.0.0.7"
    port = 502                            # optional (502)
    unit = 1                              # optional: the Modbus unit id (1)
    coils = { beacon = 0, siren = 1 }     # what each coil drives -> its address
    zones = ["overhead_busbar"]
    priorities = [1, 2]                   # optional: the hazards that set its coils
    position = [1.5, -2.0]                # optional

A zone with `on_site = false` never warns on site. Every problem is a ConfigError naming the
section, the entry and the key (onsite.phrases checks the templates' placeholders).
"""

from __future__ import annotations

import ipaddress
import string
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar
from urllib.parse import urlsplit

from stereopose.alarms.priority import CRITICAL, HIGH, PRIORITIES, parse_priority
from stereopose.checks import named_tables
from stereopose.errors import ConfigError
from stereopose.onsite.audio import CODECS, read_wav

__all__ = [
    "CALLS",
    "KINDS",
    "LANGUAGES",
    "PLACEHOLDERS",
    "SignalSpec",
    "SpeakerSpec",
    "WarningSettings",
    "check_template",
    "format_warnings",
    "parse_warnings",
]

# the site's language -> eSpeak NG's voice (onsite.speech)
LANGUAGES = {"en": "en", "zh": "cmn"}
# the events, other than an energized zone's, called on site by default (onsite.calls)
CALLS = ("person_down", "step_wrong_position")
KINDS = ("approach", "enter", "test", *CALLS)
PLACEHOLDERS = (
    "zone",
    "voltage",
    "distance",
    "direction",
)  # the messages: a hazard near, inside, a test
DEFAULT_REPEAT_S = 4.0
MAX_OUTPUTS = 64  # speakers or signals on one site
MAX_COIL = 65535

_WARNING_KEYS = {"language", "repeat_s", "priorities", "calls", "templates", "recordings"}
_SPEAKER_KEYS = {"name", "url", "codec", "zones", "ttl", "health_url", "position"}
_SIGNAL_KEYS = {"name", "host", "port", "unit", "coils", "zones", "priorities", "position"}


@dataclass(frozen=True)
class SpeakerSpec:
    """An IP speaker: RTP to host:port (multicast or unicast) in `codec`, for `zones`."""

    name: str
    host: str
    port: int
    zones: tuple[str, ...]
    codec: str = "pcmu"
    ttl: int = 4
    health_url: str | None = None
    position: tuple[float, float] | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"rtp://{host}:{self.port}"

    @property
    def multicast(self) -> bool:
        return ipaddress.ip_address(self.host).is_multicast


@dataclass(frozen=True)
class SignalSpec:
    """A Modbus TCP IO module's coils (name -> address) set while a hazard of `zones` with a
    priority in `priorities` lasts."""

    name: str
    host: str
    coils: tuple[tuple[str, int], ...]
    zones: tuple[str, ...]
    port: int = 502
    unit: int = 1
    priorities: tuple[int, ...] = (CRITICAL, HIGH)
    position: tuple[float, float] | None = None


@dataclass(frozen=True)
class WarningSettings:
    """The site's warnings on site (see the module); folder: where relative recordings are."""

    language: str = "en"
    repeat_s: float = DEFAULT_REPEAT_S
    priorities: tuple[int, ...] = (CRITICAL, HIGH)
    calls: tuple[str, ...] = CALLS
    templates: tuple[tuple[str, str], ...] = ()
    recordings: tuple[tuple[str, str], ...] = ()
    speakers: tuple[SpeakerSpec, ...] = ()
    signals: tuple[SignalSpec, ...] = ()
    folder: Path | None = field(default=None, compare=False)

    def template(self, kind: str) -> str | None:
        return dict(self.templates).get(kind)

    def recording(self, zone: str | None, kind: str) -> Path | None:
        """The site's own WAV for `kind` of `zone` (ZONE.KIND before KIND); None: spoken."""
        found = dict(self.recordings)
        given = found.get(f"{zone}.{kind}") if zone else None
        given = given or found.get(kind)
        if given is None:
            return None
        path = Path(given)
        return path if path.is_absolute() or self.folder is None else self.folder / path


def _where(section: str, name: str) -> str:
    return f"{section} {name!r}"


def _names(value: object, what: str, zones: Sequence[str]) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{what}: expected a non-empty list of zone names, got {value!r}")
    unknown = [v for v in value if v not in zones]
    if unknown:
        known = ", ".join(zones) or "none"
        raise ConfigError(f"{what}: unknown zone(s) {', '.join(unknown)}; the site has {known}")
    return tuple(dict.fromkeys(value))


def _int(value: object, what: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError(f"{what}: expected an integer in [{lo}, {hi}], got {value!r}")
    return value


def _priorities(value: object, what: str) -> tuple[int, ...]:
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{what}: expected a non-empty list of priorities (1-4), got {value!r}")
    return tuple(sorted({parse_priority(v, what) for v in value}))


def _position(value: object, what: str) -> tuple[float, float]:
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        and all(abs(float(v)) <= 1e4 for v in value)
    )
    if not ok or not isinstance(value, list):
        raise ConfigError(f"{what}: expected [x, y] in metres, got {value!r}")
    return (float(value[0]), float(value[1]))


def _host(value: object, what: str) -> str:
    if not isinstance(value, str) or not 0 < len(value) <= 253 or any(c in value for c in "/ @"):
        raise ConfigError(f"{what}: expected a host name or address, got {value!r}")
    return value


def _unknown(table: Mapping, known: set[str], where: str) -> None:
    extra = sorted(set(table) - known)
    if extra:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(extra)}; known: {', '.join(sorted(known))}"
        )


def _speaker(name: str, s: Mapping, zones: Sequence[str]) -> SpeakerSpec:
    where = _where("speaker", name)
    _unknown(s, _SPEAKER_KEYS, where)
    url = s.get("url")
    if not isinstance(url, str):
        raise ConfigError(f"{where}: url: expected rtp://HOST:PORT, got {url!r}")
    bad = f"{where}: url: expected rtp://HOST:PORT (port 1-65535), got {url!r}"
    try:
        parts = urlsplit(url)
        port, host = parts.port, parts.hostname
    except ValueError:
        raise ConfigError(bad) from None
    if parts.scheme != "rtp" or not host or not port or parts.path not in ("", "/"):
        raise ConfigError(bad)
    try:
        ipaddress.ip_address(host)
    except ValueError:
        raise ConfigError(f"{where}: url: the host must be an IP address, got {host!r}") from None
    codec = s.get("codec", "pcmu")
    if codec not in CODECS:
        raise ConfigError(f"{where}: codec: expected one of {', '.join(CODECS)}, got {codec!r}")
    health = s.get("health_url")
    if health is not None and (
        not isinstance(health, str) or urlsplit(health).scheme not in ("http", "https")
    ):
        raise ConfigError(f"{where}: health_url: expected an http(s) URL, got {health!r}")
    return SpeakerSpec(
        name,
        host,
        port,
        _names(s.get("zones"), f"{where}: zones", zones),
        codec=codec,
        ttl=_int(s.get("ttl", 4), f"{where}: ttl", 1, 255),
        health_url=health,
        position=_position(s["position"], f"{where}: position") if "position" in s else None,
    )


def _signal(name: str, s: Mapping, zones: Sequence[str]) -> SignalSpec:
    where = _where("signal", name)
    _unknown(s, _SIGNAL_KEYS, where)
    coils = s.get("coils")
    if not isinstance(coils, dict) or not coils:
        raise ConfigError(
            f"{where}: coils: expected a table such as {{ beacon = 0 }}, got {coils!r}"
        )
    pairs = tuple((str(k), _int(v, f"{where}: coils.{k}", 0, MAX_COIL)) for k, v in coils.items())
    return SignalSpec(
        name,
        _host(s.get("host"), f"{where}: host"),
        pairs,
        _names(s.get("zones"), f"{where}: zones", zones),
        port=_int(s.get("port", 502), f"{where}: port", 1, 65535),
        unit=_int(s.get("unit", 1), f"{where}: unit", 0, 255),
        priorities=_priorities(s["priorities"], f"{where}: priorities")
        if "priorities" in s
        else (CRITICAL, HIGH),
        position=_position(s["position"], f"{where}: position") if "position" in s else None,
    )


def _calls(value: object) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"[warnings] calls: expected a list of event types, got {value!r}")
    bad = [v for v in value if v not in CALLS]
    if bad:
        raise ConfigError(
            f"[warnings] calls: unknown {', '.join(map(repr, bad))}; known: {', '.join(CALLS)}"
        )
    return tuple(dict.fromkeys(value))


def _strings(value: object, what: str, keys: Sequence[str] | None) -> tuple[tuple[str, str], ...]:
    if not isinstance(value, dict) or not all(
        isinstance(k, str) and isinstance(v, str) and v for k, v in value.items()
    ):
        raise ConfigError(f"{what}: expected a table of texts, got {value!r}")
    if keys is not None:
        bad = sorted(set(value) - set(keys))
        if bad:
            known = ", ".join(keys)
            raise ConfigError(f"{what}: unknown message(s) {', '.join(bad)}; known: {known}")
    return tuple(value.items())


def check_template(text: str, where: str) -> list[tuple[str, str | None]]:
    """A template's (literal, placeholder or None) pieces; an unknown placeholder, a format
    spec or a broken brace is a ConfigError naming `where`."""
    try:
        pieces = list(string.Formatter().parse(text))
    except ValueError as e:
        raise ConfigError(f"{where}: {e} in {text!r}") from None
    out = []
    for literal, name, spec, conv in pieces:
        if name is not None and (name not in PLACEHOLDERS or spec or conv):
            raise ConfigError(
                f"{where}: unknown placeholder {{{name}}} in {text!r}; known: "
                + ", ".join(f"{{{p}}}" for p in PLACEHOLDERS)
            )
        out.append((literal, name))
    return out


_Out = TypeVar("_Out", SpeakerSpec, SignalSpec)


def _outputs(
    data: Mapping[str, object],
    key: str,
    make: Callable[[str, Mapping, Sequence[str]], _Out],
    zones: Sequence[str],
) -> list[_Out]:
    """The site file's [[speakers]] or [[signals]] tables, each checked."""
    raw = data.get(key, [])
    if not isinstance(raw, list):
        raise ConfigError(f"[[{key}]] must be an array of tables, got {raw!r}")
    if len(raw) > MAX_OUTPUTS:
        raise ConfigError(f"{len(raw)} {key}; a site holds at most {MAX_OUTPUTS}")
    return [make(name, s, zones) for name, s in named_tables(raw, key, key[:-1])]


def parse_warnings(
    data: Mapping[str, object], zones: Sequence[str], folder: Path | None = None
) -> WarningSettings | None:
    """The warnings of a site file's keys (`warnings`, `speakers`, `signals`); None when it
    has none. zones: the site's zone names; folder: the site file's (its recordings')."""
    if not any(k in data for k in ("warnings", "speakers", "signals")):
        return None
    w = data.get("warnings", {})
    if not isinstance(w, dict):
        raise ConfigError(f"[warnings] must be a table, got {w!r}")
    _unknown(w, _WARNING_KEYS, "[warnings]")
    language = w.get("language", "en")
    if language not in LANGUAGES:
        raise ConfigError(
            f"[warnings] language: expected one of {', '.join(LANGUAGES)}, got {language!r}"
        )
    repeat = w.get("repeat_s", DEFAULT_REPEAT_S)
    if isinstance(repeat, bool) or not isinstance(repeat, (int, float)) or not 1 <= repeat <= 600:
        raise ConfigError(f"[warnings] repeat_s: expected seconds in [1, 600], got {repeat!r}")
    priorities = (
        _priorities(w["priorities"], "[warnings] priorities")
        if "priorities" in w
        else (CRITICAL, HIGH)
    )
    calls = _calls(w["calls"]) if "calls" in w else CALLS
    templates = _strings(w["templates"], "[warnings] templates", KINDS) if "templates" in w else ()
    recordings = (
        _strings(w["recordings"], "[warnings] recordings", None) if "recordings" in w else ()
    )
    speakers = tuple(_outputs(data, "speakers", _speaker, zones))
    signals = tuple(_outputs(data, "signals", _signal, zones))
    for kind, _path in recordings:
        name = kind.rsplit(".", 1)[-1]
        if name not in KINDS or ("." in kind and kind.rsplit(".", 1)[0] not in zones):
            raise ConfigError(
                f"[warnings] recordings: {kind!r} is not a message (KIND or ZONE.KIND; kinds: "
                f"{', '.join(KINDS)})"
            )
    settings = WarningSettings(
        folder=folder,
        language=str(language),
        repeat_s=float(repeat),
        priorities=priorities,
        calls=calls,
        templates=templates,
        recordings=recordings,
        speakers=speakers,
        signals=signals,
    )
    assert all(p in PRIORITIES for p in settings.priorities)
    for kind, text in settings.templates:
        check_template(text, f"[warnings] templates.{kind}")
    for key, _ in settings.recordings:  # each readable now, not at the first hazard
        zone, _, kind = key.rpartition(".")
        path = settings.recording(zone or None, kind)
        assert path is not None  # a key of the recordings
        read_wav(path, f"[warnings] recordings: {key}")
    return settings


def _toml(value: object) -> str:
    import json

    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{json.dumps(k)} = {_toml(v)}" for k, v in value.items()) + " }"
    return repr(value)


def format_warnings(w: WarningSettings | None) -> list[str]:
    """The site file's lines of `w` (defaults left out); [] for None."""
    if w is None:
        return []
    lines = ["[warnings]", f"language = {_toml(w.language)}"]
    if w.repeat_s != DEFAULT_REPEAT_S:
        lines.append(f"repeat_s = {w.repeat_s!r}")
    if w.priorities != (CRITICAL, HIGH):
        lines.append(f"priorities = {list(w.priorities)}")
    if w.calls != CALLS:
        lines.append(f"calls = {_toml(w.calls)}")
    for key, table in (("templates", w.templates), ("recordings", w.recordings)):
        if table:
            lines.append(f"{key} = {_toml(dict(table))}")
    lines.append("")
    for s in w.speakers:
        lines += ["[[speakers]]", f"name = {_toml(s.name)}", f"url = {_toml(s.url)}"]
        lines.append(f"zones = {_toml(s.zones)}")
        if s.codec != "pcmu":
            lines.append(f"codec = {_toml(s.codec)}")
        if s.ttl != 4:
            lines.append(f"ttl = {s.ttl}")
        if s.health_url:
            lines.append(f"health_url = {_toml(s.health_url)}")
        if s.position:
            lines.append(f"position = {list(s.position)}")
        lines.append("")
    for g in w.signals:
        lines += ["[[signals]]", f"name = {_toml(g.name)}", f"host = {_toml(g.host)}"]
        if g.port != 502:
            lines.append(f"port = {g.port}")
        if g.unit != 1:
            lines.append(f"unit = {g.unit}")
        lines.append(f"coils = {_toml(dict(g.coils))}")
        lines.append(f"zones = {_toml(g.zones)}")
        if g.priorities != (CRITICAL, HIGH):
            lines.append(f"priorities = {list(g.priorities)}")
        if g.position:
            lines.append(f"position = {list(g.position)}")
        lines.append("")
    return lines
