"""A zone's breakers and earthing switches read from the utility's RTU over IEC 60870-5-104
secured by TLS (IEC 62351-3): mutual authentication, the RTU's certificate checked against the
CA given (and its name or address), this master's certificate shown to it.

The c104 master (scada.iec104_master) cannot verify a server over TLS (its mbedtls refuses a
verifying client without a host name, which c104 cannot set), so a TLS link is read by this
master, over Python's ssl: STARTDT, a general interrogation when the link opens and every
`interrogation_s` after, spontaneous changes as they come, acknowledgements (S frames) every
ACK_EVERY I frames, TESTFR when the link is quiet, and a reconnection (1 s, up to 10 s apart)
when it drops or a handshake fails. A lost link makes its points unknown at once; a point with
a quality flag set (or a double point indeterminate) is unknown (scada.iec104_board, shared with
c104's master). It reads M_SP_NA_1,
M_DP_NA_1, M_SP_TB_1 and M_DP_TB_1; anything else the RTU sends is skipped.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import ssl
import struct
import threading
import time
from collections.abc import MutableMapping
from pathlib import Path

from stereopose.errors import ConfigError
from stereopose.scada.iec104_board import RtuPoints
from stereopose.zones.power import Iec104Point
from stereopose.zones.power_state import PowerBoard

__all__ = ["Iec104TlsMaster", "tls_context"]

logger = logging.getLogger(__name__)

STARTDT_ACT, STARTDT_CON = 0x07, 0x0B
TESTFR_ACT, TESTFR_CON = 0x43, 0x83
ACK_EVERY = 8  # I frames received before an S frame (IEC 104's w)
QUIET_S = 20.0  # a link silent this long is sent TESTFR (t3)
TIMEOUT_S = 15.0  # no answer within this (t1): the link is dropped
ELEMENT = {1: 1, 3: 1, 30: 8, 31: 8}  # type id -> bytes of one element (after its IOA)


def tls_context(ca: Path, certificate: Path, key: Path, where: str) -> ssl.SSLContext:
    """The master's TLS: the RTU checked against `ca`, this master's certificate and key
    shown to it; a ConfigError naming `where` and the file when one cannot be used."""
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_verify_locations(cafile=str(ca))
    except (OSError, ssl.SSLError) as e:
        raise ConfigError(f"{where}: tls_ca {ca}: {e}") from None
    try:
        ctx.load_cert_chain(str(certificate), str(key))
    except (OSError, ssl.SSLError) as e:
        raise ConfigError(f"{where}: tls_certificate {certificate} / tls_key {key}: {e}") from None
    return ctx


class Iec104TlsMaster:
    """The TLS master of one RTU (see the module): start(), stop()."""

    def __init__(
        self,
        host: str,
        port: int,
        points: list[Iec104Point],
        board: PowerBoard,
        figures: MutableMapping[str, int],
        context: ssl.SSLContext,
    ) -> None:
        self.host, self.port, self.figures = host, int(port), figures
        self.context = context
        self.rtu = RtuPoints(host, self.port, points, board, figures)
        self.interrogation_s, self.stations = self.rtu.interrogation_s, self.rtu.stations
        self._stop = threading.Event()
        self._sock: ssl.SSLSocket | None = None
        self._thread = threading.Thread(target=self._run, name=f"iec104-tls-{host}", daemon=True)
        self.connected = False  # the link is open (STARTDT confirmed)
        self.sent = self.received = self.unacked = 0  # I frames' sequence numbers (the link's)

    def __repr__(self) -> str:
        return f"IEC 104 (TLS) master of {self.host}:{self.port}"

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        sock = self._sock
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
        self._thread.join(timeout=5.0)

    # --- the master's thread -----------------------------------------------------------------

    def _run(self) -> None:
        wait = 1.0
        while not self._stop.is_set():
            try:
                self._link()
                wait = 1.0
            except ssl.SSLError as e:
                self.figures["iec104_tls_refused"] += 1
                logger.warning("IEC 104 %s:%d: TLS: %s", self.host, self.port, e.reason or e)
            except (OSError, ConnectionError, TimeoutError, ValueError) as e:
                if not self.connected:  # refused, unreachable, or dropped in its handshake
                    self.figures["iec104_link_failed"] += 1
                logger.info("IEC 104 %s:%d: %s", self.host, self.port, e)
            finally:
                if self.connected:
                    self.connected = False
                    self.rtu.lost()
            self._stop.wait(wait)
            wait = min(2 * wait, 10.0)

    def _link(self) -> None:
        raw = socket.create_connection((self.host, self.port), timeout=TIMEOUT_S)
        with self.context.wrap_socket(raw, server_hostname=self.host) as sock:
            self._sock = sock
            if self._stop.is_set():
                return
            sock.settimeout(1.0)
            sock.sendall(bytes([0x68, 4, STARTDT_ACT, 0, 0, 0]))
            self.sent = self.received = self.unacked = 0
            last_heard = time.monotonic()
            asked, tested, started = 0.0, None, False
            while not self._stop.is_set():
                now = time.monotonic()
                if started and now - asked >= self.interrogation_s:
                    for ca in self.stations:
                        self._interrogate(sock, ca)
                    asked = now
                if tested is None and now - last_heard >= QUIET_S:
                    sock.sendall(bytes([0x68, 4, TESTFR_ACT, 0, 0, 0]))
                    tested = now
                if now - last_heard >= QUIET_S + TIMEOUT_S:
                    raise TimeoutError("the RTU does not answer")
                frame = self._frame(sock)
                if frame is None:  # quiet for a second: what came is acknowledged (t2)
                    if self.unacked:
                        self._ack(sock)
                    continue
                last_heard, tested = time.monotonic(), None
                control, asdu = frame
                if control[0] & 1 == 0:  # an I frame
                    self.received = (self.received + 1) & 0x7FFF
                    self.unacked += 1
                    self._asdu(asdu)
                    if self.unacked >= ACK_EVERY:
                        self._ack(sock)
                elif control[0] == STARTDT_CON:  # the link is open
                    started, asked, self.connected = True, 0.0, True
                elif control[0] == TESTFR_ACT:
                    sock.sendall(bytes([0x68, 4, TESTFR_CON, 0, 0, 0]))

    def _frame(self, sock: ssl.SSLSocket) -> tuple[bytes, bytes] | None:
        """The next APDU's control field and ASDU; None when nothing came within a second."""
        try:
            head = sock.recv(2)
        except TimeoutError:
            return None
        if not head:
            raise ConnectionError("the RTU closed the link")
        if len(head) < 2:
            head += self._exactly(sock, 1)
        if head[0] != 0x68 or head[1] < 4:
            raise ValueError(f"not an IEC 104 frame (start {head[0]:#x}, length {head[1]})")
        body = self._exactly(sock, head[1])
        return body[:4], body[4:]

    @staticmethod
    def _exactly(sock: ssl.SSLSocket, n: int) -> bytes:
        out = b""
        deadline = time.monotonic() + TIMEOUT_S
        while len(out) < n:
            try:
                got = sock.recv(n - len(out))
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise
                continue
            if not got:
                raise ConnectionError("the RTU closed the link within a frame")
            out += got
        return out

    def _ack(self, sock: ssl.SSLSocket) -> None:
        sock.sendall(bytes([0x68, 4, 0x01, 0]) + struct.pack("<H", self.received << 1))
        self.unacked = 0

    def _interrogate(self, sock: ssl.SSLSocket, ca: int) -> None:
        """C_IC_NA_1 (activation, station interrogation) to common address `ca`."""
        asdu = bytes([100, 1, 6, 0]) + struct.pack("<H", ca) + bytes([0, 0, 0, 20])
        control = struct.pack("<HH", self.sent << 1, self.received << 1)
        sock.sendall(bytes([0x68, 4 + len(asdu)]) + control + asdu)
        self.sent = (self.sent + 1) & 0x7FFF
        self.unacked = 0

    def _asdu(self, asdu: bytes) -> None:
        """The points of one ASDU onto the board (unknown points and bad ones counted)."""
        if len(asdu) < 6:
            self.rtu.refused()
            return
        type_id, vsq = asdu[0], asdu[1]
        size = ELEMENT.get(type_id)
        if size is None:  # not a point this master reads (an interrogation's answer, ...)
            return
        ca = struct.unpack_from("<H", asdu, 4)[0]
        n, sequence = vsq & 0x7F, bool(vsq & 0x80)
        at, ioa = 6, 0
        for k in range(n):
            if not sequence or k == 0:
                if at + 3 > len(asdu):
                    break
                ioa, at = int.from_bytes(asdu[at : at + 3], "little"), at + 3
            elif sequence:
                ioa += 1
            if at + size > len(asdu):
                self.rtu.refused()
                return
            self._point(type_id, ca, ioa, asdu[at])
            at += size

    def _point(self, type_id: int, ca: int, ioa: int, q: int) -> None:
        good = q & 0xF0 == 0  # no IV, NT, SB or BL flag
        if type_id in (3, 31):
            self.rtu.double(ca, ioa, q & 0x03, good)
        else:
            self.rtu.single(ca, ioa, bool(q & 0x01), good)
