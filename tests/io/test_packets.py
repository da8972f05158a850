"""A live camera's full stream kept encoded (io.packets): the ring's keyframe-aligned bounds,
stream copies that decode, a real stream demuxed without decoding beside its substream, and
the clips' full-stream copies."""

from __future__ import annotations

import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.errors import StereoposeError
from stereopose.io.cameraset import CameraSet
from stereopose.io.packets import PacketRing, StreamFormat, write_copy
from stereopose.io.sinks.base import FrameResult
from stereopose.io.sinks.clips import FULL_SUFFIX, ClipSettings, ClipSink
from stereopose.types import Camera, Event, People3D, Rig
from stereopose.viz.clips import clip_drawer
from streams import ffmpeg, free_port, stop, wait_serving
from waiting import wait_until

FPS = 25.0


def test_the_ring_keeps_whole_groups_from_a_keyframe() -> None:
    ring = PacketRing(keep_s=1.0, max_bytes=10_000)
    ring.push(0.00, False, b"x" * 10)  # before any keyframe: nothing to decode it from
    assert ring.packets == 0 and ring.between(0, 10) == []
    for i in range(100):  # a keyframe every 10 packets, 25 packets a second
        ring.push(0.04 * (i + 1), i % 10 == 0, bytes([i]) * 10)
    # the newest 1 s at least, whole groups: the oldest kept starts at a keyframe
    kept = [data for _, data in ring.between(-1, 10)]
    assert kept[0] == bytes([80]) * 10 or kept[0] == bytes([70]) * 10
    assert kept[-1] == bytes([99]) * 10
    # from the last keyframe at or before t0, up to t1
    part = [data for _, data in ring.between(0.04 * 95, 0.04 * 97)]
    assert part == [bytes([i]) * 10 for i in range(90, 97)]
    # what follows a copy written up to t0
    more = ring.after(0.04 * 97, 0.04 * 99)
    assert [data for _, data in more] == [bytes([97]) * 10, bytes([98]) * 10]
    assert ring.dropped_groups == 0


def test_the_byte_bound_drops_the_oldest_groups_and_counts_them() -> None:
    ring = PacketRing(keep_s=100.0, max_bytes=1_000)
    for i in range(50):
        ring.push(i * 0.04, i % 5 == 0, b"y" * 100)
    assert ring.bytes <= 1_000
    assert ring.dropped_groups == 8  # 10 groups of 500 bytes: the 2 newest kept
    assert len(ring.between(0, 100)) == 10


def test_bad_bounds_are_refused() -> None:
    with pytest.raises(StereoposeError, match="keep_s and max_bytes"):
        PacketRing(0, 10)


def _encode(path: Path, codec: str, seconds: float = 3.0, size: str = "192x128") -> Path:
    cmd = [
        ffmpeg(),
        "-loglevel",
        "error",
        "-y",
        "-f",
        "lavfi",
        "-i",
        f"testsrc=size={size}:rate={FPS:g}",
        "-t",
        str(seconds),
        "-c:v",
        codec,
        "-g",
        "10",
        "-f",
        "mpegts",
        str(path),
    ]
    subprocess.run(cmd, check=True, timeout=60)
    return path


def _demuxed(path: Path) -> PacketRing:
    """The file's packets, as a live reader keeps them (t = index / fps)."""
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, [cv2.CAP_PROP_FORMAT, -1])
    code = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode().strip("\x00 ")
    ring = PacketRing(100.0, 2**24)
    ring.format = StreamFormat(code, FPS, (int(cap.get(3)), int(cap.get(4))))
    i = 0
    while cap.grab():
        ok, packet = cap.retrieve()
        assert ok
        ring.push(i / FPS, bool(cap.get(cv2.CAP_PROP_LRF_HAS_KEY_FRAME)), packet.tobytes())
        i += 1
    cap.release()
    return ring


@pytest.mark.parametrize("codec", ["libx264", "mpeg1video"])
def test_a_stream_copy_decodes_from_the_keyframe_before_its_start(tmp_path, codec) -> None:
    ring = _demuxed(_encode(tmp_path / "in.ts", codec))
    out = tmp_path / "copy.mp4"
    frames = write_copy(out, ring.between(1.0, 2.0), ring.format)
    assert frames == 31  # from the keyframe at 0.8 s (every 10 frames) to 2.0 s
    cap = cv2.VideoCapture(str(out))
    ok, image = cap.read()
    cap.release()
    assert ok and image.shape == (128, 192, 3)


def test_a_copy_that_cannot_be_written_is_an_error_naming_it(tmp_path) -> None:
    ring = _demuxed(_encode(tmp_path / "in.ts", "libx264"))
    bad = tmp_path / "missing" / "copy.mp4"
    with pytest.raises(StereoposeError, match="copy"):
        write_copy(bad, ring.between(0, 1), ring.format)
    with pytest.raises(StereoposeError, match="no packets"):
        write_copy(tmp_path / "x.mp4", [], ring.format)


