"""Who is near a hazard: a person with a joint within an energized, live zone's approach
distance, plus the way a hand can travel before the next look at him.

    hazards = Hazards(site.zones, dead=lambda: states.safe_now())
    near = hazards.near(people.joints, ahead_s=0.05)     # (P,) bool

The detector's shortcuts (detection.carry: a camera's people carried from its last detection
instead of detected) are allowed only where nobody is near: an alarm on an energized zone is
never late for them. The distance is the fences' own (zones.geometry, as the `approach` event
measures it), the reach is the zone's approach margin (`margin_m`, from its voltage or given;
0 for a zone with no approach event: its prism alone), and the margin of motion is
`speed_m_s` (a worker's fast hand, 2 m/s) times `ahead_s`, the time from the pose known to the
step judged. Every joint counts, not only the zone's triggering ones: a body within reach can
put a hand in at the next step, and a hand misread as an elbow is still a hand.

A zone is live unless `dead()` names it: its breakers and earthing switches read dead
(zones.power_state); unknown is live. A zone isolated by a work ticket alone still counts as
live here: the ticket says what the work may touch, not what the breakers read.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence

import numpy as np

from stereopose.zones.geometry import ZoneGeometry
from stereopose.zones.safe import ENERGIZED
from stereopose.zones.zone import Zone

__all__ = ["HAND_SPEED_M_S", "Hazards"]

HAND_SPEED_M_S = 2.0  # a worker's fast hand (a reach, a slip), metres a second


def _no_dead() -> Collection[str]:
    return ()


class Hazards:
    """The site's energized zones as hazards (see the module). zones: the site's zones (the
    energized ones are kept); dead: the names of the zones dead now (called at each `near`;
    None: every energized zone live); speed_m_s: how fast a hand may close in."""

    def __init__(
        self,
        zones: Sequence[Zone],
        dead: Callable[[], Collection[str]] | None = None,
        speed_m_s: float = HAND_SPEED_M_S,
    ) -> None:
        if not speed_m_s >= 0:
            raise ValueError(f"a hand's speed must be >= 0 m/s, got {speed_m_s!r}")
        self.zones = tuple(z for z in zones if z.kind == ENERGIZED)
        self.names = tuple(z.name for z in self.zones)
        self.geometry = ZoneGeometry(self.zones) if self.zones else None
        self.reach = np.array([z.margin_m for z in self.zones], dtype=np.float64)
        self.dead = dead or _no_dead
        self.speed_m_s = float(speed_m_s)

    def __bool__(self) -> bool:
        """Whether the site has an energized zone at all."""
        return bool(self.zones)

    def live(self) -> np.ndarray:
        """(Z,) which of `zones` are live now (not named by `dead`)."""
        dead = set(self.dead())
        return np.array([n not in dead for n in self.names], dtype=bool)

    def near(self, joints: np.ndarray, ahead_s: float) -> np.ndarray:
        """(P,) whether each person, joints (P, 17, 3) metres in the world frame (NaN: not
        reconstructed), has a joint within a live energized zone's approach distance plus
        speed_m_s * ahead_s (seconds >= 0) of it: inside its prism counts as distance 0."""
        J = np.asarray(joints, dtype=np.float64)
        if J.ndim != 3 or J.shape[2] != 3:
            raise ValueError(f"joints must have shape (P, J, 3), got {J.shape}")
        P = J.shape[0]
        if self.geometry is None or P == 0:
            return np.zeros(P, dtype=bool)
        live = self.live()
        if not live.any():
            return np.zeros(P, dtype=bool)
        reach = np.where(live, self.reach + self.speed_m_s * max(float(ahead_s), 0.0), -np.inf)
        # only people whose joints' box comes within reach of a zone's box are measured
        with np.errstate(invalid="ignore"):
            boxes = np.stack([np.fmin.reduce(J, axis=1), np.fmax.reduce(J, axis=1)], axis=1)
        close = self.geometry.near(boxes, np.where(live, reach, 0.0)) & live[None]
        out = np.zeros(P, dtype=bool)
        for p in np.flatnonzero(close.any(axis=1)):
            _, dist = self.geometry.distance(J[p])  # (17, Z), inf for a missing joint
            out[p] = bool((dist <= reach[None]).any())
        return out
