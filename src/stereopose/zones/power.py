"""Where an energized zone's state comes from (a zone's `state` in the site file, documented
in docs/zone-state.md): the positions of the utility's breakers and earthing switches, read
over IEC 60870-5-104, OPC UA or MQTT, and the rule that makes the zone dead.

One point, its own rule:

    state = { iec104 = { host = "10.0.0.5", port = 2404, common_address = 1, ioa = 1001,
                         type = "double", energized_when = "closed" } }

Several named points and an expression over them:

    [zones.state]
    dead_when = "qf2 == 'open' and qe2 == 'closed'"
    [zones.state.points]
    qf2 = { iec104 = { host = "10.0.0.5", common_address = 1, ioa = 1001, type = "double" } }
    qe2 = { opcua = { endpoint = "opc.tcp://10.0.0.6:4840", node_id = "ns=2;s=QE2" } }

A point's value reads as a string: a single point (and an OPC UA or MQTT boolean) "on" or
"off", a double point "open", "closed" or "intermediate"; an OPC UA number as its number; an
MQTT payload as its JSON value (true/false as "on"/"off") or its text. An expression uses the
point names, string and number literals, == != < <= > >=, and, or, not and parentheses.
Everything else is a ConfigError naming the zone and the key.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any, SupportsFloat, SupportsIndex

from stereopose.errors import ConfigError
from stereopose.secrets import redact

__all__ = [
    "PROTOCOLS",
    "Iec104Point",
    "MqttPoint",
    "OpcuaPoint",
    "PointSource",
    "PowerSpec",
    "parse_power",
]

PROTOCOLS = ("iec104", "opcua", "mqtt")
SINGLE, DOUBLE = "single", "double"
TLS_KEYS = ("tls_ca", "tls_certificate", "tls_key")  # IEC 104 over TLS: all three or none
MAX_POINTS = 16
MAX_EXPRESSION = 500
DEFAULT_INTERROGATION_S = 60.0  # IEC 104 general interrogation, OPC UA read: this often
_KEYS = {
    "iec104": {
        "host",
        "port",
        "common_address",
        "ioa",
        "type",
        "time_tag",
        "interrogation_s",
        *TLS_KEYS,
    },
    "opcua": {"endpoint", "node_id", "username", "password_file", "interrogation_s"},
    "mqtt": {"topic"},
}
_STATE_KEYS = {"points", "dead_when", "energized_when", "stale_s"}
_COMPARE = (ast.Eq, ast.NotEq, ast.Lt, ast.LtE, ast.Gt, ast.GtE)


@dataclass(frozen=True)
class PointSource:
    """One breaker's or switch's position: `name` in the expression, its protocol and its
    parameters (key, value pairs: the table given in the site file, checked). Made by
    `PointSource.of` as the point of its protocol (Iec104Point, OpcuaPoint, MqttPoint), each
    with its parameters typed, its label and its link."""

    name: str
    protocol: str
    params: tuple[tuple[str, Any], ...]

    def get(self, key: str, default: Any = None) -> Any:
        return dict(self.params).get(key, default)

    @property
    def label(self) -> str:
        """What names the source in events and messages (never a credential)."""
        raise NotImplementedError  # each protocol's point names itself

    @property
    def link(self) -> tuple[str, ...]:
        """The connection it is read over: points of one link share one client."""
        raise NotImplementedError

    @property
    def interrogation_s(self) -> float:
        return float(self.get("interrogation_s", DEFAULT_INTERROGATION_S))

    @staticmethod
    def of(name: str, protocol: str, params: Mapping[str, object]) -> PointSource:
        """The point of `protocol` (iec104, opcua, mqtt) with these checked parameters."""
        kind = {"iec104": Iec104Point, "opcua": OpcuaPoint, "mqtt": MqttPoint}[protocol]
        return kind(name, protocol, tuple(params.items()))


class Iec104Point(PointSource):
    """A point of an RTU over IEC 60870-5-104."""

    @property
    def host(self) -> str:
        return str(self.get("host"))

    @property
    def port(self) -> int:
        return int(self.get("port", 2404))

    @property
    def common_address(self) -> int:
        return int(self.get("common_address"))

    @property
    def ioa(self) -> int:
        return int(self.get("ioa"))

    @property
    def double(self) -> bool:
        return self.get("type") == DOUBLE

    @property
    def time_tag(self) -> bool:
        return bool(self.get("time_tag", True))

    @property
    def tls(self) -> tuple[str, str, str] | None:
        """(CA, certificate, key) files of a link over TLS, else None."""
        files = tuple(self.get(k) for k in TLS_KEYS)
        return None if files[0] is None else (str(files[0]), str(files[1]), str(files[2]))

    @property
    def label(self) -> str:
        return f"iec104 {self.host}:{self.port} ca {self.common_address} ioa {self.ioa}"

    @property
    def link(self) -> tuple[str, ...]:
        return ("iec104", self.host, str(self.port))


class OpcuaPoint(PointSource):
    """A node of an OPC UA server."""

    @property
    def endpoint(self) -> str:
        return str(self.get("endpoint"))

    @property
    def node_id(self) -> str:
        return str(self.get("node_id"))

    @property
    def username(self) -> str | None:
        return self.get("username")

    @property
    def password_file(self) -> str | None:
        return self.get("password_file")

    @property
    def label(self) -> str:
        return f"opcua {redact(self.endpoint)} {self.node_id}"

    @property
    def link(self) -> tuple[str, ...]:
        return ("opcua", self.endpoint)


class MqttPoint(PointSource):
    """A topic of the site's broker."""

    @property
    def topic(self) -> str:
        return str(self.get("topic"))

    @property
    def label(self) -> str:
        return f"mqtt {self.topic}"

    @property
    def link(self) -> tuple[str, ...]:
        return ("mqtt",)


