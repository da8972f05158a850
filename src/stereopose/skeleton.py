"""The COCO-17 skeleton: joint names, limbs and the left/right swap table."""

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

# Bones as (parent, child) joint indices; the ten body limbs used by PCP come first.
LIMBS: tuple[tuple[int, int], ...] = (
    (5, 7),  # left upper arm
    (7, 9),  # left forearm
    (6, 8),  # right upper arm
    (8, 10),  # right forearm
    (11, 13),  # left thigh
    (13, 15),  # left shin
    (12, 14),  # right thigh
    (14, 16),  # right shin
    (5, 11),  # left torso side
    (6, 12),  # right torso side
    (5, 6),  # shoulders
    (11, 12),  # hips
    (0, 1),
    (0, 2),
    (1, 3),
    (2, 4),
)
PCP_LIMBS: tuple[tuple[int, int], ...] = LIMBS[:10]

# (left, right) joint pairs; SWAP[i] is the index of the mirror joint of i.
LR_PAIRS: tuple[tuple[int, int], ...] = (
    (1, 2),
    (3, 4),
    (5, 6),
    (7, 8),
    (9, 10),
    (11, 12),
    (13, 14),
    (15, 16),
)
SWAP: np.ndarray = np.arange(NUM_JOINTS)
for _l, _r in LR_PAIRS:
    SWAP[_l], SWAP[_r] = _r, _l
SWAP.setflags(write=False)

LEFT_HIP, RIGHT_HIP = JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]
LEFT_ANKLE, RIGHT_ANKLE = JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]


def joint_index(name: str) -> int:
    """Index of a COCO-17 joint given its name; raises ValueError naming the valid names."""
    try:
        return JOINT_INDEX[name]
    except KeyError:
        raise ValueError(f"unknown joint {name!r}; expected one of {', '.join(JOINTS)}") from None
