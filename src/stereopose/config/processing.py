"""The configuration's reconstruction and tracking sections."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from stereopose.checks import DAY_S
from stereopose.config.fields import _LENGTH_M, Mode, Section, _schema, number
from stereopose.skeleton import NUM_JOINTS


@_schema("reconstruction.association")
@dataclass(frozen=True)
class AssociationConfig(Section):
    """Cross-camera grouping of 2D people.

    Costs are epipolar distances divided by the person's size in the image (dimensionless), so
    near and far people are treated alike.
    """

    # joints below this confidence do not vote
    min_conf: float = number(0.3, ge=0.0, le=1.0)
    # a camera pair needs this many joints confident in both
    min_common_joints: int = number(3, integer=True, ge=1, le=NUM_JOINTS)
    # mean normalised epipolar distance accepted for a match
    max_cost: float = number(0.12, gt=0.0, le=100.0)
    reassign_leftovers: bool = True  # give unmatched detections to a reconstructed person
    # a tracked person's pose reprojected into a camera claims the detection within this mean
    # joint distance, divided by the detection's size
    track_max_cost: float = number(0.25, gt=0.0, le=100.0)
    # robust mode, frame-by-frame calls: the people of the previous frame (and of the few
    # frames before, for people missed since) seed the next frame as a tracked person's
    # predicted pose does, so their association and left/right labels carry over; 0: each
    # frame on its own
    continuity_frames: int = number(3, integer=True, ge=0, le=1000)


@_schema("reconstruction.triangulation")
@dataclass(frozen=True)
class TriangulationConfig(Section):
    """Triangulation of one person's joints from the views of its group."""

    mode: Mode = "robust"
    # joints below this confidence are not used
    min_conf: float = number(0.05, ge=0.0, le=1.0)
    # `pair` mode: weight per pixel of mean epipolar distance
    pair_a: float = number(0.01, ge=0.0, le=1e6)
    # `pair` mode: weight of the mean confidences of the two views
    pair_b: float = number(1.0, ge=0.0, le=1e6)
    # `robust`: reprojection error always accepted, pixels
    inlier_px: float = number(10.0, ge=0.0, le=1e5)
    # `robust`: ... or this fraction of the person's size in the view
    inlier_rel: float = number(0.03, ge=0.0, le=1.0)
    fix_swaps: bool = True  # `robust`: correct left/right labels swapped by the detector
    # `robust`: a joint seen in one view only is placed on that view's ray, at the point nearest
    # a reconstructed neighbouring joint (within one bone length of the truth); views = 1
    single_view: bool = True


@_schema("reconstruction.plausibility")
@dataclass(frozen=True)
class PlausibilityConfig(Section):
    """Rejection of reconstructed people that cannot be real."""

    # fewer joints reconstructed from two views or more: not a person
    min_joints: int = number(5, integer=True, ge=0, le=NUM_JOINTS)
    # lowest joint may be this far below the floor
    floor_tolerance_m: float = number(0.4, ge=0.0, le=_LENGTH_M)
    # vertical extent of a person's joints
    max_height_m: float = number(3.0, gt=0.0, le=_LENGTH_M)
    # a joint making a PCP limb longer than this is dropped
    max_limb_m: float = number(1.0, gt=0.0, le=_LENGTH_M)
    # seen by fewer than this fraction of the cameras that should see them: a ghost
    min_view_fraction: float = number(0.4, ge=0.0, le=1.0)


@_schema("reconstruction")
@dataclass(frozen=True)
class ReconstructionConfig(Section):
    association: AssociationConfig = field(default_factory=AssociationConfig)
    triangulation: TriangulationConfig = field(default_factory=TriangulationConfig)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)


@_schema("tracking")
@dataclass(frozen=True)
class TrackingConfig(Section):
    """Identities over time, online smoothing and positioning of reconstructed people."""

    enabled: bool = True  # false: per-frame people, ids 0..P-1 in each frame (memory "recent")
    # what the 3D stage remembers between frames (tracking.memory): "tracker" (Kalman tracks,
    # persistent ids), "recent" (the last continuity_frames frames seed the next, ids per
    # frame) or "none" (every frame on its own)
    memory: Literal["tracker", "recent", "none"] = "tracker"
    # a person gets an id after this many consecutive frames
    confirm_frames: int = number(3, integer=True, ge=1, le=100_000)
    # gaps up to this long are filled by prediction, flagged predicted
    bridge_s: float = number(0.2, ge=0.0, le=DAY_S)
    # an unseen person's predicted pose is looked for in images this long
    seed_s: float = number(0.4, ge=0.0, le=DAY_S)
    # an unseen person keeps their id this long, then the track ends
    max_lost_s: float = number(3.0, ge=0.0, le=DAY_S)
    # a returning person is this close to where they were last ...
    reid_radius_m: float = number(1.0, ge=0.0, le=_LENGTH_M)
    # ... plus walking at this speed for the time unseen
    reid_speed_mps: float = number(1.5, ge=0.0, le=100.0)
    # a new person this close to a tracked one is the same
    duplicate_radius_m: float = number(0.4, ge=0.0, le=_LENGTH_M)
    smoothing: bool = True  # false: raw per-frame joints (the filter still predicts gaps)
    # constant-velocity model: acceleration density, m^2/s^3 ...
    process_noise: float = number(3.0, gt=0.0, le=1e6)
    # ... times this for elbows and knees, squared for wrists, ankles
    limb_noise_factor: float = number(2.5, gt=0.0, le=1e3)
    # joint noise of a reconstruction from two views
    measurement_noise_m: float = number(0.03, gt=0.0, le=_LENGTH_M)
    # ... of a joint seen in one view (depth from a neighbour)
    single_view_noise_m: float = number(0.15, gt=0.0, le=_LENGTH_M)
    # a joint jumping farther than this from its prediction ...
    gate_m: float = number(0.25, gt=0.0, le=_LENGTH_M)
    # ... and this many standard deviations is not believed
    gate_sigmas: float = number(4.0, gt=0.0, le=1e3)
    # ... unless it stays there this many frames in a row
    gate_reset_frames: int = number(3, integer=True, ge=1, le=100_000)
    bone_lengths: bool = True  # keep each person's limb lengths at their running estimate

    @property
    def ids(self) -> bool:
        """Whether people keep ids over time: the tracker's memory (what zone events and
        two-way smoothing need)."""
        return self.enabled and self.memory == "tracker"