@dataclass(frozen=True)
class PowerSpec:
    """A zone's state source: its points, the expression that makes it dead (`dead`: true
    when the expression says dead; false: it says energized), the stale bound."""

    points: tuple[PointSource, ...]
    expression: str
    dead: bool
    stale_s: float | None  # None: a point is stale after 1.5 interrogation periods

    def stale_after(self, point: PointSource) -> float | None:
        """Seconds without an update after which `point` is stale (None: never: MQTT)."""
        if self.stale_s is not None:
            return self.stale_s if self.stale_s > 0 else None
        return None if isinstance(point, MqttPoint) else 1.5 * point.interrogation_s

    @cached_property
    def _tree(self) -> ast.AST:
        """The rule parsed once (checked at load): judged at every step of the service."""
        return ast.parse(self.expression, mode="eval").body

    def is_dead(self, values: Mapping[str, object]) -> bool:
        """Whether the zone is dead with these point values (every point known)."""
        result = _evaluate(self._tree, values)
        return bool(result) if self.dead else not bool(result)

    def to_toml(self) -> dict:
        """The site file's table (format_site)."""
        key = "dead_when" if self.dead else "energized_when"
        out: dict[str, object] = {key: self.expression}
        if self.stale_s is not None:
            out["stale_s"] = self.stale_s
        out["points"] = {p.name: {p.protocol: dict(p.params)} for p in self.points}
        return out


