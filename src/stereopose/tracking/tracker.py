"""Persistent identities over time: one `update` per frame, also when nobody is seen.

Each frame:
1. every track's pose is predicted to the frame (constant velocity);
2. the predicted poses of the tracks seen recently seed the reconstruction: each camera's
   detections are matched to them reprojected, and only the detections left over are
   associated across cameras from scratch (see Reconstructor.reconstruct);
3. a person no seed explains is matched on the floor to a track unseen for a while (someone
   back from behind a cabinet or from a camera stall keeps their id); otherwise they start a
   tentative track, which gets an id only after `confirm_frames` consecutive frames (a
   ghost of a frame or two never gets one);
4. measured joints update the per-joint Kalman filters; gaps up to `bridge_s` are bridged by
   prediction (people flagged `predicted`), and a track unseen for `max_lost_s` ends.
"""

from __future__ import annotations

import collections
import logging
from collections.abc import Sequence

import numpy as np

from stereopose.association.assignment import linear_sum_assignment
from stereopose.config import Config
from stereopose.reconstruction import Reconstruction
from stereopose.skeleton import LEFT_HIP, NUM_JOINTS, RIGHT_HIP, joint_index
from stereopose.tracking.bones import BoneLengths
from stereopose.tracking.filter import JointFilters
from stereopose.tracking.ids import IdSource, id_source
from stereopose.tracking.offline import NOT_USED, RESTARTED, TrackLog, smooth_people
from stereopose.tracking.positioning import Trajectory, floor_position
from stereopose.types import People3D, Rig

logger = logging.getLogger(__name__)

# Trajectories of ended tracks kept (the oldest are forgotten beyond this): the tracker's
# memory stays bounded however long it runs.
MAX_ENDED_TRAJECTORIES = 10_000
_PREDICTED_CONF = 0.5  # confidence of a bridged joint, relative to its last measurement


