"""The COCO-17 skeleton: joint names, limbs, the left/right tables, and body geometry.

Every table is written with joint names; the indices other modules use come from here.
"""

from __future__ import annotations

import numpy as np

JOINTS: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)
NUM_JOINTS = len(JOINTS)
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINTS)}


def joint_index(name: str) -> int:
    """Index of a COCO-17 joint given its name; raises ValueError naming the valid names."""
    try:
        return JOINT_INDEX[name]
    except KeyError:
        raise ValueError(f"unknown joint {name!r}; expected one of {', '.join(JOINTS)}") from None


def _pairs(*names: tuple[str, str]) -> tuple[tuple[int, int], ...]:
    return tuple((JOINT_INDEX[a], JOINT_INDEX[b]) for a, b in names)


def joint_table(*rows: tuple[str, ...]) -> np.ndarray:
    """(R, K) int64 table of joint indices from rows of K joint names."""
    return np.array([[JOINT_INDEX[name] for name in row] for row in rows], dtype=np.int64)


NOSE = JOINT_INDEX["nose"]
LEFT_EYE, RIGHT_EYE = JOINT_INDEX["left_eye"], JOINT_INDEX["right_eye"]
LEFT_EAR, RIGHT_EAR = JOINT_INDEX["left_ear"], JOINT_INDEX["right_ear"]
LEFT_SHOULDER, RIGHT_SHOULDER = JOINT_INDEX["left_shoulder"], JOINT_INDEX["right_shoulder"]
LEFT_ELBOW, RIGHT_ELBOW = JOINT_INDEX["left_elbow"], JOINT_INDEX["right_elbow"]
LEFT_WRIST, RIGHT_WRIST = JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"]
LEFT_HIP, RIGHT_HIP = JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]
LEFT_KNEE, RIGHT_KNEE = JOINT_INDEX["left_knee"], JOINT_INDEX["right_knee"]
LEFT_ANKLE, RIGHT_ANKLE = JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]
FACE: tuple[int, ...] = (NOSE, LEFT_EYE, RIGHT_EYE)

# Bones as (parent, child) joint indices; the ten body limbs used by PCP come first.
LIMBS: tuple[tuple[int, int], ...] = _pairs(
    ("left_shoulder", "left_elbow"),  # upper arms, forearms
    ("left_elbow", "left_wrist"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("left_hip", "left_knee"),  # thighs, shins
    ("left_knee", "left_ankle"),
    ("right_hip", "right_knee"),
    ("right_knee", "right_ankle"),
    ("left_shoulder", "left_hip"),  # torso sides
    ("right_shoulder", "right_hip"),
    ("left_shoulder", "right_shoulder"),
    ("left_hip", "right_hip"),
    ("nose", "left_eye"),
    ("nose", "right_eye"),
    ("left_eye", "left_ear"),
    ("right_eye", "right_ear"),
)
PCP_LIMBS: tuple[tuple[int, int], ...] = LIMBS[:10]

# (left, right) joint pairs; SWAP[i] is the index of the mirror joint of i.
LR_PAIRS: tuple[tuple[int, int], ...] = _pairs(
    ("left_eye", "right_eye"),
    ("left_ear", "right_ear"),
    ("left_shoulder", "right_shoulder"),
    ("left_elbow", "right_elbow"),
    ("left_wrist", "right_wrist"),
    ("left_hip", "right_hip"),
    ("left_knee", "right_knee"),
    ("left_ankle", "right_ankle"),
)
LEFT = np.array([a for a, _ in LR_PAIRS])
RIGHT = np.array([b for _, b in LR_PAIRS])
SWAP: np.ndarray = np.arange(NUM_JOINTS)
SWAP[LEFT], SWAP[RIGHT] = RIGHT, LEFT
for _a in (LEFT, RIGHT, SWAP):
    _a.setflags(write=False)

# Detectors swap the whole body or the legs alone, so left/right labels are decided for two
# body parts apart: 0, the face, arms and hips; 1, the legs (knees and ankles).
PARTS: tuple[str, ...] = ("upper", "legs")
_LEGS = {LEFT_KNEE, RIGHT_KNEE, LEFT_ANKLE, RIGHT_ANKLE}
PART_OF_PAIR = np.array([int(a in _LEGS) for a, _ in LR_PAIRS])  # (8,) part of each pair
JOINT_PARTS = np.zeros((NUM_JOINTS, len(PARTS)))  # (17, 2) 1 where j is a side joint of p
JOINT_PARTS[LEFT, PART_OF_PAIR] = JOINT_PARTS[RIGHT, PART_OF_PAIR] = 1.0
PART_OF_JOINT = np.full(NUM_JOINTS, len(PARTS))  # (17,) part of each side joint; len(PARTS): none
PART_OF_JOINT[LEFT] = PART_OF_JOINT[RIGHT] = PART_OF_PAIR
for _a in (PART_OF_PAIR, JOINT_PARTS, PART_OF_JOINT):
    _a.setflags(write=False)


def floor_position(joints: np.ndarray) -> np.ndarray:
    """Where people stand on the floor: (P, 17, 3) joints (metres, world) -> (P, 2) x-y of the
    mid-hip point, or the mean x-y of the joints known without both hips (NaN: none)."""
    J = np.asarray(joints, dtype=np.float64)
    if J.ndim != 3 or J.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(f"joints must have shape (P, {NUM_JOINTS}, 3), got {J.shape}")
    xy = J[..., :2]
    mid = 0.5 * (xy[:, LEFT_HIP] + xy[:, RIGHT_HIP])
    hips = np.asarray(np.isfinite(mid).all(-1))
    if hips.all():
        return mid
    known = np.isfinite(xy).all(-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(known, xy, 0.0).sum(1) / known.sum(1)
    return np.where(hips[:, None], mid, mean)


def heading_deg(joints: np.ndarray) -> np.ndarray:
    """(P, 17, 3) joints -> (P,) direction the body faces on the floor, degrees
    counter-clockwise from world +x (NaN when neither shoulders nor hips are known).

    The front is up x (right - left) of the shoulders, or of the hips without shoulders.
    """
    right = joints[:, RIGHT_SHOULDER, :2] - joints[:, LEFT_SHOULDER, :2]
    hips = joints[:, RIGHT_HIP, :2] - joints[:, LEFT_HIP, :2]
    right = np.where(np.isfinite(right).all(-1, keepdims=True), right, hips)
    return np.degrees(np.arctan2(right[:, 0], -right[:, 1]))