def parse_power(doc: object, where: str) -> PowerSpec:
    """A zone's `state` table (see the module) checked; `where`: "zone 'x'"."""
    where = f"{where}: state"
    if not isinstance(doc, Mapping):
        raise ConfigError(f"{where}: expected a table, got {doc!r}")
    if set(doc) & set(PROTOCOLS):  # the one-point form
        if len(doc) != 1:
            raise ConfigError(f"{where}: one of {', '.join(PROTOCOLS)} alone (or `points`)")
        ((protocol, table),) = doc.items()
        point = _point("state", {protocol: table}, where)
        params = dict(point.params)
        when = params.pop("energized_when", None)
        point = PointSource.of("state", point.protocol, params)
        if when is None:
            when = "closed" if params.get("type") == DOUBLE else "on"
        if not isinstance(when, (str, bool, int, float)):
            raise ConfigError(f"{where}: energized_when: expected a value, got {when!r}")
        return PowerSpec((point,), f"state == {_literal(when)}", False, None)
    unknown = sorted(set(doc) - _STATE_KEYS)
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(unknown)}; known: "
            f"{', '.join(sorted(_STATE_KEYS))} or one of {', '.join(PROTOCOLS)}"
        )
    points = doc.get("points")
    if not isinstance(points, Mapping) or not points:
        raise ConfigError(f"{where}: points: expected a table of named points")
    if len(points) > MAX_POINTS:
        raise ConfigError(f"{where}: points: at most {MAX_POINTS}")
    parsed = tuple(_point(str(n), t, f"{where}: points.{n}") for n, t in points.items())
    for p in parsed:
        if not p.name.isidentifier() or p.name in ("and", "or", "not"):
            raise ConfigError(f"{where}: points: {p.name!r} is not a name an expression can use")
        if p.get("energized_when") is not None:
            raise ConfigError(f"{where}: points.{p.name}: energized_when belongs to the zone")
    has = [k for k in ("dead_when", "energized_when") if k in doc]
    if len(has) != 1:
        raise ConfigError(f"{where}: give one of dead_when or energized_when")
    expression = doc[has[0]]
    _check_expression(expression, {p.name for p in parsed}, f"{where}: {has[0]}")
    stale = doc.get("stale_s")
    if stale is not None and (
        isinstance(stale, bool) or not isinstance(stale, (int, float)) or not 0 <= stale <= 86400
    ):
        raise ConfigError(f"{where}: stale_s: expected 0 (never) to 86400 seconds, got {stale!r}")
    return PowerSpec(parsed, expression, has[0] == "dead_when", None if stale is None else stale)


def _literal(value: object) -> str:
    if isinstance(value, bool):
        return repr("on" if value else "off")
    return repr(value)


def _point(name: str, doc: object, where: str) -> PointSource:
    if not isinstance(doc, Mapping) or len(doc) != 1 or next(iter(doc)) not in PROTOCOLS:
        raise ConfigError(f"{where}: expected one of {', '.join(PROTOCOLS)} = {{ ... }}")
    ((protocol, table),) = doc.items()
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: {protocol}: expected a table, got {table!r}")
    allowed = _KEYS[protocol] | ({"energized_when"} if name == "state" else set())
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(
            f"{where}: {protocol}: unknown key(s) {', '.join(unknown)}; known: "
            f"{', '.join(sorted(allowed))}"
        )
    p = dict(table)
    w = f"{where}: {protocol}"
    if protocol == "iec104":
        _text(p, "host", w)
        p.setdefault("port", 2404)
        _integer(p, "port", 1, 65535, w)
        _integer(p, "common_address", 0, 65535, w)
        _integer(p, "ioa", 0, 2**24 - 1, w)
        p.setdefault("type", SINGLE)
        if p["type"] not in (SINGLE, DOUBLE):
            raise ConfigError(f"{w}: type: expected single or double, got {p['type']!r}")
        p.setdefault("time_tag", True)
        if not isinstance(p["time_tag"], bool):
            raise ConfigError(f"{w}: time_tag: expected true or false, got {p['time_tag']!r}")
        given = [k for k in TLS_KEYS if k in p]
        if given and len(given) != len(TLS_KEYS):
            raise ConfigError(f"{w}: TLS needs {', '.join(TLS_KEYS)} together (files)")
        for key in given:
            _text(p, key, w)
    elif protocol == "opcua":
        _text(p, "endpoint", w)
        if not str(p["endpoint"]).startswith("opc.tcp://"):
            raise ConfigError(f"{w}: endpoint: expected opc.tcp://host:port, got {p['endpoint']!r}")
        _text(p, "node_id", w)
        for key in ("username", "password_file"):
            if key in p:
                _text(p, key, w)
    else:
        _text(p, "topic", w)
        if any(c in p["topic"] for c in "+#\0"):
            raise ConfigError(f"{w}: topic: one topic, no wildcard, got {p['topic']!r}")
    if "interrogation_s" in p:
        v = p["interrogation_s"]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 1 <= v <= 86400:
            raise ConfigError(f"{w}: interrogation_s: expected 1 to 86400 seconds, got {v!r}")
    return PointSource.of(name, protocol, p)


