"""The surveyed points of the console (site.http.api.calibration): the rig placed from points of
known site coordinates clicked in the cameras' pictures, while the service runs.

An admin keeps the points file (calibration.surveyed: `[points]` in metres, `[cameras.<name>]`
in pixels) in `<output>/survey/points.toml`, the file `stereopose calibrate points` reads.
`solve()` places every camera from it on the running rig's intrinsics and says each click's
residual, each camera's error and how far it would move; `accept()` hands the solved rig to
the calibration keeper, which applies it at the next step (the 3D stage, the regions, the
calibration's health) and writes it as the corrected calibration beside the original, with its
history. A rig that does not place every running camera is refused: cameras in two world
frames would not see the same people.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from pathlib import Path

from stereopose.calibration.poses import pose_change
from stereopose.calibration.surveyed import (
    PointsResult,
    calibrate_points,
    format_survey,
    read_survey,
    survey_from_doc,
)
from stereopose.errors import CalibrationError
from stereopose.extras import require
from stereopose.io.writing import make_folder, write_private

__all__ = ["SurveyDesk"]

POINTS = Path("survey") / "points.toml"
NAMED = Path(POINTS.name)  # how messages name it: a client learns no folder of the server


class SurveyDesk:
    """See the module. keeper: the running calibration keeper (its rig, `take_rig`)."""

    def __init__(self, keeper, folder: Path) -> None:
        self.keeper, self.path = keeper, Path(folder) / POINTS
        self._lock = threading.Lock()
        self._solved: PointsResult | None = None

    def current(self) -> dict:
        """{"file", "points", "cameras", "solved"}: the points file as JSON (empty tables
        before the first save) and the last solution not yet accepted (None)."""
        with self._lock:
            if not self.path.exists():
                return {"file": None, "points": {}, "cameras": {}, "solved": None}
            survey = read_survey(self.path)
            solved = None if self._solved is None else self._summary(self._solved)
        return {
            "file": str(self.path),
            "points": {k: v.tolist() for k, v in survey.world.items()},
            "cameras": {c: {k: v.tolist() for k, v in t.items()} for c, t in survey.clicks.items()},
            "solved": solved,
        }

    def put(self, doc: object) -> None:
        """The points file from `doc` ({"points", "cameras"}), written atomically; a
        CalibrationError naming the key and the problem changes nothing."""
        survey = survey_from_doc(doc, NAMED)
        unknown = sorted(set(survey.clicks) - set(self.keeper.rig.names))
        if unknown:
            raise CalibrationError(f"{NAMED}: no camera {', '.join(unknown)} in the rig")
        with self._lock:
            make_folder(self.path.parent)
            write_private(self.path, format_survey(survey).encode("utf-8"))
            self._solved = None

    def solve(self) -> dict:
        """Every camera placed from the points file (calibration.surveyed.calibrate_points on
        the running rig's intrinsics): the summary (see `_summary`); CalibrationError naming
        the camera or the point when it cannot be."""
        require("scipy", "calibration", "solving the surveyed points")
        with self._lock:
            if not self.path.exists():
                raise CalibrationError("no surveyed points yet: save them first")
            survey = dataclasses.replace(read_survey(self.path), path=NAMED)
            result = calibrate_points(self.keeper.rig, survey)
            self._solved = result
            return self._summary(result)

    def accept(self, by: str) -> list[str]:
        """The solved rig handed to the keeper (applied at the next step): its cameras.
        LookupError when nothing is solved; CalibrationError when it does not place every
        running camera."""
        with self._lock:
            if self._solved is None:
                raise LookupError("nothing solved: solve the surveyed points first")
            self.keeper.take_rig(self._solved.rig, by)
            names = list(self._solved.rig.names)
            self._solved = None
            return names

    def _summary(self, r: PointsResult) -> dict:
        """Per camera its error and how far it moves from the running pose; every click's
        residual; the clicks left out; warnings (a camera not placed, a point far off)."""
        running = self.keeper.rig
        cameras = {}
        for cam in r.rig:
            turned, moved = (
                pose_change(running[cam.name], cam) if cam.name in running.names else (None, None)
            )
            cameras[cam.name] = {
                "rms_px": round(r.camera_rms_px[cam.name], 2),
                "moved_m": None if moved is None else round(moved, 3),
                "turned_deg": None if turned is None else round(turned, 2),
            }
        return {
            "cameras": cameras,
            "residuals_px": {
                c: {p: round(e, 2) if math.isfinite(e) else None for p, e in res.items()}
                for c, res in r.residuals_px.items()
            },
            "left_out": [{"camera": c, "point": p, "px": round(e, 1)} for c, p, e in r.left_out],
            "unplaced": sorted(set(running.names) - set(r.rig.names)),
            "not_placed": dict(r.unplaced),  # camera -> why, and what would place it
            "warnings": list(r.warnings),
        }
