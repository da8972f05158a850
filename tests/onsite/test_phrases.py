"""The spoken messages (onsite.phrases, onsite.speech): eSpeak NG from its wheel, rendered
once, put together per message."""

from __future__ import annotations

import time
import wave

import numpy as np
import pytest

from stereopose.errors import ConfigError
from stereopose.fence.site import parse_site
from stereopose.onsite.audio import RATE
from stereopose.onsite.phrases import Phrasebook
from stereopose.onsite.speech import Speech

BUSBAR = {
    "name": "overhead_busbar",
    "kind": "energized",
    "polygon": [[0, 0], [1, 0], [1, 1]],
    "z": [1, 2],
    "voltage_kv": 110,
}


def book(tmp_path=None, **warnings) -> Phrasebook:
    where = tmp_path / "site.toml" if tmp_path is not None else None
    s = parse_site({"zones": [BUSBAR], "warnings": warnings}, where)
    return Phrasebook(s.warnings, s.zones, Speech())


def voiced(pcm: np.ndarray) -> float:
    """Seconds of the message louder than a whisper (20 ms frames)."""
    frames = pcm[: len(pcm) // 160 * 160].reshape(-1, 160).astype(float)
    return float((np.sqrt((frames**2).mean(1)) > 300).sum() * 0.02)


@pytest.mark.parametrize("language", ["en", "zh"])
def test_every_message_is_spoken_in_the_sites_language(language):
    b = book(language=language)
    near = b.message("overhead_busbar", "approach", 0.6, "left")
    inside = b.message("overhead_busbar", "enter")
    test = b.message(None, "test")
    for pcm in (near, inside, test):
        assert pcm.dtype == np.int16 and 1.0 < len(pcm) / RATE < 10.0
        assert voiced(pcm) > 0.5
    # the side and the distance are the message's own pieces: another side, other words
    right = b.message("overhead_busbar", "approach", 0.6, "right")
    assert len(right) != len(near) or not np.array_equal(right, near)
    assert np.array_equal(b.message("overhead_busbar", "approach", 0.61, "left"), near)


def test_pieces_are_rendered_once_and_messages_put_together_at_once():
    b = book()
    pieces = b.pieces()
    t0 = time.perf_counter()
    for k in range(100):
        b.message("overhead_busbar", "approach", k / 50, ("left", "right", "ahead")[k % 3])
    assert b.pieces() == pieces  # nothing new spoken
    assert time.perf_counter() - t0 < 1.0  # a generous bound: about 0.05 ms each here
    with pytest.raises(KeyError):
        b.message("no_such_zone", "enter")


def test_a_sites_recording_replaces_the_spoken_message(tmp_path):
    tone = (3000 * np.sin(np.arange(RATE) / 3)).astype(np.int16)
    with wave.open(str(tmp_path / "enter.wav"), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(RATE)
        w.writeframes(tone.tobytes())
    b = book(tmp_path, recordings={"overhead_busbar.enter": "enter.wav"})
    assert np.array_equal(b.message("overhead_busbar", "enter"), tone)
    assert not np.array_equal(b.message(None, "test")[: len(tone)], tone)
    with pytest.raises(ConfigError, match=r"recordings: test: .*gone\.wav"):  # at the site's load
        parse_site(
            {"zones": [BUSBAR], "warnings": {"recordings": {"test": "gone.wav"}}},
            tmp_path / "s.toml",
        )