def _text(p: dict, key: str, where: str) -> None:
    if key not in p:
        raise ConfigError(f"{where}: missing `{key}`")
    v = p[key]
    if not isinstance(v, str) or not v.strip() or len(v) > 500:
        raise ConfigError(f"{where}: {key}: expected a text, got {v!r}")


def _integer(p: dict, key: str, lo: int, hi: int, where: str) -> None:
    if key not in p:
        raise ConfigError(f"{where}: missing `{key}`")
    v = p[key]
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ConfigError(f"{where}: {key}: expected an integer {lo} to {hi}, got {v!r}")


def _check_expression(text: object, names: set[str], where: str) -> None:
    if not isinstance(text, str) or not text.strip() or len(text) > MAX_EXPRESSION:
        raise ConfigError(f"{where}: expected an expression of at most {MAX_EXPRESSION} characters")
    try:
        tree = ast.parse(text, mode="eval")
    except (SyntaxError, ValueError, RecursionError) as e:
        raise ConfigError(f"{where}: not an expression: {e}") from None
    used: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            used.add(node.id)
        elif isinstance(node, ast.Constant):
            if not isinstance(node.value, (str, int, float, bool)):
                raise ConfigError(f"{where}: {node.value!r} is not a value it can hold")
        elif not isinstance(
            node,
            (
                ast.Expression,
                ast.BoolOp,
                ast.And,
                ast.Or,
                ast.UnaryOp,
                ast.Not,
                ast.Compare,
                ast.Load,
                *_COMPARE,
            ),
        ):
            raise ConfigError(f"{where}: {type(node).__name__} is not allowed in {text!r}")
    unknown = sorted(used - names)
    if unknown:
        raise ConfigError(
            f"{where}: {', '.join(unknown)} not among the points ({', '.join(sorted(names))})"
        )


def _evaluate(node: ast.AST, values: Mapping[str, object]) -> Any:
    if isinstance(node, ast.BoolOp):
        parts = [_evaluate(v, values) for v in node.values]
        return all(parts) if isinstance(node.op, ast.And) else any(parts)
    if isinstance(node, ast.UnaryOp):
        return not _evaluate(node.operand, values)
    if isinstance(node, ast.Name):
        return values[node.id]
    if isinstance(node, ast.Constant):
        return ("on" if node.value else "off") if isinstance(node.value, bool) else node.value
    if isinstance(node, ast.Compare):
        left = _evaluate(node.left, values)
        for op, right_node in zip(node.ops, node.comparators, strict=True):
            right = _evaluate(right_node, values)
            if not _compare(op, left, right):
                return False
            left = right
        return True
    raise ValueError(f"cannot evaluate {type(node).__name__}")


def _compare(op: ast.cmpop, a: object, b: object) -> bool:
    if isinstance(op, (ast.Eq, ast.NotEq)):
        same = _same(a, b)
        return same if isinstance(op, ast.Eq) else not same
    try:
        x, y = _as_float(a), _as_float(b)
    except (TypeError, ValueError):
        raise ValueError(f"cannot order {a!r} and {b!r}") from None  # the zone: unknown
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ValueError(f"cannot order {a!r} and {b!r}")
    return {ast.Lt: x < y, ast.LtE: x <= y, ast.Gt: x > y, ast.GtE: x >= y}[type(op)]


def _as_float(x: object) -> float:
    """float(x): a TypeError where x is neither a number nor a number's text."""
    if isinstance(x, (str, bytes, SupportsFloat, SupportsIndex)):
        return float(x)
    raise TypeError(f"not a number: {x!r}")


def _same(a: object, b: object) -> bool:
    if isinstance(a, str) and isinstance(b, str):
        return a.strip().lower() == b.strip().lower()
    try:
        return _as_float(a) == _as_float(b)
    except (TypeError, ValueError):
        return str(a).strip().lower() == str(b).strip().lower()


def reading(value: object) -> Any:
    """A point's value as the expressions read it: a boolean as "on" / "off", a number or text
    as it is, anything else as its text."""
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, (int, float, str)):
        return value
    return str(value)
