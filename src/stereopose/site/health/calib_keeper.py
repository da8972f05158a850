"""The rig kept calibrated while the service runs: a camera that drifted (calibration_drift) is
placed again from the people the other cameras see, and the new pose applied at a step
boundary.

    keeper = CalibrationKeeper(rig, calib_path, health, apply=[stage.set_rig, ...])
    events += keeper.update(frame, t, people2d, events)   # after the calibration health's

From a camera's `calibration_drift` on, each step with people gives one sample: the people the
other cameras reconstruct (3D) and the camera's own detections (a bounded buffer of `samples`
steps). When it is full, the camera's pose is estimated again (calibration.refine) on a worker
thread, so the frame loop never waits. The new pose is accepted when its reprojection error is
back near the camera's reference (at most `accept_factor` times it, or it + 2 px) over joints
that cover at least `min_coverage` of its view. The reference is the calibrated pose measured
the same way (the others' people against its detections, the RMS over the joints that agree)
on half as many samples as `samples`, taken before any drift (every CALM_EVERY steps; fewer
when the camera drifts first); until it is known, the health's baseline stands in. A pose the
old one fits as well is a false alarm. Then, with `auto` and a change of at most AUTO_MAX_DEG
and AUTO_MAX_M, the new pose is applied at once
(every part given the new rig), a `calibration_corrected` event says the turn and shift,
and the corrected calibration is written beside the original (`<name>.corrected.toml`, never
over it) with a line in its history (`<name>.corrections.jsonl`). Without `auto`, or for a
larger change, it is proposed (`proposals()`) for an admin to accept (`accept(camera)`). A
camera that cannot be corrected stays flagged with the reason (`figures()`), and is tried again
with fresh samples.
"""

from __future__ import annotations

import concurrent.futures
import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from stereopose.calibration.formats import save_calibration
from stereopose.calibration.poses import pose_change
from stereopose.calibration.refine import Refined, pose_error, refine_camera
from stereopose.errors import CalibrationError
from stereopose.reconstruction import Reconstructor
from stereopose.site.handover import Handover
from stereopose.site.health.calib_health import CalibrationHealth
from stereopose.site.health.corrected_calibration import corrected_file
from stereopose.site.health.survey_desk import SurveyDesk
from stereopose.site.health.watch import camera_event
from stereopose.types import Event, People2D, Rig

if TYPE_CHECKING:
    from stereopose.types import Camera

__all__ = ["CalibrationKeeper", "KeeperDesk", "corrected_file"]

logger = logging.getLogger(__name__)

SAMPLES = 150  # steps with people sampled before a camera is placed again
MIN_COVERAGE = 0.25  # share of its view the agreeing joints must cover
ACCEPT_FACTOR = 1.5  # the new error at most this many times the baseline (or baseline + 2 px)
STILL_DEG, STILL_M = 0.1, 0.05  # a pose found this close to the old one is left alone
# the most a pose may change to be applied unasked: a camera knocked on its pole turns a few
# degrees; a larger change (a mirror solve of the people's left and right, or a camera moved
# on purpose) is proposed to an admin, never applied by itself
AUTO_MAX_DEG, AUTO_MAX_M = 15.0, 1.0
MAX_TRIES = 20  # attempts per drift (each on fresh samples), then the camera stays flagged
# a new pose is taken only where the old one, on the same samples, has its error this many
# times larger, or fewer than KEPT times its agreeing joints
BETTER, KEPT = 1.25, 0.8
CALM_EVERY = 2  # before any drift, every this many steps a sample for the camera's reference
MIN_CALM = 10  # calm samples a reference is measured from when the camera drifts first


@dataclass
class _Case:
    """One drifted camera: its samples, the attempt under way, the outcome."""

    samples: deque
    others: Reconstructor  # of the other cameras
    job: concurrent.futures.Future | None = None
    tries: int = 0
    reason: str | None = None
    proposal: Refined | None = None  # awaiting an admin
    accepted_by: str | None = None  # an admin accepted it: applied at the next step


