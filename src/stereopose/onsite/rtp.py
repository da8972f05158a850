"""IP speakers paged by RTP (RFC 3550, the audio/video profile RFC 3551): G.711 at 8 kHz in
20 ms packets (160 samples), multicast or unicast over UDP, as IP public-address speakers
(Axis, Algo, 2N and alike) take a page.

    speaker = Speaker(spec, repeat_s=4.0)      # a thread of its own, paced by the clock
    speaker.want(("busbar", "approach", 7), priority=2, pcm=message)   # the step's wish
    speaker.quiet()                            # the hazard is over: silent at the next packet

One message plays at a time, never two at once on one speaker. A more urgent message (a lower
priority number) cuts in at the next packet; a message of the same hazard (its key) asked for
again takes the new words (a distance, a side) at its next repeat; another of the same or
lower urgency waits for the one playing to end. While it is wanted a message is said again
every `repeat_s` from its start. `quiet` ends it at the next packet (at most 20 ms). Sending
never blocks a caller: the thread does it, and a send that fails is counted.
"""

from __future__ import annotations

import random
import socket
import struct
import threading
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass

import numpy as np

from stereopose.onsite.audio import CODECS, RATE, encode
from stereopose.onsite.settings import SpeakerSpec

__all__ = ["PACKET_S", "RtpPackets", "Speaker"]

PACKET_S = 0.02
SAMPLES = int(RATE * PACKET_S)  # 160


class RtpPackets:
    """RTP packets of one stream (one SSRC): the sequence number and the timestamp carried on
    from packet to packet; a talkspurt's first packet has the marker bit."""

    def __init__(self, codec: str, rng: random.Random | None = None) -> None:
        rng = rng or random.Random()
        self.payload_type = CODECS[codec]
        self.ssrc = rng.getrandbits(32)
        self.seq = rng.getrandbits(16)
        self.timestamp = rng.getrandbits(32)

    def packet(self, payload: bytes, marker: bool = False) -> bytes:
        header = struct.pack(
            "!BBHII",
            0x80,  # version 2, no padding, no extension, no CSRC
            (0x80 if marker else 0) | self.payload_type,
            self.seq,
            self.timestamp,
            self.ssrc,
        )
        self.seq = (self.seq + 1) & 0xFFFF
        self.timestamp = (self.timestamp + len(payload)) & 0xFFFFFFFF
        return header + payload

    def skip(self, samples: int) -> None:
        """The timestamp moved on over a silence of `samples` (nothing sent)."""
        self.timestamp = (self.timestamp + max(int(samples), 0)) & 0xFFFFFFFF


@dataclass
class _Message:
    key: Hashable
    priority: int
    payload: bytes  # encoded, whole
    next_payload: bytes | None = None  # the same hazard's newer words, from its next repeat


