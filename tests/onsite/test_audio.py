"""G.711 and 8 kHz audio for the IP speakers (onsite.audio)."""

from __future__ import annotations

import warnings
import wave

import numpy as np
import pytest

from stereopose.errors import ConfigError
from stereopose.onsite.audio import RATE, decode, encode, read_wav, resample

EVERY = np.arange(-32768, 32768, dtype=np.int16)


@pytest.mark.parametrize("codec", ["pcmu", "pcma"])
def test_g711_matches_the_reference_and_keeps_the_sound(codec):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        audioop = pytest.importorskip("audioop")  # the reference codec (Python <= 3.12)
    ours = encode(EVERY, codec)
    ref = (audioop.lin2ulaw if codec == "pcmu" else audioop.lin2alaw)(EVERY.tobytes(), 2)
    assert ours == ref
    codes = bytes(range(256))
    back = (audioop.ulaw2lin if codec == "pcmu" else audioop.alaw2lin)(codes, 2)
    assert np.array_equal(decode(codes, codec), np.frombuffer(back, np.int16))


@pytest.mark.parametrize("codec", ["pcmu", "pcma"])
def test_g711_quantisation_is_within_its_step(codec):
    again = decode(encode(EVERY, codec), codec).astype(np.int64)
    x = EVERY.astype(np.int64)
    err = np.abs(again - x)
    # a logarithmic step: within 1/16 of the value (and 16 near zero)
    assert (err <= np.maximum(np.abs(x) / 16, 16)).all()
    with pytest.raises(ValueError, match="unknown codec"):
        encode(EVERY, "opus")


def test_resampling_keeps_a_tone_and_drops_what_would_fold():
    t = np.arange(22050) / 22050
    tone = (8000 * np.sin(2 * np.pi * 440 * t)).astype(np.int16)
    high = (8000 * np.sin(2 * np.pi * 6000 * t)).astype(np.int16)  # above 4 kHz
    a, b = resample(tone, 22050), resample(high, 22050)
    assert len(a) == RATE
    spectrum = np.abs(np.fft.rfft(a.astype(float)))
    assert abs(int(np.argmax(spectrum)) - 440) <= 1  # 1 Hz bins over one second
    assert np.abs(b[50:-50]).max() < 0.05 * np.abs(a).max()  # away from the edges


def test_a_sites_own_recording(tmp_path):
    path = tmp_path / "stop.wav"
    with wave.open(str(path), "wb") as w:
        w.setnchannels(2)
        w.setsampwidth(2)
        w.setframerate(16000)
        left = (1000 * np.sin(np.arange(16000) / 10)).astype(np.int16)
        w.writeframes(np.column_stack([left, np.zeros_like(left)]).tobytes())
    pcm = read_wav(path, "[warnings] recordings: test")
    assert len(pcm) == RATE and np.abs(pcm).max() > 500
    bad = tmp_path / "bad.wav"
    bad.write_bytes(b"RIFF0000WAVEjunk")
    with pytest.raises(ConfigError, match=r"recordings: test: .*bad.wav: not a readable WAV"):
        read_wav(bad, "[warnings] recordings: test")
    with pytest.raises(ConfigError, match=r"missing\.wav"):
        read_wav(tmp_path / "missing.wav", "[warnings] recordings: test")
