"""Speech, offline: eSpeak NG (the library and its voice data from the `espeakng-loader`
wheel, no system package) rendering a text in the site's language to 8 kHz PCM.

    voice = Speech()
    pcm = voice.say("Stop. Busbar, to your left.", "en")    # (N,) int16 at 8 kHz

eSpeak NG keeps one state per process: every call holds one lock. It renders a sentence in a
few milliseconds; the warnings render theirs at start and at each site change, never in a
step (onsite.phrases).
"""

from __future__ import annotations

import ctypes
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereopose.errors import StereoposeError
from stereopose.onsite.audio import resample
from stereopose.onsite.settings import LANGUAGES

__all__ = ["LANGUAGES", "Speech"]

_SYNCHRONOUS = 2  # AUDIO_OUTPUT_SYNCHRONOUS: the samples come to the callback, nothing plays
_DONT_EXIT = 0x8000  # espeakINITIALIZE_DONT_EXIT: an error is returned, never exit()
_CHARS_UTF8 = 1
_POS_CHARACTER = 1
_RATE = 1  # espeakRATE, words a minute
_CALLBACK = ctypes.CFUNCTYPE(
    ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.c_void_p
)

_lock = threading.Lock()


@dataclass(frozen=True)
class _Engine:
    """eSpeak NG loaded: the library, its sample rate, the callback it holds and the
    chunks of sound the callback gathers."""

    lib: ctypes.CDLL
    rate: int
    callback: object  # kept: the library holds its pointer
    chunks: list[np.ndarray]


_engine: list[_Engine] = []  # once per process


def _library() -> _Engine:
    """eSpeak NG loaded and initialised once (under _lock)."""
    if _engine:
        return _engine[0]
    try:
        import espeakng_loader
    except ImportError:
        raise StereoposeError(
            "spoken warnings need eSpeak NG: pip install espeakng-loader (a dependency of "
            "stereopose; reinstall the package)"
        ) from None
    try:
        lib = ctypes.CDLL(espeakng_loader.get_library_path())
        data = Path(espeakng_loader.get_data_path()).parent
    except (OSError, RuntimeError) as e:
        raise StereoposeError(f"eSpeak NG cannot be loaded: {e}") from None
    lib.espeak_Initialize.restype = ctypes.c_int
    rate = lib.espeak_Initialize(_SYNCHRONOUS, 0, str(data).encode(), _DONT_EXIT)
    if rate <= 0:
        raise StereoposeError(f"eSpeak NG did not start (its data in {data})")
    chunks: list[np.ndarray] = []

    def collect(wav: bytes, n: int, _events: object) -> int:
        if n > 0 and wav:
            chunks.append(np.ctypeslib.as_array(wav, shape=(n,)).copy())
        return 0

    callback = _CALLBACK(collect)  # kept: the library holds the pointer
    lib.espeak_SetSynthCallback(callback)
    _engine.append(_Engine(lib, rate, callback, chunks))
    return _engine[0]


class Speech:
    """Texts spoken by eSpeak NG; words_per_minute: its pace (a warning is said briskly)."""

    def __init__(self, words_per_minute: int = 165) -> None:
        self.words_per_minute = int(words_per_minute)

    def say(self, text: str, language: str) -> np.ndarray:
        """`text` spoken in `language` (LANGUAGES) -> (N,) int16 at 8 kHz."""
        voice = LANGUAGES.get(language)
        if voice is None:
            raise ValueError(f"unknown language {language!r}; expected one of {list(LANGUAGES)}")
        with _lock:
            engine = _library()
            lib, rate, chunks = engine.lib, engine.rate, engine.chunks
            chunks.clear()
            if lib.espeak_SetVoiceByName(voice.encode()) != 0:
                raise StereoposeError(f"eSpeak NG has no voice {voice!r} (language {language})")
            lib.espeak_SetParameter(_RATE, self.words_per_minute, 0)
            data = text.encode("utf-8")
            status = lib.espeak_Synth(
                ctypes.c_char_p(data), ctypes.c_size_t(len(data) + 1), 0, _POS_CHARACTER, 0,
                _CHARS_UTF8, None, None,
            )  # fmt: skip
            lib.espeak_Synchronize()
            pcm = np.concatenate(chunks) if chunks else np.zeros(0, np.int16)
            chunks.clear()
        if status != 0 or not len(pcm):
            raise StereoposeError(f"eSpeak NG could not say {text!r} ({language})")
        return resample(pcm, rate)
