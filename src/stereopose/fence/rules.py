"""Zone rules over tracked people: enter, exit, approach, dwell, left_work_area.

Per person and zone, the raw condition of each frame (a triggering joint inside the prism; or,
for `approach`, within `margin_m` of an energized zone without being inside) is debounced: a
zone is entered once the raw condition has held for `enter_s` and left once it has been false
for `exit_s`, so a detection flickering for a frame neither opens nor closes it. Everything is
online: an event is raised at the frame its debounce completes, and carries the time its
condition began (onset_t). People not output in a frame (unseen) keep their state; a person
unseen for `lost_s` while inside a zone gets an `exit` marked lost.

The state is kept in (people x zones) arrays, so the cost per frame hardly grows with zones.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from stereopose.fence.site import Site
from stereopose.skeleton import JOINTS, NUM_JOINTS, floor_position
from stereopose.types import Event, People3D
from stereopose.zones import ZoneGeometry
from stereopose.zones.debounce import TIME_EPS, Debounced


@dataclass
class _Geometry:
    """One frame's people against the zones: inside (P, Z) and distance (P, Z, metres) of
    their triggering joints; pair (P, Z) row of the tested (person, zone) pairs (-1: not
    tested, far apart) in joint_inside and joint_distance (K, 17)."""

    inside: np.ndarray
    distance: np.ndarray
    pair: np.ndarray
    joint_inside: np.ndarray | None = None
    joint_distance: np.ndarray | None = None


@dataclass
class _Step:
    """One frame through the debouncers, (P, Z) per person row and zone: rose, fell (inside
    turned on or off), onset (when), began (since when inside); dwell and near_rose (the
    approach turned on) with near_onset, None when no zone needs them."""

    people: People3D
    t: float
    geo: _Geometry
    pos: np.ndarray
    rose: np.ndarray
    fell: np.ndarray
    onset: np.ndarray
    began: np.ndarray
    dwell: np.ndarray | None
    near_rose: np.ndarray | None
    near_onset: np.ndarray | None


class FenceMonitor:
    """Turns tracked people, frame by frame, into zone events. `update` once per frame."""

    def __init__(self, site: Site, fps: float, lost_s: float = 3.0) -> None:
        self.site = site
        self.zones = site.zones
        self.fps = float(fps)
        self.lost_s = float(lost_s)
        self.geometry = ZoneGeometry(self.zones)
        Z = len(self.zones)
        self.mask = np.zeros((NUM_JOINTS, Z), dtype=bool)  # triggering joints per zone
        for k, z in enumerate(self.zones):
            self.mask[list(z.joints), k] = True
        on = np.array([z.enter_s for z in self.zones])
        off = np.array([z.exit_s for z in self.zones])
        self.margin = np.array([z.margin_m if z.kind == "energized" else 0.0 for z in self.zones])
        self.dwell = np.array([z.dwell_s if z.dwell_s else np.inf for z in self.zones])
        self.any_dwell = bool(np.isfinite(self.dwell).any())
        self.needs_distance = bool((self.margin > 0).any())
        self.inside = Debounced(on, off)
        self.near = Debounced(on, off)
        self.dwelt = np.zeros((0, Z), dtype=bool)
        self.off = np.zeros(Z, dtype=bool)  # zones switched off (switch): no events of theirs
        self.row_of: dict[int, int] = {}
        self._last_ids: tuple[np.ndarray, np.ndarray] | None = None
        self.ids = np.zeros(0, dtype=np.int64)
        self.last_seen = np.zeros(0)
        self.last_pos = np.zeros((0, 2))

    def carry(self, old: FenceMonitor) -> None:
        """A new site's monitor (none of its people seen yet) given what `old` knew: every
        person, and who is inside, near or dwelling in each zone kept as it was (the same
        name, kind, prism, joints, margin and debounce), so that a site change raises no
        event of its own for them."""
        n = len(old.ids)
        self.ids, self.row_of = old.ids.copy(), dict(old.row_of)
        self.last_seen, self.last_pos = old.last_seen.copy(), old.last_pos.copy()
        self.inside.add_rows(n)
        self.near.add_rows(n)
        self.dwelt = np.zeros((n, len(self.zones)), dtype=bool)
        before = {z.name: j for j, z in enumerate(old.zones)}
        for k, z in enumerate(self.zones):
            j = before.get(z.name)
            if j is None or not z.tests_alike(old.zones[j]):
                continue
            for mine, theirs in ((self.inside, old.inside), (self.near, old.near)):
                mine.state[:, k] = theirs.state[:, j]
                mine.since[:, k] = theirs.since[:, j]
                mine.began[:, k] = theirs.began[:, j]
            self.dwelt[:, k] = old.dwelt[:, j]
        for k, z in enumerate(self.zones):  # a zone switched off stays so
            j = before.get(z.name)
            self.off[k] = j is not None and bool(old.off[j])
        self._last_ids = None

    def switch(self, zone: str, on: bool) -> bool:
        """Switch `zone` off (no event of its own from then on; who is inside or near it is
        forgotten: the caller raises their exits first, from `occupants`) or on again (people
        in it enter as newcomers, after its debounce). Whether it changed; False for a zone
        this site does not have."""
        k = next((i for i, z in enumerate(self.zones) if z.name == zone), None)
        if k is None or bool(self.off[k]) != on:
            return False
        self.off[k] = not on
        if not on:
            for d in (self.inside, self.near):
                d.state[:, k], d.since[:, k], d.began[:, k] = False, np.nan, np.nan
            self.dwelt[:, k] = False
        return True

    def _rows(self, ids: np.ndarray) -> np.ndarray:
        """State rows of people `ids`, new people added."""
        if self._last_ids is not None and np.array_equal(ids, self._last_ids[0]):
            return self._last_ids[1]  # the same people as last frame, as usual
        new = [int(i) for i in ids if int(i) not in self.row_of]
        if new:
            for i in new:
                self.row_of[i] = len(self.ids)
                self.ids = np.append(self.ids, i)
            n = len(new)
            self.inside.add_rows(n)
            self.near.add_rows(n)
            self.dwelt = np.concatenate([self.dwelt, np.zeros((n, len(self.zones)), bool)])
            self.last_seen = np.append(self.last_seen, np.full(n, np.nan))
            self.last_pos = np.concatenate([self.last_pos, np.full((n, 2), np.nan)])
        rows = np.array([self.row_of[int(i)] for i in ids], dtype=np.int64)
        self._last_ids = (ids.copy(), rows)
        return rows

    def occupants(
        self, zone: str
    ) -> tuple[list[tuple[int, np.ndarray]], list[tuple[int, np.ndarray]]]:
        """([(person id, floor point)] inside `zone` now, [...] within its approach margin and
        not inside), as the debounced states hold them."""
        k = next((i for i, z in enumerate(self.zones) if z.name == zone), None)
        if k is None or not len(self.ids):
            return [], []
        inside = self.inside.state[:, k]
        near = self.near.state[:, k] & ~inside
        return (
            [(int(self.ids[r]), self.last_pos[r]) for r in np.flatnonzero(inside)],
            [(int(self.ids[r]), self.last_pos[r]) for r in np.flatnonzero(near)],
        )

    def update(self, people: People3D) -> list[Event]:
        """Events raised at this frame (usually none), at its time (People3D.time: live
        cameras stamp their arrival time; frame / fps otherwise). A person the tracker only
        predicts (no camera saw him this frame) changes nothing: no alarm rests on a predicted
        position alone, and whoever was inside stays so until seen again or lost."""
        t = people.time(self.fps)
        events: list[Event] = []
        if people.predicted is not None and people.predicted.any():
            people = people.where(~people.predicted)
        if len(people):
            rows = self._rows(people.ids)
            geo = self._geometry(people.joints)
            raw_in = geo.inside & ~self.off
            pos = floor_position(people.joints)
            self.last_seen[rows] = t
            self.last_pos[rows] = pos
            rose, fell, onset = self.inside.step(rows, raw_in, t)
            began = self.inside.began[rows]
            dwell = None
            if self.any_dwell:
                self.dwelt[rows] &= self.inside.state[rows]  # re-armed by leaving
                dwell = (
                    self.inside.state[rows]
                    & ~self.dwelt[rows]
                    & (t - began >= self.dwell - TIME_EPS)
                )
                self.dwelt[rows] |= dwell
            near_rose = near_onset = None
            if self.needs_distance:
                raw_near = ~raw_in & (geo.distance <= self.margin) & ~self.off
                near_rose, _, near_onset = self.near.step(rows, raw_near, t)
            fired = rose | fell
            for extra in (dwell, near_rose):
                if extra is not None:
                    fired |= extra
            if fired.any():
                if onset is None:  # none went in or out: only a dwell or an approach
                    onset = np.full(rose.shape, np.nan)
                step = _Step(
                    people, t, geo, pos, rose, fell, onset, began, dwell, near_rose, near_onset
                )
                for p, k in zip(*np.nonzero(fired), strict=True):
                    events.extend(self._events(step, p, k))
        events.extend(self._lost(t, people.frame))
        return events

    def _geometry(self, joints: np.ndarray) -> _Geometry:
        """Which triggering joints are inside or near which zones. Only people whose box
        comes near a zone's box are tested joint by joint."""
        P, Z = joints.shape[0], len(self.zones)
        geo = _Geometry(
            np.zeros((P, Z), dtype=bool), np.full((P, Z), np.inf), np.full((P, Z), -1, np.int64)
        )
        # fmin/fmax skip NaN joints; a person with no joint gets a NaN box, near nothing
        boxes = np.stack([np.fmin.reduce(joints, axis=1), np.fmax.reduce(joints, axis=1)], axis=1)
        near = self.geometry.near(boxes, self.margin)  # NaN boxes compare False
        ps, zs = np.nonzero(near)
        if ps.size == 0:
            return geo
        ins, d = self.geometry.test(joints[ps], zs)  # (K, 17) per near (person, zone) pair
        mask = self.mask[:, zs].T  # (K, 17)
        geo.joint_inside = ins & mask
        geo.joint_distance = np.where(mask, d, np.inf)
        geo.inside[ps, zs] = geo.joint_inside.any(1)
        geo.distance[ps, zs] = geo.joint_distance.min(1)
        geo.pair[ps, zs] = np.arange(ps.size)
        return geo

    def _events(self, step: _Step, p: int, k: int) -> list[Event]:
        """The events of person row p in zone k at this step."""
        people, t, geo, pos, onset, began = (
            step.people,
            step.t,
            step.geo,
            step.pos,
            step.onset,
            step.began,
        )
        rose, fell, dwell, near_rose, near_onset = (
            step.rose,
            step.fell,
            step.dwell,
            step.near_rose,
            step.near_onset,
        )
        zone = self.zones[k]
        pid = int(people.ids[p])
        event = partial(
            Event,
            t=t,
            frame=people.frame,
            person=pid,
            zone=zone.name,
            kind=zone.kind,
            position=(float(pos[p, 0]), float(pos[p, 1])) if np.isfinite(pos[p]).all() else None,
            allowed=pid in zone.allowed,
        )
        out = []
        pair = geo.pair[p, k]
        if rose[p, k]:
            assert geo.joint_inside is not None  # inside: its joints were tested
            j = int(np.argmax(geo.joint_inside[pair]))
            out.append(event(type="enter", onset_t=float(onset[p, k]), joint=JOINTS[j]))
        if fell[p, k]:
            stay = float(onset[p, k] - began[p, k]) if np.isfinite(began[p, k]) else None
            out.append(event(type="exit", onset_t=float(onset[p, k]), duration_s=stay))
            if pid in zone.expected:
                out.append(
                    event(type="left_work_area", onset_t=float(onset[p, k]), duration_s=stay)
                )
        if dwell is not None and dwell[p, k]:
            out.append(
                event(type="dwell", onset_t=float(began[p, k]), duration_s=float(t - began[p, k]))
            )
        if near_rose is not None and near_rose[p, k]:
            assert near_onset is not None and geo.joint_distance is not None  # near: tested
            j = int(np.argmin(geo.joint_distance[pair]))
            out.append(
                event(
                    type="approach",
                    onset_t=float(near_onset[p, k]),
                    joint=JOINTS[j],
                    distance_m=float(geo.joint_distance[pair, j]),
                )
            )
        return out

    def _lost(self, t: float, frame: int) -> list[Event]:
        """Exit events for people unseen for lost_s while inside; their state is dropped."""
        gone = t - self.last_seen > self.lost_s + TIME_EPS
        if not gone.any():
            return []
        out = []
        for r in np.flatnonzero(gone):
            pid = int(self.ids[r])
            for k in np.flatnonzero(self.inside.state[r]):
                zone = self.zones[k]
                began = self.inside.began[r, k]
                pos = self.last_pos[r]
                out.append(
                    Event(
                        t=t,
                        frame=frame,
                        person=pid,
                        zone=zone.name,
                        kind=zone.kind,
                        type="exit",
                        onset_t=float(self.last_seen[r]),
                        duration_s=float(self.last_seen[r] - began) if np.isfinite(began) else None,
                        position=(float(pos[0]), float(pos[1])) if np.isfinite(pos).all() else None,
                        allowed=pid in zone.allowed,
                        lost=True,
                    )
                )
        keep = ~gone
        self.inside.keep(keep)
        self.near.keep(keep)
        self.dwelt = self.dwelt[keep]
        self.ids, self.last_seen, self.last_pos = (
            self.ids[keep],
            self.last_seen[keep],
            self.last_pos[keep],
        )
        self.row_of = {int(i): r for r, i in enumerate(self.ids)}
        self._last_ids = None
        return out