class Speaker:
    """One IP speaker (see the module). clock: monotonic seconds; sock: a UDP socket (None:
    one of its own, with the spec's multicast TTL)."""

    def __init__(
        self,
        spec: SpeakerSpec,
        repeat_s: float,
        clock: Callable[[], float] = time.monotonic,
        sock: socket.socket | None = None,
    ) -> None:
        self.spec, self.repeat_s, self.clock = spec, float(repeat_s), clock
        self.address = (spec.host, spec.port)
        family = socket.AF_INET6 if ":" in spec.host else socket.AF_INET
        self.sock = sock or socket.socket(family, socket.SOCK_DGRAM)
        if sock is None and spec.multicast:
            if family == socket.AF_INET:
                self.sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, spec.ttl)
            else:
                self.sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, spec.ttl)
        self.rtp = RtpPackets(spec.codec)
        self._cond = threading.Condition()
        self._wanted: _Message | None = None  # what the warner wants now
        self._playing: _Message | None = None
        self._stopped = False
        self.figures = {
            "packets": 0,
            "messages": 0,  # messages started (a repeat counts again)
            "cut_in": 0,
            "send_errors": 0,
        }
        self.sounding: Hashable | None = None  # the key of what plays now
        self._thread = threading.Thread(target=self._run, name=f"speaker {spec.name}", daemon=True)
        self._thread.start()

    # -- the warner's side: never blocks ---------------------------------------------------

    def want(self, key: Hashable, priority: int, pcm: np.ndarray) -> None:
        """Say `pcm` (int16 at 8 kHz) for hazard `key` while it is wanted (see the module)."""
        with self._cond:
            w = self._wanted
            if w is not None and w.key == key:
                w.next_payload = encode(pcm, self.spec.codec) if len(pcm) else w.payload
                return
            self._wanted = _Message(key, int(priority), encode(pcm, self.spec.codec))
            self._cond.notify()

    def quiet(self) -> None:
        """Nothing wanted: the message playing ends at the next packet."""
        with self._cond:
            if self._wanted is not None:
                self._wanted = None
                self._cond.notify()

    def close(self, timeout_s: float = 2.0) -> None:
        with self._cond:
            self._stopped = True
            self._wanted = None
            self._cond.notify()
        self._thread.join(timeout_s)
        self.sock.close()

    # -- the speaker's thread ---------------------------------------------------------------

    def _next(self, playing: _Message | None, ended: bool) -> _Message | None:
        """What plays from this packet on (under the lock): the wanted message, cutting in
        when more urgent, else after the one playing has ended."""
        w = self._wanted
        if w is None:
            return None
        if playing is None or w is playing:
            return w
        if w.priority < playing.priority:
            self.figures["cut_in"] += 1
            return w
        return w if ended else playing

    def _run(self) -> None:
        playing: _Message | None = None
        k = 0  # the next packet of the message playing
        started = 0.0  # when it started (its repeats count from there)
        due = sent_until = self.clock()  # the next packet's time; the last one's end
        while True:
            with self._cond:
                if self._stopped:
                    return
                ended = playing is not None and k * SAMPLES >= len(playing.payload)
                chosen = self._next(playing, ended)
                if chosen is not playing or playing is None:
                    playing, k = chosen, 0
                    started = due = max(due, self.clock())
                    if playing is not None:
                        self._start(playing, started - sent_until)
                elif ended:  # said: again once repeat_s from its start has passed
                    wait = started + self.repeat_s - self.clock()
                    if wait > 0:
                        self.sounding = None
                        self._cond.wait(wait)
                        continue
                    if playing.next_payload is not None:
                        playing.payload, playing.next_payload = playing.next_payload, None
                    k = 0
                    started = due = self.clock()
                    self._start(playing, started - sent_until)
                if playing is None:
                    self.sounding = None
                    self._cond.wait(1.0)
                    due = self.clock()
                    continue
                chunk = playing.payload[k * SAMPLES : (k + 1) * SAMPLES]
                first = k == 0
                k += 1
            self._send(chunk, first)
            due += PACKET_S
            sent_until = due
            with self._cond:  # paced: the next packet at its time; quiet or a cut-in at once
                while not self._stopped:
                    delay = due - self.clock()
                    w = self._wanted
                    cut_in = w is not None and w is not playing and w.priority < playing.priority
                    if delay <= 0 or w is None or cut_in:
                        break
                    self._cond.wait(delay)

    def _start(self, m: _Message, gap_s: float) -> None:
        """A talkspurt begins: its timestamp moved on over the silence before it."""
        self.rtp.skip(round(gap_s * RATE))
        self.figures["messages"] += 1
        self.sounding = m.key

    def _send(self, chunk: bytes, first: bool) -> None:
        if len(chunk) < SAMPLES:  # the last packet padded with silence (0xFF mu-law, 0xD5 A)
            chunk = chunk + bytes([0xFF if self.spec.codec == "pcmu" else 0xD5]) * (
                SAMPLES - len(chunk)
            )
        try:
            self.sock.sendto(self.rtp.packet(chunk, marker=first), self.address)
            self.figures["packets"] += 1
        except OSError:
            self.figures["send_errors"] += 1
