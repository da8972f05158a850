"""Recorded files at a node: on the wall clock, the same frame on every node at once."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from stereopose.nodes.paced import PacedCamera, PacedError, PacedFiles, ping_pong


def test_ping_pong_swings_between_the_ends():
    assert [ping_pong(i, 4) for i in range(10)] == [0, 1, 2, 3, 2, 1, 0, 1, 2, 3]
    assert ping_pong(10**12 + 3, 1) == 0
    assert ping_pong(6 * 10**11 + 2, 4) == 2  # any wall time: no frame passed over one by one


@pytest.mark.realdata
def test_two_nodes_show_the_same_frame_at_the_same_wall_time(pose2sim_dir):
    video = str(pose2sim_dir / "Demo_MultiPerson" / "videos" / "cam01.mp4")
    a = PacedFiles({"cam01": (video, True)}, rate=4.0)
    b = PacedFiles({"cam01": (video, True)}, rate=4.0)  # another node, started later
    steps_a, steps_b = [], []

    def take(src, out):
        for fs in src:
            out.append((fs.t, fs.source_frames["cam01"], fs.images["cam01"]))
            if len(out) == 4:
                src.end()

    threads = [threading.Thread(target=take, args=(s, o)) for s, o in ((a, steps_a), (b, steps_b))]
    for th in threads:
        th.start()
    for th in threads:
        th.join(30)
    assert len(steps_a) == len(steps_b) == 4
    times = [t for t, _, _ in steps_a]
    assert all(abs(t * 4 - round(t * 4)) < 1e-6 for t in times)  # on the 4-Hz grid
    assert np.all(np.diff(times) > 0)
    cam = a.cameras["cam01"]
    assert cam.fps == 60.0 and len(cam.frames) == 100
    both = {t: pos for t, pos, _ in steps_a} | {}
    for t, pos, image in steps_b:
        assert pos == ping_pong(int(np.floor(t * 60)), 100)
        if t in both:
            assert both[t] == pos
        assert image.shape == (1920, 1088, 3)


def test_a_file_that_is_not_a_video_is_named(tmp_path):
    bad = tmp_path / "cam01.mp4"
    bad.write_bytes(b"not a video at all")
    with pytest.raises(PacedError, match="cam01"):
        PacedCamera("cam01", str(bad), True)
