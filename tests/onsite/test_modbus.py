"""Beacons and sirens by Modbus TCP (onsite.modbus): pymodbus's own server plays the IO
module, and its coils are read back from it; a device that is down, hangs or answers
garbage is told once, never a traceback, never a blocked caller."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from modbus_device import IoModule
from stereopose.onsite.modbus import Signal
from stereopose.onsite.settings import SignalSpec
from waiting import wait_until


def spec(port: int, unit: int = 1) -> SignalSpec:
    return SignalSpec("tower", "127.0.0.1", (("beacon", 0), ("siren", 3)), ("busbar",), port, unit)


@pytest.fixture
def module():
    m = IoModule(unit=2).start()
    yield m
    m.stop()


def test_the_coils_follow_what_is_wanted_and_go_off_at_close(module):
    told = []
    signal = Signal(spec(module.port, unit=2), on_health=lambda *a: told.append(a))
    try:
        signal.want({"beacon", "siren", "horn"})  # a name it has not: ignored
        wait_until(lambda: module.coils(0, 4) == [True, False, False, True], "both on")
        signal.want({"beacon"})
        wait_until(lambda: module.coils(0, 4) == [True, False, False, False], "the siren off")
        t0 = time.monotonic()
        signal.want(set())
        wait_until(lambda: module.coils(0, 4) == [False] * 4, "every coil off")
        wait_until(lambda: signal.taken[0] == frozenset(), "the wish taken")
        assert signal.taken[1] >= t0
        signal.want({"siren"})
        wait_until(lambda: module.coils(3) == [True], "the siren on again")
    finally:
        signal.close()
    assert module.coils(0, 4) == [False] * 4  # closed: nothing left on
    assert signal.up and told == [] and signal.figures["failures"] == 0


def test_a_device_down_is_told_once_and_back_when_it_answers_and_is_set_again(module):
    told = []
    signal = Signal(spec(module.port, unit=2), on_health=lambda *a: told.append(a[:2]))
    try:
        signal.want({"beacon"})
        wait_until(lambda: module.coils(0) == [True], "the beacon on")
        module.stop()
        wait_until(lambda: told == [("tower", False)], "down told", timeout_s=10)
        t0 = time.monotonic()
        signal.want({"beacon", "siren"})  # never waits on the device
        assert time.monotonic() - t0 < 0.05
        restarted = IoModule(unit=2, port=module.port).start()  # a module that restarted
        try:
            wait_until(lambda: told[-1] == ("tower", True), "back told", timeout_s=10)
            wait_until(lambda: restarted.coils(0, 4) == [True, False, False, True], "set again")
        finally:
            signal.close()
            restarted.stop()
    finally:
        signal.close()
    assert told == [("tower", False), ("tower", True)]


class Hostile:
    """A TCP server that answers every request with `reply` (b"": never answers)."""

    def __init__(self, reply: bytes) -> None:
        self.reply = reply
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            threading.Thread(target=self._answer, args=(conn,), daemon=True).start()

    def _answer(self, conn: socket.socket) -> None:
        try:
            while conn.recv(1024):
                if self.reply:
                    conn.sendall(self.reply)
        except OSError:
            return

    def close(self) -> None:
        self.sock.close()
        for c in self.conns:
            c.close()


@pytest.mark.parametrize(
    "reply",
    [b"", b"\x00\x01\x00\x00\x00\x03\x01\x85\x02", b"HTTP/1.1 400 Bad Request\r\n\r\n" * 3],
    ids=["hangs", "exception", "garbage"],
)
def test_a_device_that_hangs_or_answers_badly_is_down(reply):
    peer = Hostile(reply)
    told = []
    signal = Signal(spec(peer.port), on_health=lambda *a: told.append(a), timeout_s=0.3)
    try:
        signal.want({"beacon"})
        wait_until(lambda: told, "down told", timeout_s=10)
        assert told[0][:2] == ("tower", False) and told[0][2]
        assert signal.up is False and signal.figures["failures"] >= 1
    finally:
        signal.close()
        peer.close()