@dataclass(frozen=True)
class KeeperSettings:
    """auto: a new pose is applied by itself (else it waits for an admin); samples: steps
    with people sampled before a camera is placed again; min_coverage: the share of its view
    the agreeing joints must cover; accept_factor: the new error at most this many times the
    reference."""

    auto: bool = True
    samples: int = SAMPLES
    min_coverage: float = MIN_COVERAGE
    accept_factor: float = ACCEPT_FACTOR


class CalibrationKeeper:
    """See the module. apply: callables given the new rig when a pose is applied; out_dir:
    where the files go when the original's folder cannot be written; loaded: the file the rig
    was loaded from (calib_path, or an earlier correction of it)."""

    def __init__(
        self,
        rig: Rig,
        calib_path: str | Path,
        health: CalibrationHealth,
        *,
        apply: Sequence[Callable[[Rig], None]] = (),
        settings: KeeperSettings = KeeperSettings(),
        out_dir: str | Path | None = None,
        wall_start: float | None = None,
        loaded: str | Path | None = None,
    ) -> None:
        self.rig, self.calib_path, self.health = rig, Path(calib_path), health
        self.apply_to = tuple(apply)  # given at construction, never added to
        self.auto, self.samples = bool(settings.auto), int(settings.samples)
        self.min_coverage = float(settings.min_coverage)
        self.accept_factor = float(settings.accept_factor)
        self.out_dir = None if out_dir is None else Path(out_dir)
        self.wall_start = wall_start
        self.cases: dict[str, _Case] = {}
        self._lock = threading.Lock()  # the cases, against the API's threads
        self.corrected: dict[str, int] = {}
        self.written: Path | None = None
        self.loaded = Path(loaded) if loaded is not None else self.calib_path  # the start's file
        self._pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="calib-keeper")
        # per camera, its calibrated pose measured as a new pose is (the others' people against
        # its detections, calibration.refine.pose_error) on samples from before any drift: the
        # error a new pose is judged against (the health's baseline rests on people the camera
        # itself helped to place, and is a median, not an RMS)
        self.references: dict[str, float] = {}
        self._calm: dict[str, _Case] = {}
        self._calm_samples = max(10, self.samples // 2)
        self._steps = 0
        self._new_rig: tuple[Rig, str] | None = None  # a whole rig accepted (take_rig)

    # -- the frame loop's side ---------------------------------------------------------------

    def update(
        self, frame: int, t: float, people2d: Mapping[str, People2D], events: Sequence[Event]
    ) -> list[Event]:
        """The step's samples taken, attempts finished; the events it raises."""
        for e in events:
            if e.type == "calibration_drift" and e.camera in self.rig.names:
                self._open(e.camera)
            elif e.type == "calibration_recovered" and e.camera in self.cases:
                case = self.cases[e.camera]
                if case.proposal is None:  # it came back by itself: nothing to do
                    self._close(e.camera)
        self._steps += 1
        self._reference(people2d)
        with self._lock:
            new, self._new_rig = self._new_rig, None
        out = [] if new is None else self._replace_rig(*new, t, frame)
        for name in list(self.cases):
            case = self.cases[name]
            with self._lock:
                proposal = case.proposal
                by = case.accepted_by if proposal is not None else None
            if by is not None and proposal is not None:  # an admin's acceptance, applied
                # here: at a step boundary
                base = self.health.cameras[name].baseline or self.health.floor_px
                event = self._event("calibration_corrected", name, proposal, base, t, frame)
                assert event.result is not None  # a calibration event's figures
                event.result["accepted_by"] = by
                self._apply(name, proposal)
                out.append(event)
                continue
            if case.job is not None:
                if case.job.done():
                    out += self._judge(name, case, t, frame)
                continue
            if case.proposal is not None or case.reason == "gave up":
                continue
            self._sample(name, case, frame, people2d)
            if len(case.samples) >= self.samples:
                case.tries += 1
                case.job = self._pool.submit(_attempt, self.rig[name], list(case.samples))
                case.samples.clear()
        return out

    def _reference(self, people2d: Mapping[str, People2D]) -> None:
        """Samples for each camera's reference while it has none and is not drifting; the
        reference measured once on the worker when enough are in (or when it drifts first)."""
        for name in self.rig.names:
            calm = self._calm.get(name)
            if name in self.references:
                continue
            if calm is not None and calm.job is not None:
                if calm.job.done():
                    self.references[name] = calm.job.result()[0]
                    del self._calm[name]
                continue
            if name in self.cases:
                continue
            if calm is None:
                others = [n for n in self.rig.names if n != name]
                if len(others) < 2:
                    continue
                rec = Reconstructor(self.rig.subset(others))
                calm = self._calm[name] = _Case(deque(maxlen=self._calm_samples), rec)
            if self._steps % CALM_EVERY == 0:
                self._sample(name, calm, self._steps, people2d)
                if len(calm.samples) >= self._calm_samples:
                    self._measure(name)

    def _measure(self, name: str) -> None:
        """The camera's reference measured on the worker from the calm samples it has."""
        calm = self._calm[name]
        calm.job = self._pool.submit(pose_error, self.rig[name], list(calm.samples))
        calm.samples.clear()

    def _open(self, name: str) -> None:
        if name in self.cases:  # already under way (or proposed): kept
            return
        others = [n for n in self.rig.names if n != name]
        if len(others) < 2:
            logger.warning("camera %s drifted: too few other cameras to place it again", name)
            return
        rec = Reconstructor(self.rig.subset(others))
        calm = self._calm.get(name)
        if calm is not None and calm.job is None and len(calm.samples) >= MIN_CALM:
            self._measure(name)  # drifted before its reference was in: from what there is
        with self._lock:
            self.cases[name] = _Case(deque(maxlen=self.samples), rec)
        logger.warning("camera %s drifted: placing it again from the people the others see", name)

    def _close(self, name: str) -> None:
        with self._lock:
            self.cases.pop(name, None)

    def _sample(self, name: str, case: _Case, frame: int, people2d: Mapping[str, People2D]) -> None:
        own = people2d.get(name)
        if own is None or not len(own.keypoints):
            return
        others = {k: v for k, v in people2d.items() if k != name}
        p3 = case.others(frame, others)
        seen = p3.views.max(axis=1, initial=0) >= 2  # (not the people placed from one view)
        if seen.any():
            case.samples.append((p3.joints[seen], np.asarray(own.keypoints)))

    def _judge(self, name: str, case: _Case, t: float, frame: int) -> list[Event]:
        job, case.job = case.job, None
        assert job is not None  # done: asked only of a case with a job
        try:
            r, (old_px, old_joints) = job.result()
        except CalibrationError as e:
            return self._fail(name, case, str(e))
        except Exception as e:  # a failing attempt never stops the service
            logger.exception("camera %s: placing it again failed", name)
            return self._fail(name, case, f"{type(e).__name__}: {e}")
        # where it was, or its pose fits the samples as well as the new one: a false alarm
        still = r.turned_deg < STILL_DEG and r.moved_m < STILL_M
        if still or (old_joints >= KEPT * r.joints and old_px <= BETTER * r.rms_px):
            logger.info(
                "camera %s: the others' people fit its pose as it is (%.1f px over %d joints; "
                "placed again %.1f px over %d); nothing to correct",
                name,
                old_px,
                old_joints,
                r.rms_px,
                r.joints,
            )
            self._close(name)
            return []
        base = self.health.cameras[name].baseline or self.health.floor_px
        ref = self.references.get(name)
        ref = ref if ref is not None and math.isfinite(ref) else base
        bound = max(self.accept_factor * ref, ref + 2.0)
        if r.rms_px > bound:
            return self._fail(
                name,
                case,
                f"the new pose's error {r.rms_px:.1f} px is above {bound:.1f} px (its "
                f"calibrated pose's was {ref:.1f} px)",
            )
        if r.coverage < self.min_coverage:
            return self._fail(
                name,
                case,
                f"the people covered {100 * r.coverage:.0f}% of its view (at least "
                f"{100 * self.min_coverage:.0f}% needed)",
            )
        large = r.turned_deg > AUTO_MAX_DEG or r.moved_m > AUTO_MAX_M
        if not self.auto or large:
            case.proposal, case.reason = r, None
            logger.warning(
                "camera %s: a new pose is proposed (turned %.2f deg, moved %.2f m, %.1f px%s): "
                "an admin accepts it in the console",
                name,
                r.turned_deg,
                r.moved_m,
                r.rms_px,
                f"; over the {AUTO_MAX_DEG:g} deg or {AUTO_MAX_M:g} m applied unasked"
                if self.auto
                else "",
            )
            return [self._event("calibration_proposed", name, r, base, t, frame)]
        event = self._event("calibration_corrected", name, r, base, t, frame)
        self._apply(name, r)
        return [event]

    def _fail(self, name: str, case: _Case, reason: str) -> list[Event]:
        case.reason = reason if case.tries < MAX_TRIES else "gave up"
        logger.warning("camera %s: not corrected: %s", name, reason)
        return []

    def _event(self, type_: str, name: str, r: Refined, base: float, t: float, frame: int) -> Event:
        old = self.rig[name]
        turn = cv2.Rodrigues(r.camera.R @ old.R.T)[0].ravel()
        result = {
            "turned_deg": round(r.turned_deg, 4),
            "rotation": [round(float(v), 6) for v in turn],  # world frame, Rodrigues
            "moved_m": round(r.moved_m, 4),
            "shift_m": [round(float(v), 4) for v in r.camera.center - old.center],
            "joints": int(r.joints),
            "coverage": round(r.coverage, 3),
        }
        return camera_event(
            type_, name, t, frame, t, reprojection_px=r.rms_px, baseline_px=base, result=result
        )

    # -- applying ------------------------------------------------------------------------------

    def _apply(self, name: str, r: Refined) -> None:
        old = self.rig
        self.rig = Rig(tuple(r.camera if c.name == name else c for c in old))
        for fn in self.apply_to:
            fn(self.rig)
        self.health.set_camera(self.rig, name)
        self._calm.clear()  # the others' people as the new rig places them
        self.corrected[name] = self.corrected.get(name, 0) + 1
        self._close(name)
        self._write(name, old[name], r)

    def take_rig(self, rig: Rig, by: str) -> None:
        """A whole new rig (the surveyed points solved, accepted by an admin; any thread):
        applied at the next step. Every camera of the running rig must be in it."""
        missing = sorted(set(self.rig.names) - set(rig.names))
        if missing:
            raise CalibrationError(f"camera(s) {', '.join(missing)} not placed by the new rig")
        with self._lock:
            self._new_rig = (Rig(tuple(rig[n] for n in self.rig.names)), by)

    def _replace_rig(self, rig: Rig, by: str, t: float, frame: int) -> list[Event]:
        """The new rig applied at this step: each camera as `calibration_corrected` (who
        accepted it, how far it moved), written as the corrected calibration."""
        old, self.rig = self.rig, rig
        for fn in self.apply_to:
            fn(rig)
        self._calm.clear()
        self.references.clear()  # measured again on the new rig
        out = []
        for cam in rig:
            self.health.set_camera(rig, cam.name)
            self._close(cam.name)
            self.corrected[cam.name] = self.corrected.get(cam.name, 0) + 1
            _, moved = pose_change(old[cam.name], cam)
            result = {"accepted_by": by, "from": "surveyed points", "moved_m": round(moved, 3)}
            out.append(camera_event("calibration_corrected", cam.name, t, frame, t, result=result))
        self._write(rig[0].name, old[rig[0].name], None, by)
        return out

    def accept(self, name: str, by: str = "admin") -> bool:
        """An admin's acceptance of a proposed pose (any thread): applied at the next step;
        False when none is proposed."""
        with self._lock:
            case = self.cases.get(name)
            if case is None or case.proposal is None:
                return False
            case.accepted_by = by
            return True

    def proposals(self) -> dict[str, dict]:
        """Per camera with a pose waiting for an admin: its turn, shift and error."""
        with self._lock:
            cases = list(self.cases.items())
        return {
            n: {
                "turned_deg": p.turned_deg,
                "moved_m": p.moved_m,
                "reprojection_px": p.rms_px,
                "accepted_by": c.accepted_by,
            }
            for n, c in cases
            if (p := c.proposal) is not None
        }

    def _write(self, name: str, old: Camera, r: Refined | None, by: str | None = None) -> None:
        """The corrected calibration beside the original (or in out_dir) and its history; r:
        the camera's new pose (calibration.refine), None for a whole rig accepted by `by`."""
        stem = self.calib_path.name.split(".")[0] or "calibration"
        places = [self.calib_path.parent] + ([self.out_dir] if self.out_dir is not None else [])
        new = self.rig[name]
        line = {
            "wall_time": time.time(),
            "camera": name if r is not None else "all (surveyed points)",
            **({} if r is None else {"turned_deg": r.turned_deg, "moved_m": r.moved_m}),
            **({"accepted_by": by} if r is None else {"reprojection_px": r.rms_px}),
            "from": {"rotation": old.rotation.tolist(), "translation": old.translation.tolist()},
            "to": {"rotation": new.rotation.tolist(), "translation": new.translation.tolist()},
        }
        for folder in places:
            path = folder / f"{stem}.corrected.toml"
            try:
                meta = {"corrected_from": str(self.calib_path), "camera": name}
                save_calibration(path, self.rig, meta)
                with open(folder / f"{stem}.corrections.jsonl", "a", encoding="utf-8") as f:
                    f.write(json.dumps({**line, "file": str(path)}) + "\n")
            except OSError as e:
                logger.error("%s: cannot write the corrected calibration: %s", path, e.strerror)
                continue
            self.written = path
            logger.warning("camera %s corrected: the calibration is written to %s", name, path)
            return

    # -- health, close -------------------------------------------------------------------------

    def figures(self) -> dict:
        """Per camera being placed again: samples, attempts, the reason it is not corrected,
        a proposal waiting; the corrections made; the corrected file."""
        with self._lock:
            cases = list(self.cases.items())
        return {
            "auto": self.auto,
            "cameras": {
                n: {
                    "samples": len(c.samples),
                    "tries": c.tries,
                    "working": c.job is not None,
                    "reason": c.reason,
                    "proposed": c.proposal is not None,
                }
                for n, c in cases
            },
            "corrected": dict(self.corrected),
            "reference_px": {n: round(v, 2) for n, v in self.references.items()},
            "file": None if self.written is None else str(self.written),
            "loaded": str(self.loaded),
        }

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


def _attempt(cam: Camera, samples: list[tuple[np.ndarray, np.ndarray]]) -> tuple:
    """The camera placed again from the samples (calibration.refine), and its pose as it is
    measured on the same samples (RMS px, agreeing joints)."""
    return refine_camera(cam, samples), pose_error(cam, samples)


class KeeperDesk(Handover[CalibrationKeeper]):
    """How the HTTP API reaches the keeper: made with the app, the keeper attached once the
    frame loop runs (None until then: the API answers 503; site.handover)."""

    def __init__(self) -> None:
        super().__init__()
        self._survey: SurveyDesk | None = None
        self._survey_lock = threading.Lock()

    @property
    def keeper(self) -> CalibrationKeeper | None:
        """The running keeper (None: not yet, or closed)."""
        return self.current

    @property
    def survey(self) -> SurveyDesk | None:
        """The surveyed points' desk over the running keeper (None until it runs): its file in
        the service's output folder (or beside the calibration)."""
        k = self.keeper
        with self._survey_lock:
            if k is not None and (self._survey is None or self._survey.keeper is not k):
                self._survey = SurveyDesk(k, k.out_dir or k.calib_path.parent)
            return None if k is None else self._survey