class Tracker:
    """Tracks the people of one camera rig: per frame, in order, `prior` then `update` (the
    memory interface of tracking.memory)."""

    tracking = True

    def __init__(
        self,
        rig: Rig,
        config: Config | None = None,
        record: bool = False,
        first_id: int | IdSource = 1,
    ) -> None:
        """record: keep every track's measurements for `two_way` (offline smoothing): the one
        state that grows with the length of a run, by design (the smoother needs each whole
        track). Without it the tracker holds its live tracks and one trajectory summary per
        person. first_id: the first id given (a restarted service continues above the ids of
        its earlier runs, so that an id never names two people), or the IdSource to take each
        new id from (tracking.ids: a service's ids reserved in its log; a track waits,
        tentative, while the source has none)."""
        self._ids = id_source(first_id)
        self.ids_waited = 0  # frames a confirmed track waited for an id (the source had none)
        self.config = config or Config()
        self.record = record
        self.tc = self.config.tracking
        self.num_cameras = len(rig)
        # hands and feet accelerate hardest (a step, a reach): they get more process noise
        self._q = np.full(NUM_JOINTS, self.tc.process_noise)
        for name in ("elbow", "knee"):
            self._q[[joint_index(f"left_{name}"), joint_index(f"right_{name}")]] *= (
                self.tc.limb_noise_factor
            )
        for name in ("wrist", "ankle"):
            self._q[[joint_index(f"left_{name}"), joint_index(f"right_{name}")]] *= (
                self.tc.limb_noise_factor**2
            )
        self._t: float | None = None
        self._unseen: np.ndarray | None = None  # set by prior, used by update
        self._seed_rows = np.zeros(0, dtype=np.int64)
        self._frame = 0
        self._last_frame = 0  # the last frame not skipped
        self._skipping = False  # prior(self._frame) skipped its frame
        # per track a serial number that never changes; with `record`, its measurements
        self.serial = np.zeros(0, dtype=np.int64)
        self._next_serial = 0
        self.logs: dict[int, TrackLog] = {}
        self._serial_of_id: dict[int, int] = {}
        self.filters = JointFilters.empty()
        self.bones = BoneLengths.empty()
        # per track: id (0 while tentative), consecutive frames seen, time last seen, frame
        # of birth, last measured confidences, per joint the time last measured
        self.ids = np.zeros(0, dtype=np.int64)
        self.hits = np.zeros(0, dtype=np.int64)
        self.seen_t = np.zeros(0)
        self.born = np.zeros(0, dtype=np.int64)
        self.born_t = np.zeros(0)
        self.conf = np.zeros((0, NUM_JOINTS))
        self.joint_t = np.zeros((0, NUM_JOINTS))
        self.trajectories: dict[int, Trajectory] = {}
        self._ended: collections.deque[int] = (
            collections.deque()
        )  # ids of ended tracks, oldest first
        self.trajectories_dropped = 0  # ended trajectories forgotten (MAX_ENDED_TRAJECTORIES)

    def __len__(self) -> int:
        """Number of tracks held, tentative and lost ones included."""
        return int(self.ids.shape[0])

    def prior(self, frame: int, t: float | None = None) -> np.ndarray | None:
        """Every track's pose predicted to `frame`: the poses (T, 17, 3) of the tracks seen
        within seed_s, which seed the frame's reconstruction (None when there are none).

        The time of a frame is t seconds (None: frame / fps; live cameras give their frames'
        arrival time, so prediction and max_lost_s follow the clock). Tracks unseen for more
        than max_lost_s by then end first, however far the frame jumps ahead, so nobody lost
        that long keeps their id. A frame that does not come after the last one is skipped
        with a warning (its `update` gives nobody and changes nothing): the tracks stay as they
        were."""
        tc, fps = self.tc, self.config.fps
        t = frame / fps if t is None else float(t)
        if self._t is not None and not t > self._t:
            logger.warning(
                "frame %d does not come after frame %d: skipped by the tracker",
                frame,
                self._last_frame,
            )
            self._frame, self._skipping, self._unseen = frame, True, None
            return None
        dt = 0.0 if self._t is None else t - self._t
        self._t = t
        self._frame = self._last_frame = frame
        self._skipping = False
        self._end(t - self.seen_t > tc.max_lost_s + 1e-9)
        unseen = t - self.seen_t  # before this frame
        self.filters.predict(dt, self._q, moving=unseen <= tc.bridge_s + 1e-9)
        self._seed_rows = np.flatnonzero(unseen <= tc.seed_s + 1e-9)
        self._unseen = unseen
        return self.filters.x[self._seed_rows] if self._seed_rows.size else None

    def update(self, frame: int, rec: Reconstruction) -> People3D:
        """The tracked people at `frame` (ids persistent, joints smoothed) from its
        reconstruction, seeded by what `prior(frame)` returned."""
        if frame == self._frame and self._skipping:
            self._skipping = False
            return People3D.empty(frame, self.num_cameras)
        if frame != self._frame or self._unseen is None:
            raise ValueError(f"frame {frame}: call prior({frame}) before update")
        t, unseen, seed_rows = self._t, self._unseen, self._seed_rows
        assert t is not None  # prior(frame) set it
        self._unseen = None
        found = rec.people
        row_of = np.full(len(found), -1, dtype=np.int64)
        seeded = rec.seeds >= 0
        row_of[seeded] = seed_rows[rec.seeds[seeded]]
        self._reidentify(found, row_of, unseen)
        keep_person = self._drop_duplicates(found, row_of)
        new = np.flatnonzero((row_of < 0) & keep_person)
        if new.size:
            row_of[new] = self._add(found.joints[new], frame)
            unseen = np.concatenate([unseen, np.full(new.size, np.inf)])
        measured = np.flatnonzero(row_of >= 0)
        rows = row_of[measured]
        self._measure(rows, found, measured, unseen[rows], t)
        out = self._output(frame, t, rows, found, measured)
        self._retire(t, rows)
        return out

    def two_way(self, frames: Sequence[People3D]) -> list[People3D]:
        """The online output `frames` (this tracker's, every frame) with each person's
        joints smoothed both ways over their whole track (see tracking.offline). Needs
        `record`."""
        if not self.record:
            raise ValueError("two-way smoothing needs a Tracker made with record=True")
        logs = {i: self.logs[s] for i, s in self._serial_of_id.items() if s in self.logs}
        return smooth_people(frames, logs, self.config.fps, self._q)

    def finish(self) -> list[Trajectory]:
        """Every person's trajectory (ended and still open), by id; of the ended ones, the
        last MAX_ENDED_TRAJECTORIES (trajectories_dropped counts the ones forgotten)."""
        return [self.trajectories[k] for k in sorted(self.trajectories)]

    # -- steps ---------------------------------------------------------------------------------

    def _reidentify(self, found: People3D, row_of: np.ndarray, unseen: np.ndarray) -> None:
        """Match people no seed explained to tracks not matched this frame, on the floor."""
        tc = self.tc
        todo = np.flatnonzero(row_of < 0)
        if todo.size == 0:
            return
        free = np.setdiff1d(np.arange(len(self)), row_of[row_of >= 0])
        if free.size == 0:
            return
        a = floor_position(found.joints[todo])
        b = floor_position(self.filters.x[free])
        d = np.linalg.norm(a[:, None] - b[None], axis=-1)
        reach = tc.reid_radius_m + tc.reid_speed_mps * np.minimum(unseen[free], tc.max_lost_s)
        d[~(d <= reach[None])] = np.inf  # NaN: no position
        if not np.isfinite(d).any():
            return
        r, k = linear_sum_assignment(np.where(np.isfinite(d), d, 1e9))
        ok = np.isfinite(d[r, k])
        row_of[todo[r[ok]]] = free[k[ok]]

    def _drop_duplicates(self, found: People3D, row_of: np.ndarray) -> np.ndarray:
        """(P,) false for unexplained people standing where a matched track stands: a second
        reconstruction of someone already tracked, not a new person."""
        keep = np.ones(len(found), dtype=bool)
        todo = np.flatnonzero(row_of < 0)
        if todo.size == 0 or not (row_of >= 0).any():
            return keep
        a = floor_position(found.joints[todo])
        b = floor_position(found.joints[row_of >= 0])
        d = np.linalg.norm(a[:, None] - b[None], axis=-1)
        keep[todo[(d <= self.tc.duplicate_radius_m).any(1)]] = False
        return keep

    def _add(self, joints: np.ndarray, frame: int) -> np.ndarray:
        """Start tentative tracks at joints (n, 17, 3); returns their rows."""
        n = joints.shape[0]
        first = len(self)
        self.filters.append(joints, self.tc.measurement_noise_m)
        self.bones.append(n)
        self.ids = np.concatenate([self.ids, np.zeros(n, dtype=np.int64)])
        self.hits = np.concatenate([self.hits, np.zeros(n, dtype=np.int64)])
        self.seen_t = np.concatenate([self.seen_t, np.full(n, -np.inf)])
        self.born = np.concatenate([self.born, np.full(n, frame, dtype=np.int64)])
        self.born_t = np.concatenate([self.born_t, np.full(n, self._t)])
        self.conf = np.concatenate([self.conf, np.zeros((n, NUM_JOINTS))])
        self.joint_t = np.concatenate([self.joint_t, np.full((n, NUM_JOINTS), -np.inf)])
        serial = np.arange(self._next_serial, self._next_serial + n)
        self.serial = np.concatenate([self.serial, serial])
        self._next_serial += n
        return np.arange(first, first + n)

    def _measure(
        self,
        rows: np.ndarray,
        found: People3D,
        measured: np.ndarray,
        unseen: np.ndarray,
        t: float,
    ) -> None:
        """Feed the people measured this frame to their tracks' filters."""
        tc = self.tc
        z = found.joints[measured]
        if rows.size == 0:
            return
        # a joint one camera saw has its depth from a neighbour: where the track measured it
        # lately, its prediction is the better guess (and is what bridges the gap)
        lately = (found.views[measured] == 1) & (self.joint_t[rows] >= t - tc.bridge_s - 1e-9)
        if lately.any():
            z = np.where(lately[..., None], np.nan, z)
        # a track back after a long gap, or new, restarts from the measurement
        fresh = ~(unseen <= tc.bridge_s + 1e-9)
        codes = np.where(np.isfinite(z).all(-1), RESTARTED, NOT_USED).astype(np.int8)
        noise = np.full(codes.shape, tc.measurement_noise_m)
        if fresh.any():
            self.filters.reset(rows[fresh], z[fresh], tc.measurement_noise_m)
        if (~fresh).any():
            noise[~fresh] = self._noise(found, measured[~fresh])
            codes[~fresh] = self.filters.update(
                rows[~fresh],
                z[~fresh],
                noise[~fresh],
                tc.gate_m,
                tc.gate_sigmas,
                tc.gate_reset_frames,
            )
        if self.record:
            for i, r in enumerate(rows):
                log = self.logs.setdefault(int(self.serial[r]), TrackLog())
                log.add(self._frame, z[i], codes[i], noise[i])
        self.bones.observe(rows, z)
        self.hits[rows] += 1
        self.seen_t[rows] = t
        ok = np.isfinite(z).all(-1)
        self.conf[rows] = np.where(ok, found.conf[measured], self.conf[rows])
        self.joint_t[rows] = np.where(ok, t, self.joint_t[rows])

    def _noise(self, found: People3D, people: np.ndarray) -> np.ndarray:
        """(n, 17) measurement noise of the joints of `people`: the configured noise for a
        joint triangulated from two views, less for more views (their errors average out)."""
        views = found.views[people]
        noise = self.tc.measurement_noise_m * np.sqrt(2.0 / np.maximum(views, 2))
        # a joint seen in one view has its depth from a neighbour: off by up to a bone length
        return np.where(views == 1, self.tc.single_view_noise_m, noise)

    def _output(
        self, frame: int, t: float, rows: np.ndarray, found: People3D, measured: np.ndarray
    ) -> People3D:
        """Confirmed tracks seen now or within bridge_s, ordered by id."""
        tc = self.tc
        was = self.ids == 0
        confirm = was & (self.hits >= tc.confirm_frames)
        if confirm.any():
            for r in np.flatnonzero(confirm):
                pid = self._ids.take()
                if pid is None:  # none reserved now: tentative until a later frame
                    self.ids_waited += 1
                    break
                self.ids[r] = pid
                if self.record:  # what two_way needs; nothing kept per person otherwise
                    self._serial_of_id[pid] = int(self.serial[r])
                # the frames it was seen before confirmation count too (this one is added below)
                self.trajectories[pid] = Trajectory(
                    pid,
                    int(self.born[r]),
                    float(self.born_t[r]),
                    frame,
                    t,
                    frames_seen=int(self.hits[r]) - 1,
                )
        alive = (self.ids > 0) & (t - self.seen_t <= tc.bridge_s + 1e-9)
        out_rows = np.flatnonzero(alive)
        out_rows = out_rows[np.argsort(self.ids[out_rows])]
        P = out_rows.size
        person_of = np.full(len(self), -1, dtype=np.int64)
        person_of[rows] = measured
        src = person_of[out_rows]  # person of `found` behind each output row, -1: predicted
        is_meas = src >= 0
        X = self.filters.x[out_rows].copy()
        if not tc.smoothing:
            X[is_meas] = found.joints[src[is_meas]]
        recent = t - self.joint_t[out_rows] <= tc.bridge_s + 1e-9
        X[~recent] = np.nan
        if tc.bone_lengths and tc.smoothing:
            X = self.bones.apply(out_rows, X)
        now = self.joint_t[out_rows] == t
        conf = np.where(now, 1.0, _PREDICTED_CONF) * self.conf[out_rows]
        conf = np.where(np.isfinite(X).all(-1), conf, 0.0)
        reproj = np.full((P, NUM_JOINTS), np.nan)
        views = np.zeros((P, NUM_JOINTS), dtype=np.int64)
        detections = np.full((P, self.num_cameras), -1, dtype=np.int64)
        if is_meas.any():
            reproj[is_meas] = found.reprojection_px[src[is_meas]]
            views[is_meas] = found.views[src[is_meas]]
            if tc.smoothing:
                views[~now] = 0  # bridged by prediction, not measured now
            detections[is_meas] = found.detections[src[is_meas]]
        v = self.filters.v[out_rows]
        velocity = 0.5 * (v[:, LEFT_HIP, :2] + v[:, RIGHT_HIP, :2])
        people = People3D(
            frame=frame,
            joints=X,
            conf=conf,
            ids=self.ids[out_rows],
            reprojection_px=reproj,
            views=views,
            detections=detections,
            predicted=~is_meas,
            velocity=velocity,
        )
        if self.record:  # bridged people: a step without measurements
            none = np.full((NUM_JOINTS, 3), np.nan)
            for r in out_rows[~is_meas]:
                log = self.logs.setdefault(int(self.serial[r]), TrackLog())
                log.add(frame, none, np.zeros(NUM_JOINTS, np.int8), np.ones(NUM_JOINTS))
        pos = floor_position(X).tolist()
        ids = people.ids.tolist()
        for p in np.flatnonzero(is_meas).tolist():
            self.trajectories[ids[p]].add(frame, t, pos[p])
        return people

    def _retire(self, t: float, rows: np.ndarray) -> None:
        """Drop tentative tracks not seen this frame and confirmed ones lost too long."""
        tc = self.tc
        missed = np.ones(len(self), dtype=bool)
        missed[rows] = False
        self.hits[missed] = 0
        self._end(missed & ((self.ids == 0) | (t - self.seen_t > tc.max_lost_s + 1e-9)))

    def _end(self, drop: np.ndarray) -> None:
        """Drop the tracks flagged in `drop` (len(self),); the confirmed ones have ended."""
        if drop.any():
            ended = self.ids[drop & (self.ids > 0)].tolist()
            self._ended.extend(ended)
            while len(self._ended) > MAX_ENDED_TRAJECTORIES:  # a service runs for weeks
                del self.trajectories[self._ended.popleft()]
                self.trajectories_dropped += 1
            keep = ~drop
            self.filters.keep(keep)
            self.bones.keep(keep)
            for name in ("ids", "hits", "seen_t", "born", "born_t", "conf", "joint_t", "serial"):
                setattr(self, name, getattr(self, name)[keep])
