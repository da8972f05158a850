"""Each tracked person's box in a camera (pipeline.track_regions.track_boxes): the regions'
hints."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.io.records import people3d_from_record
from stereopose.pipeline.track_regions import FOOT_ROOM, HEAD_ROOM, track_boxes
from stereopose.types import Camera

CAM = Camera(
    "cam",
    (200, 200),
    np.array([[100.0, 0, 100], [0, 100.0, 100], [0, 0, 1]]),
    np.zeros(4),
    np.zeros(3),
    np.zeros(3),
)  # at the origin, looking along +z: x right, y down


def person(pid: int, x: float, z: float, missing=()) -> dict:
    """17 joints on a vertical line at (x, z), y from -0.8 (head) to 0.8 (feet)."""
    ys = np.linspace(-0.8, 0.8, 17)
    return {"id": pid, "joints": [None if k in missing else [x, y, z] for k, y in enumerate(ys)]}


def test_a_box_holds_the_joints_with_room_for_the_head_and_the_feet():
    people = people3d_from_record(0, [person(1, 0.0, 4.0), person(2, 1.0, 8.0, missing=(0,))])
    boxes = track_boxes(people, CAM, 0.0)
    assert boxes.shape == (2, 4)
    h1 = 100 * 1.6 / 4  # 40 px tall at 4 m
    assert boxes[0] == pytest.approx([100, 100 - 20 - HEAD_ROOM * h1, 100, 120 + FOOT_ROOM * h1])
    # the second: his missing top joint left out, 8 m away
    top = 100 + 100 * np.linspace(-0.8, 0.8, 17)[1] / 8
    assert boxes[1][0] == pytest.approx(112.5) and boxes[1][1] < top


def test_people_behind_or_beside_the_camera_give_no_box():
    people = people3d_from_record(
        0, [person(1, 0.0, -3.0), person(2, 0.0, 4.0), person(3, 0.0, 0.3)]
    )
    boxes = track_boxes(people, CAM, 0.0)
    assert len(boxes) == 1 and boxes[0][0] == pytest.approx(100)
    assert track_boxes(people3d_from_record(0, []), CAM, 0.0).shape == (0, 4)


def test_the_cameras_that_see_a_person():
    """A camera sees a picked person where its detection was used for him, or where a joint
    of his projects into its picture; people not picked are not asked about."""
    from stereopose.pipeline.track_regions import cameras_seeing
    from stereopose.types import Rig

    lens = (CAM.size, CAM.matrix, CAM.distortions)
    turned = Camera("back", *lens, np.array([0.0, np.pi, 0.0]), np.zeros(3))
    aside = Camera("aside", *lens, np.zeros(3), np.array([50.0, 0, 0]))
    rig = Rig((CAM, turned, aside))
    ahead, behind = person(1, 0.0, 4.0), person(2, 0.0, -4.0)
    people = people3d_from_record(0, [ahead, behind])
    assert cameras_seeing(people, rig, np.array([True, False])) == {"cam"}
    assert cameras_seeing(people, rig, np.array([False, True])) == {"back"}
    assert cameras_seeing(people, rig, np.array([False, False])) == set()
    # matched in the camera aside although he projects outside its picture
    used = np.array([[-1, -1, 0], [-1, -1, -1]])
    people = type(people)(**{**people.__dict__, "detections": used})
    assert cameras_seeing(people, rig, np.array([True, False])) == {"cam", "aside"}
    assert cameras_seeing(people3d_from_record(0, []), rig, np.zeros(0, bool)) == set()
