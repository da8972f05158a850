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
import logging
import math
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from stereopose.calibration.poses import pose_change
from stereopose.calibration.surveyed import (
    PointsResult,
    calibrate_points,
    format_survey,
    read_survey,
    survey_from_doc,
)
from stereopose.errors import CalibrationError, StereoposeError
from stereopose.extras import require
from stereopose.io.writing import make_folder, write_private

if TYPE_CHECKING:
    from stereopose.calibration.surveyed import Survey
    from stereopose.types import Rig

__all__ = ["SolveJob", "SurveyDesk"]

logger = logging.getLogger(__name__)

POINTS = Path("survey") / "points.toml"
NAMED = Path(POINTS.name)  # how messages name it: a client learns no folder of the server


class RigKeeper(Protocol):
    """The running calibration keeper (site.health.calib_keeper.CalibrationKeeper) as the
    desk uses it: its rig now, and a whole new rig handed to it."""

    @property
    def rig(self) -> Rig: ...

    def take_rig(self, rig: Rig, by: str) -> None: ...


@dataclasses.dataclass
class SolveJob:
    """One solve: its number, set `done` once it ended, with its summary or its error."""

    number: int
    done: threading.Event = dataclasses.field(default_factory=threading.Event)
    summary: dict | None = None
    error: str | None = None


class SurveyDesk:
    """See the module. keeper: the running calibration keeper (its rig, `take_rig`)."""

    def __init__(self, keeper: RigKeeper, folder: Path) -> None:
        self.keeper, self.path = keeper, Path(folder) / POINTS
        self._lock = threading.Lock()
        self._solved: PointsResult | None = None
        self._job: SolveJob | None = None

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

    def start(self) -> SolveJob:
        """A solve of the points file (calibration.surveyed.calibrate_points on the running
        rig's intrinsics) begun on a thread of its own, so that no request waits for it; one at
        a time (asked again while one runs: that one). CalibrationError at once when there is
        no file or it cannot be read; the solve's own failure is the job's `error`."""
        require("scipy", "calibration", "solving the surveyed points")
        with self._lock:
            if self._job is not None and not self._job.done.is_set():
                return self._job
            if not self.path.exists():
                raise CalibrationError("no surveyed points yet: save them first")
            survey = dataclasses.replace(read_survey(self.path), path=NAMED)
            job = self._job = SolveJob((self._job.number + 1) if self._job else 1)
        threading.Thread(
            target=self._solve,
            args=(job, survey, self.keeper.rig),
            name="survey-solve",
            daemon=True,
        ).start()
        return job

    def job(self) -> SolveJob | None:
        """The last solve begun (None: none since the start)."""
        with self._lock:
            return self._job

    def solve(self) -> dict:
        """A solve begun and waited for: its summary (see `_summary`); CalibrationError naming
        the camera or the point when none can be placed."""
        job = self.start()
        job.done.wait()
        if job.error is not None:
            raise CalibrationError(job.error)
        assert job.summary is not None
        return job.summary

    def _solve(self, job: SolveJob, survey: Survey, rig: Rig) -> None:
        try:
            result = calibrate_points(rig, survey)
            with self._lock:
                self._solved = result
                job.summary = self._summary(result)
        except StereoposeError as e:  # no camera can be placed, a point far off, ...
            job.error = str(e)
        except Exception as e:  # a solver's own failure: said, never the thread's silent end
            logger.exception("survey: the solve failed")
            job.error = f"the solve failed: {type(e).__name__}"
        finally:
            job.done.set()

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
