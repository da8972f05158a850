"""Lines of a gzip file of one or more members that may have been cut off by a crash.

A segment writer appends one complete gzip member per flush, so a file whose writer was
killed ends either after a whole member or inside the last one. Python's gzip module raises
EOFError in the second case; `GzipLines` instead ends the text at its last complete line (with
a warning) and keeps memory bounded however far the data expands.
"""

from __future__ import annotations

import logging
import zlib
from typing import IO

logger = logging.getLogger(__name__)

__all__ = ["DamagedGzipError", "GzipLines"]

_CHUNK = 64 * 1024
_GZIP = 16 + zlib.MAX_WBITS  # zlib's gzip framing


class DamagedGzipError(ValueError):
    """The bytes of a gzip file are not gzip data (beyond a cut-off end)."""


class GzipLines:
    """``readline(limit)`` over the decompressed bytes of a gzip file opened in binary.

    A file cut off inside a member ends at its last complete line (`cut` is then true); bytes
    that are not gzip data raise DamagedGzipError. At most ``limit`` + 64 KiB are held at once.
    """

    def __init__(self, f: IO[bytes], name: str) -> None:
        self._f, self.name = f, name
        self._d = zlib.decompressobj(_GZIP)
        self._input = b""  # read but not yet given to the decompressor (the next member's start)
        self._in_member = False  # the current member has begun and not ended
        self._buf = bytearray()
        self._scanned = 0  # bytes of _buf known to hold no newline
        self._done = False
        self.cut = False

    def readline(self, limit: int = -1) -> bytes:
        """The next line with its newline (the last may have none); b"" at the end; at most
        `limit` bytes when limit >= 0."""
        while True:
            i = self._buf.find(b"\n", self._scanned)
            if i >= 0 and (limit < 0 or i < limit):
                return self._take(i + 1)
            if 0 <= limit <= len(self._buf):
                return self._take(limit)
            self._scanned = len(self._buf)
            if not self._fill():
                return self._take(len(self._buf))

    def _take(self, n: int) -> bytes:
        line = bytes(self._buf[:n])
        del self._buf[:n]
        self._scanned = 0
        return line

    def _fill(self) -> bool:
        """More decompressed bytes into the buffer; False at the end of the file."""
        while not self._done:
            data = self._d.unconsumed_tail or self._input
            self._input = b""
            if not data:
                data = self._f.read(_CHUNK)
                if not data:
                    self._end()
                    return False
            try:
                out = self._d.decompress(data, _CHUNK)
            except zlib.error as e:
                raise DamagedGzipError(f"damaged gzip data ({e})") from None
            self._in_member = not self._d.eof
            if self._d.eof:  # a member ended: what follows starts the next one
                self._input = self._d.unused_data
                self._d = zlib.decompressobj(_GZIP)
            if out:
                self._buf += out
                return True
        return False

    def _end(self) -> None:
        self._done = True
        if not self._in_member:
            return
        self.cut = True
        keep = self._buf.rfind(b"\n") + 1
        dropped = len(self._buf) - keep
        del self._buf[keep:]
        logger.warning(
            "%s: cut off inside its last gzip member (its writer stopped mid-write); read to "
            "its last complete line (%d byte(s) of a partial line dropped)",
            self.name,
            dropped,
        )

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> GzipLines:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
