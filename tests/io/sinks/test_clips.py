"""Event clips on real frames: the MP4 decodes with the frames from pre_s before to post_s after,
alarms close together share one clip, hostile zone names, a folder gone, a stalled buffer."""

from __future__ import annotations

import threading
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.errors import ConfigError
from stereopose.io.sinks import FrameResult
from stereopose.io.sinks.clips import ClipSettings, ClipSink, clip_name
from stereopose.types import Event, People3D
from waiting import wait_until

FPS = 10.0
CAMERAS = ["cam1", "cam2"]
WALL = datetime(2024, 5, 1, 13, 0, 0, tzinfo=UTC).timestamp()


def people(f: int, seen_by: list[int]) -> People3D:
    """Person 3, seen by the cameras of `seen_by` (indices into CAMERAS)."""
    det = [[0 if c in seen_by else -1 for c in range(len(CAMERAS))]]
    return People3D(
        f, np.zeros((1, 17, 3)), np.ones((1, 17)), [3], np.zeros((1, 17)), np.full((1, 17), 2), det
    )


def alarm(f: int, zone: str = "panel_A", kind: str = "energized", type_: str = "enter") -> Event:
    return Event(f / FPS, f, 3, zone, kind, type_, f / FPS)


def frame(f: int, events: tuple[Event, ...] = (), seen_by: list[int] | None = None) -> FrameResult:
    """160x120 frames showing the frame number: 8 columns, white for its bits that are set."""
    images = {c: numbered(f) for c in CAMERAS}
    return FrameResult(
        f, f / FPS, {}, people(f, [0] if seen_by is None else seen_by), events, images
    )


def numbered(f: int) -> np.ndarray:
    bits = (f >> np.arange(8)) & 1
    return np.repeat(np.repeat(bits * 255, 20)[None, :, None], 120, 0).repeat(3, 2).astype(np.uint8)


def number(image: np.ndarray) -> int:
    columns = image.reshape(120, 8, 20, 3).mean(axis=(0, 2, 3)) > 128
    return int(sum(1 << k for k in range(8) if columns[k]))


def sink(tmp_path: Path, **kw) -> ClipSink:
    draw = kw.pop("draw", None)
    # a queue that holds a whole test run: frames dropped when it is full are tested apart
    kw.setdefault("clip_queue_frames", 1000)
    settings = ClipSettings(clip_pre_s=1.0, clip_post_s=1.0, clip_scale=1.0, **kw)
    return ClipSink(tmp_path, CAMERAS, FPS, wall_start=WALL, draw=draw, settings=settings)


def run(s: ClipSink, frames: int, events: dict[int, tuple[Event, ...]]) -> list[Path]:
    for f in range(frames):
        s.write(frame(f, events.get(f, ())))
    return s.close()


