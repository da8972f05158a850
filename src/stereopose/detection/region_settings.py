"""What detection in regions is told (RegionSettings, from the `[detector]` settings) and what
it reports: each camera's figures (CameraRegions) and a run's line of them (describe)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class RegionSettings:
    """imgsz: each region's model input side (a multiple of 32); full_scan_s: each camera's
    whole frame scanned this often, seconds; motion_threshold: grey levels of change that count
    as motion (lower: more sensitive); hold_s: a camera's own person keeps his region this long
    after he was last found; detail: a region's people are seen at least this many times as
    finely as in the whole frame at the detector's imgsz (a region too large for that gives way
    to the whole frame); below 1, large people cost less and their joints are less exact."""

    imgsz: int = 320
    full_scan_s: float = 3.0
    motion_threshold: int = 25
    hold_s: float = 1.0
    detail: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.imgsz, int) or self.imgsz < 64 or self.imgsz % 32:
            raise ValueError(
                f"region imgsz must be a multiple of 32 of at least 64, got {self.imgsz!r}"
            )
        if not self.full_scan_s > 0:
            raise ValueError(f"full_scan_s must be positive, got {self.full_scan_s!r}")
        if not self.hold_s >= 0:
            raise ValueError(f"hold_s must be at least 0, got {self.hold_s!r}")
        if not 0 < self.detail <= 4:
            raise ValueError(f"region detail must be in (0, 4], got {self.detail!r}")


@dataclass
class CameraRegions:
    """One camera's figures: steps detected; regions cut; steps detected whole (regions would
    cost more and see no finer); steps with no inference at all; full scans; model input
    pixels used, and what whole frames at the detector's size would have used; frame pixels cut
    into regions, and the frames' own pixels; people found; newcomers found by motion and by a
    scan (people in no region of a track or of the camera's own people); frames motion looked
    at (none where the camera is detected whole whatever moves)."""

    steps: int = 0
    regions: int = 0
    whole_frames: int = 0
    idle_steps: int = 0
    full_scans: int = 0
    input_px: int = 0
    whole_input_px: int = 0
    crop_px: int = 0
    frame_px: int = 0
    people: int = 0
    found_by_motion: int = 0
    found_by_scan: int = 0
    motion_frames: int = 0

    def as_dict(self) -> dict[str, float | int]:
        out: dict[str, float | int] = asdict(self)
        out["input_share"] = self.input_px / self.whole_input_px if self.whole_input_px else 0.0
        return out


def describe(report: Mapping[str, Mapping[str, float | int]]) -> str:
    """One line of a run's figures by camera (RegionDetector.report()): the share of whole
    frames' model input used, regions per step, scans and newcomers."""
    used = sum(c["input_px"] for c in report.values())
    whole = sum(c["whole_input_px"] for c in report.values())
    per = ", ".join(
        f"{name} {100 * c['input_share']:.0f} % ({c['regions'] / max(c['steps'], 1):.1f} "
        f"regions/step)"
        for name, c in report.items()
    )
    scans = sum(c["full_scans"] for c in report.values())
    motion = sum(c["found_by_motion"] for c in report.values())
    scanned = sum(c["found_by_scan"] for c in report.values())
    share = 100 * used / whole if whole else 0.0
    return (
        f"regions: {share:.0f} % of whole frames' model input ({per}); {scans} full "
        f"scans; newcomers found by motion {motion}, by a scan {scanned}"
    )
