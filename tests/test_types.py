"""Validated data between stages: cameras, rigs and 2D/3D people."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.errors import CalibrationError, KeypointsError
from stereopose.skeleton import JOINTS, LR_PAIRS, SWAP, joint_index
from stereopose.types import Camera, People2D, People3D, Rig

K = [[1000.0, 0.0, 960.0], [0.0, 1000.0, 540.0], [0.0, 0.0, 1.0]]


def cam(name: str = "c", **kw) -> Camera:
    args = dict(
        size=(1920, 1080),
        matrix=K,
        distortions=[0, 0, 0, 0],
        rotation=[0.1, 0.2, 0.3],
        translation=[0, 0, 4],
    )
    args.update(kw)
    return Camera(name, **args)


def test_camera_derived_matrices() -> None:
    c = cam()
    np.testing.assert_allclose(c.R @ c.R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(c.R @ c.center + c.translation, 0, atol=1e-12)
    np.testing.assert_allclose(c.projection, np.asarray(K) @ c.P)
    assert c.focal == 1000.0
    with pytest.raises(AttributeError):
        c.name = "other"  # frozen


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"matrix": [[0, 0, 1], [0, 1, 1], [0, 0, 1]]}, "focal lengths must be positive"),
        ({"matrix": [[1, 0], [0, 1]]}, r"matrix must have shape \(3, 3\)"),
        ({"distortions": [0, 0, 0]}, "distortions must be"),
        ({"translation": [0, np.nan, 1]}, "NaN or infinite"),
        ({"rotation": np.diag([1.0, 1.0, -1.0])}, "not a rotation matrix"),
        ({"rotation": [[1, 0, 0], [0, 2, 0], [0, 0, 1]]}, "not a rotation matrix"),
        ({"size": (0, 1080)}, "size must be positive"),
        ({"rotation": "x"}, "rotation must be numbers"),
    ],
)
def test_bad_cameras_name_the_camera(kw, message) -> None:
    with pytest.raises(CalibrationError, match=f"^camera 'cam7': .*{message}"):
        cam("cam7", **kw)


def test_rig_names_are_unique_and_indexable() -> None:
    rig = Rig((cam("a"), cam("b")))
    assert rig.names == ("a", "b") and rig["b"].name == "b" and rig.index("b") == 1
    assert rig.subset(["b", "a"]).names == ("b", "a")
    with pytest.raises(CalibrationError, match="repeated: a"):
        Rig((cam("a"), cam("a")))
    with pytest.raises(KeyError, match="no camera named 'z'"):
        rig["z"]


def test_people2d_normalises_missing_joints() -> None:
    kp = np.ones((2, 17, 3))
    kp[0, 3] = [np.nan, 5.0, 0.9]  # NaN coordinate
    kp[1, 4] = [10.0, 10.0, 0.0]  # zero confidence
    kp[1, 5, 2] = 1.7  # confidence above 1
    p = People2D("c", 3, kp)
    assert np.isnan(p.keypoints[0, 3, :2]).all() and p.keypoints[0, 3, 2] == 0
    assert np.isnan(p.keypoints[1, 4, :2]).all()
    assert p.keypoints[1, 5, 2] == 1.0
    assert len(People2D.empty("c", 0)) == 0
    with pytest.raises(KeypointsError, match=r"camera 'c' frame 3: keypoints must have shape"):
        People2D("c", 3, np.ones((2, 16, 3)))
    with pytest.raises(KeypointsError, match="boxes must have shape"):
        People2D("c", 3, np.ones((2, 17, 3)), boxes=np.ones((3, 4)))


def test_people3d_shapes_are_checked() -> None:
    assert len(People3D.empty(0, 4)) == 0
    with pytest.raises(ValueError, match="conf must have shape"):
        People3D(
            0,
            np.zeros((1, 17, 3)),
            np.zeros((2, 17)),
            np.zeros(1),
            np.zeros((1, 17)),
            np.zeros((1, 17)),
            np.zeros((1, 4)),
        )


def test_skeleton_tables() -> None:
    assert len(JOINTS) == 17 and joint_index("right_wrist") == 10
    assert (SWAP[SWAP] == np.arange(17)).all()
    for left, right in LR_PAIRS:
        assert JOINTS[left].startswith("left_") and JOINTS[right] == "right_" + JOINTS[left][5:]
    with pytest.raises(ValueError, match="unknown joint 'elbow'"):
        joint_index("elbow")


def test_event_fields_are_the_events_optional_fields() -> None:
    """EventFields (the keyword arguments of the helpers that make an Event) names exactly
    the Event's fields that have a default, with the same types."""
    import dataclasses
    from typing import ForwardRef

    from stereopose.types import Event, EventFields

    optional = {
        f.name: f.type
        for f in dataclasses.fields(Event)
        if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
    }
    assert EventFields.__annotations__.keys() == optional.keys()
    for name, kind in optional.items():
        hint = EventFields.__annotations__[name]
        assert (hint.__forward_arg__ if isinstance(hint, ForwardRef) else hint) == kind, name
