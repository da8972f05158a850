"""Audio for IP speakers: 16-bit PCM brought to 8 kHz, and G.711 (ITU-T G.711) mu-law and
A-law, the codecs every IP public-address speaker takes (RTP payload types 0 and 8, RFC 3551).

Arrays: pcm (N,) int16 samples; codes (N,) uint8 bytes of the codec.
"""

from __future__ import annotations

import wave
from pathlib import Path

import numpy as np

from stereopose.errors import ConfigError

__all__ = ["CODECS", "RATE", "decode", "encode", "read_wav", "resample", "silence"]

RATE = 8000  # G.711's sample rate, Hz
CODECS = {"pcmu": 0, "pcma": 8}  # codec -> its static RTP payload type (RFC 3551)

_BIAS = 0x84
_SEG_UEND = np.array([0x3F, 0x7F, 0xFF, 0x1FF, 0x3FF, 0x7FF, 0xFFF, 0x1FFF])


def resample(pcm: np.ndarray, rate: int, to: int = RATE) -> np.ndarray:
    """(N,) int16 at `rate` Hz -> int16 at `to` Hz: a low-pass (a windowed sinc at 0.45 of the
    lower rate, so nothing folds back) and linear interpolation."""
    x = np.asarray(pcm, dtype=np.float64)
    if rate == to or not len(x):
        return np.asarray(pcm, dtype=np.int16).copy()
    if to < rate:
        cut = 0.45 * to / rate  # cycles per input sample
        n = np.arange(-32, 33)
        taps = 2 * cut * np.sinc(2 * cut * n) * np.hamming(len(n))
        x = np.convolve(x, taps / taps.sum(), mode="same")
    t = np.arange(int(len(x) * to / rate)) * (rate / to)
    y = np.interp(t, np.arange(len(x)), x)
    return np.clip(np.round(y), -32768, 32767).astype(np.int16)


def silence(seconds: float) -> np.ndarray:
    """(N,) int16 zeros at RATE."""
    return np.zeros(round(seconds * RATE), dtype=np.int16)


def _ulaw(pcm: np.ndarray) -> np.ndarray:
    """G.711 mu-law as its reference code computes it (on 14 bits, the magnitude biased by
    33 and clipped at 8159)."""
    x = pcm.astype(np.int32) >> 2
    mask = np.where(x < 0, 0x7F, 0xFF)
    mag = np.minimum(np.abs(x), 8159) + 33
    seg = np.searchsorted(_SEG_UEND, mag)  # the first segment whose end holds it
    code = np.where(seg >= 8, 0x7F, (np.minimum(seg, 7) << 4) | ((mag >> (seg + 1)) & 0x0F))
    return (code ^ mask).astype(np.uint8)


def _ulaw_decode(codes: np.ndarray) -> np.ndarray:
    u = ~codes.astype(np.int32) & 0xFF
    exp, mant = (u >> 4) & 0x07, u & 0x0F
    mag = (((mant << 3) + _BIAS) << exp) - _BIAS
    return np.where(u & 0x80, -mag, mag).astype(np.int16)


def _alaw(pcm: np.ndarray) -> np.ndarray:
    x = pcm.astype(np.int32) >> 3  # 13 bits
    sign = np.where(x >= 0, 0x80, 0)
    mag = np.minimum(np.where(x >= 0, x, -x - 1), 0x0FFF)
    exp = np.where(mag < 32, 0, np.floor(np.log2(np.maximum(mag, 1))).astype(np.int32) - 4)
    mant = np.where(exp == 0, mag >> 1, mag >> exp) & 0x0F
    return ((sign | (exp << 4) | mant) ^ 0x55).astype(np.uint8)


def _alaw_decode(codes: np.ndarray) -> np.ndarray:
    a = codes.astype(np.int32) ^ 0x55
    exp, mant = (a >> 4) & 0x07, a & 0x0F
    mag = np.where(exp == 0, (mant << 4) + 8, ((mant << 4) + 0x108) << np.maximum(exp - 1, 0))
    return np.where(a & 0x80, mag, -mag).astype(np.int16)


def encode(pcm: np.ndarray, codec: str) -> bytes:
    """(N,) int16 at RATE -> N bytes of `codec` (pcmu or pcma)."""
    x = np.asarray(pcm, dtype=np.int16)
    if codec == "pcmu":
        return _ulaw(x).tobytes()
    if codec == "pcma":
        return _alaw(x).tobytes()
    raise ValueError(f"unknown codec {codec!r}; expected one of {', '.join(CODECS)}")


def decode(data: bytes, codec: str) -> np.ndarray:
    """N bytes of `codec` -> (N,) int16."""
    codes = np.frombuffer(data, dtype=np.uint8)
    if codec == "pcmu":
        return _ulaw_decode(codes)
    if codec == "pcma":
        return _alaw_decode(codes)
    raise ValueError(f"unknown codec {codec!r}; expected one of {', '.join(CODECS)}")


def read_wav(path: str | Path, what: str) -> np.ndarray:
    """A site's own recording: a PCM WAV file (8 or 16 bits, mono or the first channel of
    several, any rate) -> (N,) int16 at RATE; a ConfigError naming `what` and the file."""
    path = Path(path)
    try:
        with wave.open(str(path), "rb") as w:
            width, channels, rate = w.getsampwidth(), w.getnchannels(), w.getframerate()
            raw = w.readframes(w.getnframes())
    except (OSError, EOFError, wave.Error) as e:
        raise ConfigError(f"{what}: {path}: not a readable WAV file ({e})") from None
    if width not in (1, 2) or channels < 1 or rate <= 0:
        raise ConfigError(
            f"{what}: {path}: {8 * width}-bit WAV; expected 8- or 16-bit PCM"
            if width not in (1, 2)
            else f"{what}: {path}: no audio channel"
        )
    if width == 1:
        pcm = (np.frombuffer(raw, np.uint8).astype(np.int16) - 128) << 8
    else:
        pcm = np.frombuffer(raw[: len(raw) // 2 * 2], "<i2")
    pcm = pcm[: len(pcm) // channels * channels].reshape(-1, channels)[:, 0]
    if not len(pcm):
        raise ConfigError(f"{what}: {path}: the WAV file holds no sound")
    return resample(pcm, rate)