def decoded(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened()
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(FPS)
    out = []
    while True:
        ok, image = cap.read()
        if not ok:
            break
        out.append(image)
    cap.release()
    return out


def levels(path: Path) -> list[int]:
    """The frame numbers a clip holds, read from its pictures."""
    return [number(im) for im in decoded(path)]


def test_an_alarm_makes_a_clip_from_pre_s_before_to_post_s_after(tmp_path: Path) -> None:
    s = sink(tmp_path)
    paths = run(s, 60, {30: (alarm(30),), 10: (alarm(10, kind="work_area"),)})
    # only the camera that saw the person; the work-area event is no alarm
    assert [p.name for p in paths] == ["20240501-130003_3_panel_A_cam1.mp4"]
    assert levels(paths[0]) == list(range(20, 41))  # t in [2.0, 4.0]: 21 frames, 2.1 s
    assert s.clips_written == 1 and s.clips_failed == 0 and s.incomplete is None
    assert sorted(p.name for p in (tmp_path / "clips").iterdir()) == [paths[0].name]


def test_alarms_close_together_share_one_clip(tmp_path: Path) -> None:
    s = sink(tmp_path)
    paths = run(s, 80, {30: (alarm(30),), 35: (alarm(35, type_="approach"),), 60: (alarm(60),)})
    assert [p.name for p in paths] == [
        "20240501-130003_3_panel_A_cam1.mp4",
        "20240501-130006_3_panel_A_cam1.mp4",
    ]
    assert levels(paths[0]) == list(range(20, 46))  # extended to 1 s after the second
    assert levels(paths[1]) == list(range(50, 71))
    assert s.frames_dropped == 0


def test_a_clip_never_repeats_frames_of_the_one_before(tmp_path: Path) -> None:
    s = sink(tmp_path, clip_max_s=1.5)
    paths = run(s, 60, {30: (alarm(30),), 36: (alarm(36),)})
    first, second = (levels(p) for p in paths)
    assert first == list(range(20, 36)) and second == list(range(36, 47))


def test_a_full_buffer_drops_its_oldest_frames_counted(tmp_path: Path) -> None:
    s = sink(tmp_path, clip_buffer_frames=4)
    (path,) = run(s, 40, {30: (alarm(30),)})
    assert levels(path) == list(range(27, 40))  # the run ends at frame 39
    assert s.buffer_dropped > 0


def test_every_camera_that_saw_the_person_gets_its_clip(tmp_path: Path) -> None:
    s = sink(tmp_path)
    for f in range(40):
        s.write(frame(f, (alarm(30),) if f == 30 else (), seen_by=[0, 1]))
    assert sorted(p.name.rsplit("_", 1)[1] for p in s.close()) == ["cam1.mp4", "cam2.mp4"]


@pytest.mark.parametrize(
    "zone", ["../../etc/passwd", "panel/A\x00\n", "⚡ Hochspannung ⚡", "", "." * 300, "a" * 1000]
)
def test_any_zone_name_gives_a_safe_file_name_in_the_clips_folder(tmp_path: Path, zone: str):
    s = sink(tmp_path)
    (path,) = run(s, 35, {30: (alarm(30, zone=zone),)})
    assert path.parent == tmp_path / "clips" and len(path.name) < 200
    assert path.name.startswith("20240501-130003_3_") and path.name.endswith("_cam1.mp4")
    assert all(c.isascii() and (c.isalnum() or c in "_.-") for c in path.name)
    assert sorted(tmp_path.rglob("*")) == [tmp_path / "clips", path]


def test_a_name_taken_is_never_overwritten(tmp_path: Path) -> None:
    taken = tmp_path / "clips" / (clip_name(WALL + 3.0, 3, "panel_A", "cam1") + ".mp4")
    taken.parent.mkdir()
    taken.write_bytes(b"an earlier clip")
    (path,) = run(sink(tmp_path), 35, {30: (alarm(30),)})
    assert path.name == "20240501-130003_3_panel_A_cam1_001.mp4"
    assert taken.read_bytes() == b"an earlier clip"


def test_a_folder_gone_loses_that_clip_counted_and_the_next_one_is_written(
    tmp_path: Path, caplog
) -> None:
    s = sink(tmp_path)
    clips = tmp_path / "clips"
    clips.rmdir()
    clips.write_text("a file where the folder was")
    for f in range(35):
        s.write(frame(f, (alarm(30),) if f == 30 else ()))
    s.write(frame(50))  # a frame after the end of the clip: it is finished
    wait_until(lambda: s.clips_failed == 1, "the clip to fail")
    clips.unlink()  # the folder can be made again
    for f in range(51, 80):
        s.write(frame(f, (alarm(60),) if f == 60 else ()))
    paths = s.close()
    assert [p.name for p in paths] == ["20240501-130006_3_panel_A_cam1.mp4"]
    assert levels(paths[0]) == list(range(51, 71))  # none of the lost clip's frames
    assert s.clips_failed == 1 and "1 event clip(s) not written" in s.incomplete
    assert caplog.text.count("not written") == 1  # logged once
    assert "written again" in caplog.text


def test_a_stalled_buffer_never_stalls_the_frame_loop(tmp_path: Path) -> None:
    release = threading.Event()

    def slow_draw(camera, image, p2, p3, scale, label):
        release.wait(10)
        return image

    s = sink(tmp_path, draw=slow_draw, clip_queue_frames=2)
    for f in range(40):  # returns at once although nothing is drawn
        s.write(frame(f, (alarm(39),) if f == 39 else ()))
    assert s.frames_dropped >= 30
    release.set()
    (path,) = s.close()  # the alarm of a dropped frame still makes its clip
    assert path.name == "20240501-130003_3_panel_A_cam1.mp4" and decoded(path)


def test_drawn_frames_are_the_ones_in_the_clip(tmp_path: Path) -> None:
    def draw(camera, image, p2, p3, scale, label):
        out = image.copy()
        cv2.rectangle(out, (40, 30), (120, 90), (0, 0, 255), -1)  # red, where the person is
        return out

    (path,) = run(sink(tmp_path, draw=draw), 35, {30: (alarm(30),)})
    first = decoded(path)[0]
    assert first[60, 80, 2] > 200 and first[60, 80, 0] < 60 and first[5, 5, 2] < 100


def test_clip_drawer_draws_the_reprojected_people(tmp_path: Path) -> None:
    from stereopose.sim import simulate
    from stereopose.viz.clips import clip_drawer
    from stereopose.viz.overlay import draw_overlay

    scene = simulate(num_cameras=2, num_people=1, num_frames=2, seed=1, difficulty="easy")
    cam = scene.rig[0]
    w, h = (int(v) for v in cam.size)
    image = np.zeros((h, w, 3), np.uint8)
    p3 = People3D(
        1,
        scene.truth[1][:1],
        np.ones((1, 17)),
        [5],
        np.zeros((1, 17)),
        np.full((1, 17), 2),
        np.zeros((1, 2), int),
    )
    drawn = clip_drawer(scene.rig)(cam.name, image, None, p3, 0.25, "label")
    assert np.array_equal(drawn, draw_overlay(image, cam, None, p3, 0.25, "label"))
    assert drawn.shape == (round(h * 0.25), round(w * 0.25), 3) and drawn.max() > 0


def test_settings_name_their_key() -> None:
    with pytest.raises(ConfigError, match=r"storage\.clip_pre_s: expected"):
        ClipSettings(clip_pre_s=-1)
    with pytest.raises(ConfigError, match=r"storage\.clip_buffer_frames: expected an integer"):
        ClipSettings(clip_buffer_frames=2.5)
