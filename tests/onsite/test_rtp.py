"""IP speakers by RTP (onsite.rtp): what FFmpeg decodes from the stream is the message, and
the speaker's rules (one message at a time, a more urgent one cuts in, repeats, quiet)."""

from __future__ import annotations

import itertools
import socket
import subprocess
import time

import numpy as np
import pytest

from rtp_listener import Listener
from stereopose.onsite.audio import decode, encode
from stereopose.onsite.rtp import SAMPLES, Speaker
from stereopose.onsite.settings import SpeakerSpec
from streams import ffmpeg
from waiting import wait_until


def udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tone(hz: float, seconds: float, level: float = 8000) -> np.ndarray:
    t = np.arange(int(8000 * seconds)) / 8000
    return (level * np.sin(2 * np.pi * hz * t) * np.hanning(len(t))).astype(np.int16)


def chirp(seconds: float) -> np.ndarray:
    """A sweep 300-3000 Hz: one clear peak of correlation."""
    t = np.arange(int(8000 * seconds)) / 8000
    f = 300 + (3000 - 300) * t / seconds
    return (9000 * np.sin(2 * np.pi * np.cumsum(f) / 8000)).astype(np.int16)


def bound(port: int) -> bool:
    """Whether someone has bound UDP `port` on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


@pytest.mark.parametrize(("codec", "pt", "name"), [("pcmu", 0, "PCMU"), ("pcma", 8, "PCMA")])
def test_ffmpeg_decodes_the_message_from_the_sdp(tmp_path, codec, pt, name):
    port = udp_port() & ~1  # RTP on an even port, RTCP on the next
    sdp = tmp_path / "page.sdp"
    sdp.write_text(
        "v=0\r\no=- 0 0 IN IP4 127.0.0.1\r\ns=page\r\nc=IN IP4 127.0.0.1\r\nt=0 0\r\n"
        f"m=audio {port} RTP/AVP {pt}\r\na=rtpmap:{pt} {name}/8000\r\n"
    )
    out = tmp_path / "heard.raw"
    cmd = [ffmpeg(), "-nostdin", "-loglevel", "error", "-protocol_whitelist", "file,udp,rtp"]
    cmd += ["-analyzeduration", "500000"]  # the SDP says the codec: no long probe
    cmd += ["-i", str(sdp), "-f", "s16le", "-ar", "8000", "-ac", "1", "-y", str(out)]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE)
    speaker = None
    try:
        wait_until(lambda: bound(port), "FFmpeg listening", timeout_s=20)
        spec = SpeakerSpec("pa", "127.0.0.1", port, ("busbar",), codec=codec)
        speaker = Speaker(spec, repeat_s=60.0)
        message = chirp(1.5)
        speaker.want(("busbar", "approach", 1), 2, message)
        packets = -(-len(message) // SAMPLES)
        wait_until(lambda: speaker.figures["packets"] >= packets, "the message sent", 10)
        speaker.quiet()
        expected = decode(encode(message, codec), codec).astype(float)
        wait_until(lambda: out.exists() and out.stat().st_size >= 2 * len(expected), "decoded")
    finally:
        if speaker is not None:
            speaker.close()
        proc.terminate()
        proc.wait(10)
    heard = np.frombuffer(out.read_bytes(), "<i2").astype(float)
    corr = np.correlate(heard, expected, mode="valid")
    at = int(np.argmax(corr))
    piece = heard[at : at + len(expected)]
    r = float(np.dot(piece, expected) / (np.linalg.norm(piece) * np.linalg.norm(expected)))
    assert r > 0.95, r
    assert speaker.figures["send_errors"] == 0 and speaker.figures["messages"] == 1


def test_one_message_at_a_time_a_more_urgent_one_cuts_in_and_quiet_ends_it():
    ear = Listener()
    spec = SpeakerSpec("pa", "127.0.0.1", ear.port, ("busbar",))
    speaker = Speaker(spec, repeat_s=1.0)
    low, high = tone(400, 3.0), tone(1200, 0.5)
    try:
        speaker.want(("work", "approach", 1), 3, low)
        ear.take(lambda: len(ear.packets) >= 10)
        speaker.want(("busbar", "enter", 2), 1, high)  # cuts in at the next packet
        ear.take(lambda: sum(p[1] for p in ear.packets) >= 3)  # the P1's first and a repeat
        speaker.quiet()
        quiet_at = time.monotonic()
        wait_until(lambda: speaker.sounding is None, "quiet")
        sent = speaker.figures["packets"]
        ear.take(lambda: len(ear.packets) >= sent)
    finally:
        speaker.close()
    packets = ear.packets
    seqs = [p[3] for p in packets]
    assert all((b - a) % 65536 == 1 for a, b in itertools.pairwise(seqs))
    assert all(len(p[5]) == SAMPLES and p[2] == 0 for p in packets)
    starts = [k for k, p in enumerate(packets) if p[1]]
    assert starts[0] == 0 and starts[1] < 20  # the P3 cut after about 10 packets, not 150
    cut = packets[starts[1]]
    assert cut[5] == encode(high, "pcmu")[:SAMPLES]
    # the P1 said again repeat_s after its start, its packets 20 ms apart in between
    gap = packets[starts[2]][0] - cut[0]
    assert 0.9 < gap < 1.6, gap
    assert speaker.figures["cut_in"] == 1
    assert packets[-1][0] - quiet_at < 0.1  # quiet at the next packet (20 ms), not the end


def test_the_same_hazard_takes_new_words_at_its_next_repeat_and_a_lesser_one_waits():
    ear = Listener()
    spec = SpeakerSpec("pa", "127.0.0.1", ear.port, ("busbar",))
    speaker = Speaker(spec, repeat_s=1.0)
    first, newer, other = tone(500, 0.4), tone(900, 0.4), tone(1500, 0.4)
    try:
        speaker.want(("busbar", "approach", 1), 2, first)
        ear.take(lambda: len(ear.packets) >= 3)
        speaker.want(("busbar", "approach", 1), 2, newer)  # the same hazard, nearer now
        ear.take(lambda: sum(p[1] for p in ear.packets) >= 2)
        speaker.want(("busbar", "approach", 2), 2, other)  # another, as urgent: waits its end
        ear.take(lambda: sum(p[1] for p in ear.packets) >= 3)
    finally:
        speaker.close()
    starts = [p for p in ear.packets if p[1]]
    assert starts[0][5] == encode(first, "pcmu")[:SAMPLES]
    assert starts[1][5] == encode(newer, "pcmu")[:SAMPLES]  # the repeat with the new words
    assert starts[2][5] == encode(other, "pcmu")[:SAMPLES]
    k = ear.packets.index(starts[2])
    assert ear.packets[k - 1][5] == encode(newer, "pcmu")[SAMPLES * 19 : SAMPLES * 20]