def _serve_ts(path: Path, port: int, name: str) -> subprocess.Popen:
    cmd = [
        ffmpeg(),
        "-loglevel",
        "error",
        "-re",
        "-stream_loop",
        "-1",
        "-i",
        str(path),
        "-an",
        "-c",
        "copy",
        "-f",
        "mpegts",
        "-listen",
        "1",
        f"http://127.0.0.1:{port}/{name}.ts",
    ]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def test_a_full_stream_is_kept_encoded_beside_its_substream(tmp_path) -> None:
    full = _encode(tmp_path / "full.ts", "libx264", 4.0, "384x256")
    sub = _encode(tmp_path / "sub.ts", "libx264", 4.0, "96x64")
    ports = [free_port(), free_port()]
    servers = [_serve_ts(full, ports[0], "full"), _serve_ts(sub, ports[1], "sub")]
    ring = PacketRing(10.0, 2**24)
    try:
        wait_serving(servers, ports)
        urls = [f"http://127.0.0.1:{ports[0]}/full.ts", f"http://127.0.0.1:{ports[1]}/sub.ts"]
        with CameraSet([urls[0]], ["cam"], detect=[urls[1]], packets={"cam": ring}) as cams:
            steps = []
            for step in cams:
                steps.append(step)
                if len(steps) == 10:
                    break
            wait_until(lambda: ring.packets >= 25, "a second of the full stream kept")
            full_stats = cams.stats()["cam"]
    finally:
        stop(servers)
    # every step's picture is the substream's frame; the full stream was never decoded
    assert all(s.images["cam"] is s.detect["cam"] for s in steps)
    assert {s.images["cam"].shape for s in steps} == {(64, 96, 3)}
    assert full_stats.decoded == 0 and full_stats.grabbed >= 25
    assert ring.format is not None and ring.format.size == (384, 256)
    frames = write_copy(tmp_path / "copy.mp4", ring.between(0, 1e9), ring.format)
    assert frames >= 10


def test_an_alarm_clip_has_its_full_stream_copy_beside_it(tmp_path) -> None:
    """A camera kept encoded: its clip drawn on the substream's (small) frames, at the clip
    size a full frame gives, and `<clip>.full.mp4` of the same span from the packets."""
    cam, (w, h) = "cam", (384, 256)
    K = np.array([[300.0, 0, w / 2], [0, 300.0, h / 2], [0, 0, 1]])
    rig = Rig((Camera(cam, (w, h), K, np.zeros(5), np.zeros(3), np.array([0, 0, 5.0])),))
    ring = _demuxed(_encode(tmp_path / "in.ts", "libx264", 6.0, f"{w}x{h}"))
    settings = ClipSettings(clip_pre_s=1.0, clip_post_s=1.0, clip_queue_frames=1000)
    sink = ClipSink(
        tmp_path,
        [cam],
        FPS,
        wall_start=1.8e9,
        settings=settings,
        draw=clip_drawer(rig),
        packets={cam: ring},
    )
    small = np.zeros((h // 4, w // 4, 3), np.uint8)
    for i in range(100):
        t = i / FPS
        events = [Event(t, i, 1, "busbar", "energized", "enter", t)] if i == 50 else []
        sink.write(FrameResult(i, t, {}, People3D.empty(0, 0), events, {cam: small}))
    written = sink.close()
    drawn = [p for p in written if not p.name.endswith(FULL_SUFFIX)]
    copies = [p for p in written if p.name.endswith(FULL_SUFFIX)]
    assert len(drawn) == 1 and len(copies) == 1, written
    assert copies[0].name == drawn[0].name[: -len(".mp4")] + FULL_SUFFIX
    assert sink.copies_written == 1 and sink.copies_failed == 0
    cap = cv2.VideoCapture(str(drawn[0]))
    ok, image = cap.read()
    cap.release()
    assert ok and image.shape[:2] == (h // 2, w // 2)  # clip_scale of a full frame
    cap = cv2.VideoCapture(str(copies[0]))
    n, ok = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), cap.read()[0]
    cap.release()
    assert ok and n >= 50  # 1 s before to 1 s after, from the keyframe before


def test_a_clip_extended_by_later_alarms_has_all_of_its_full_stream(tmp_path) -> None:
    """The copy is written as the clip goes on: a clip longer than the ring holds (alarms that
    keep coming) still has its whole span; the ring is fed as a live reader feeds it."""
    cam, (w, h) = "cam", (192, 128)
    source = _demuxed(_encode(tmp_path / "in.ts", "libx264", 12.0, f"{w}x{h}"))
    packets = source.between(0, 1e9)
    ring = PacketRing(2.0, 2**24)  # 2 s: far shorter than the clip
    ring.format = source.format
    settings = ClipSettings(clip_pre_s=1.0, clip_post_s=1.0, clip_queue_frames=1000)
    sink = ClipSink(tmp_path, [cam], FPS, wall_start=1.8e9, settings=settings, packets={cam: ring})
    image = np.zeros((h, w, 3), np.uint8)
    keys = {i for i in range(len(packets)) if i % 10 == 0}
    for i in range(len(packets)):
        t = i / FPS
        ring.push(t, i in keys, packets[i][1])
        alarm = 50 <= i <= 200 and i % 25 == 0  # every second from 2 s to 8 s
        events = [Event(t, i, 1, "busbar", "energized", "enter", t)] if alarm else []
        sink.write(FrameResult(i, t, {}, People3D.empty(0, 0), events, {cam: image}))
        # a live feed is paced by the cameras: the writer keeps within the ring's span
        wait_until(lambda: sink._jobs.qsize() == 0 and sink._frames.qsize() == 0, "the clips")
    written = sink.close()
    copies = [p for p in written if p.name.endswith(FULL_SUFFIX)]
    assert len(copies) == 1 and sink.copies_failed == 0, written
    cap = cv2.VideoCapture(str(copies[0]))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert n >= 8 * FPS  # 1 s before the first alarm to 1 s after the last: 8 s and more
