"""The spoken messages: templates per message kind in the site's language, their pieces
rendered once (at start and at each site change) and put together when a message is asked
for, so that nothing waits for speech synthesis.

    book = Phrasebook(settings, zones, Speech())       # renders every piece now
    pcm = book.message("overhead_busbar", "approach", distance_m=0.6, side="left")

A template's placeholders: {zone} (the zone's name, its underscores spoken as spaces),
{voltage} ("110 kilovolts"; empty without one), {distance} (to the nearest 0.1 m) and
{direction} (where the hazard is for the worker: ahead, behind, to his left or right, from his
skeleton's heading; "nearby" when it is not known). A site's own recording (a WAV per message,
[warnings] recordings) replaces the spoken message.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from stereopose.onsite.audio import read_wav, silence
from stereopose.onsite.settings import CALLS, KINDS, WarningSettings, check_template
from stereopose.onsite.speech import Speech
from stereopose.zones import Zone

__all__ = ["SIDES", "TEMPLATES", "Phrasebook"]

_DYNAMIC = ("distance", "direction")  # filled per message; the others per zone
SIDES = ("ahead", "behind", "left", "right", "nearby")
MAX_DISTANCE_M = 10.0  # distances spoken up to this far (farther: said as this)
_PAUSE_S = 0.12  # a comma's pause between pieces

TEMPLATES = {
    "en": {
        "approach": "Stop. {voltage} {zone}, {distance}, {direction}.",
        "enter": "Danger! You are inside the {voltage} {zone}. Back away, now.",
        "test": "This is a test of the site warning system.",
        "person_down": "Attention. A person is down. Go and help now.",
        "step_wrong_position": "Stop. Wrong position for this step. Check your work ticket.",
    },
    "zh": {
        "approach": "停！{voltage}{zone}，{distance}，在你的{direction}。",
        "enter": "危险！你已进入{voltage}{zone}，立即撤离！",
        "test": "这是现场警告系统测试。",
        "person_down": "注意！有人倒地，请立即前往救助。",
        "step_wrong_position": "停！操作位置错误，请核对工作票。",
    },
}
_WORDS = {
    "en": {
        "sides": {
            "ahead": "in front of you",
            "behind": "behind you",
            "left": "to your left",
            "right": "to your right",
            "nearby": "close by",
        },
        "kv": "{v:g} kilovolt",
        "m": "{d:.1f} metres",
    },
    "zh": {
        "sides": {
            "ahead": "前方",
            "behind": "后方",
            "left": "左边",
            "right": "右边",
            "nearby": "附近",
        },
        "kv": "{v:g}千伏",
        "m": "{d:.1f}米",
    },
}


def _spoken_name(zone: Zone) -> str:
    return zone.name.replace("_", " ").replace("-", " ")


def _has_words(text: str) -> bool:
    return any(c.isalnum() for c in text)


class Phrasebook:
    """Every message of the site's warnings, its pieces rendered at construction (see the
    module). zones: the site's zones (the energized ones are spoken); speech: the renderer."""

    def __init__(self, settings: WarningSettings, zones: Sequence[Zone], speech: Speech) -> None:
        self.settings = settings
        self.language = settings.language
        self.speech = speech
        words = _WORDS[self.language]
        self._templates = {
            k: check_template(
                settings.template(k) or TEMPLATES[self.language][k], f"[warnings] templates.{k}"
            )
            for k in KINDS
        }
        self._pause = silence(_PAUSE_S)
        self._cache: dict[str, np.ndarray] = {}
        self._recorded: dict[tuple[str | None, str], np.ndarray] = {}
        self.zones = {z.name: z for z in zones if z.kind == "energized"}
        for name in [None, *self.zones]:
            for kind in KINDS:
                path = settings.recording(name, kind)
                if path is not None:
                    where = f"[warnings] recordings: {name + '.' if name else ''}{kind}"
                    self._recorded[(name, kind)] = read_wav(path, where)
        # every piece rendered now: the zones' parts, the distances and the sides
        self._sides = {s: self._say(words["sides"][s]) for s in SIDES}
        steps = round(MAX_DISTANCE_M * 10)
        self._metres = [self._say(words["m"].format(d=k / 10)) for k in range(steps + 1)]
        self.render_all()

    def _say(self, text: str) -> np.ndarray:
        """A piece of text spoken (cached by its text); a piece without a word: a pause."""
        text = text.strip()
        if not _has_words(text):
            return self._pause if text else np.zeros(0, np.int16)
        if text not in self._cache:
            self._cache[text] = self.speech.say(text, self.language)
        return self._cache[text]

    def _filled(self, text: str, zone: Zone | None) -> str:
        words = _WORDS[self.language]
        voltage = words["kv"].format(v=zone.voltage_kv) if zone and zone.voltage_kv else ""
        name = _spoken_name(zone) if zone else ""
        return text.replace("{zone}", name).replace("{voltage}", voltage)

    def message(
        self, zone: str | None, kind: str, distance_m: float | None = None, side: str = "nearby"
    ) -> np.ndarray:
        """The message `kind` about `zone` (None: a message of no zone: a test, a call),
        (N,) int16 at 8 kHz."""
        for key in ((zone, kind), (None, kind)):
            if key in self._recorded:
                return self._recorded[key]
        z = self.zones.get(zone) if zone is not None else None
        if zone is not None and z is None:
            raise KeyError(f"no energized zone {zone!r} in the warnings' site")
        out: list[np.ndarray] = []
        static = ""
        for literal, name in self._templates[kind]:
            static += literal
            if name is None or name not in _DYNAMIC:
                static += "{" + name + "}" if name else ""
                continue
            out.append(self._say(self._filled(static, z)))
            static = ""
            if name == "distance":
                d = 0.0 if distance_m is None else min(max(distance_m, 0.0), MAX_DISTANCE_M)
                out.append(self._metres[round(d * 10)])
            else:
                out.append(self._sides.get(side, self._sides["nearby"]))
        out.append(self._say(self._filled(static, z)))
        return np.concatenate([o for o in out if len(o)] or [self._pause])

    def pieces(self) -> int:
        """How many pieces are rendered (the cache's size)."""
        return len(self._cache)

    def render_all(self) -> None:
        """Every zone's message of every kind said once (their static pieces into the cache),
        so that a message asked for later only puts rendered pieces together."""
        for name in self.zones:
            for kind in ("approach", "enter"):
                self.message(name, kind, 0.0, "nearby")
        for kind in ("test", *CALLS):
            self.message(None, kind)
