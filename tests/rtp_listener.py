"""An RTP listener for the tests: a UDP socket on 127.0.0.1 that keeps every packet."""

from __future__ import annotations

import socket
import struct
import time


class Listener:
    """A UDP socket that keeps every RTP packet: (arrival, marker, pt, seq, ts, payload)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.packets: list[tuple] = []

    def take(self, until) -> None:
        deadline = time.monotonic() + 15
        while not until() and time.monotonic() < deadline:
            try:
                data = self.sock.recv(2048)
            except TimeoutError:
                continue
            b0, b1, seq, ts, _ssrc = struct.unpack("!BBHII", data[:12])
            assert b0 == 0x80
            self.packets.append((time.monotonic(), bool(b1 & 0x80), b1 & 0x7F, seq, ts, data[12:]))
