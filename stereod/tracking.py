"""Associate 3D observations over time into tracks and derive their motion (eq. 21-23).

This is the nearest-neighbour association the paper implies: each observation joins the track
whose predicted position is nearest, within a gate (m); an unmatched observation starts a track;
a track unseen for ``max_coast_s`` ends. Velocity comes from :mod:`stereod.motion` over the last
``time_base_s`` seconds of the track. All times are seconds from timestamps, never frame counts.
"""

from __future__ import annotations

import collections
import enum
from dataclasses import dataclass, field

import numpy as np

from . import motion


class TrackLifecycle(str, enum.Enum):
    """Where a track is in its life."""

    TENTATIVE = "tentative"
    """Seen fewer than ``confirm_hits`` times: may be noise."""
    CONFIRMED = "confirmed"
    """Seen often enough to be a real object."""


@dataclass(frozen=True, slots=True)
class Observation:
    """One object triangulated from one stereo pair.

    ``position_m`` (3,) rig frame; ``cov_m2`` (3, 3); ``left_px``/``right_px`` (2,) centroids;
    ``left_bbox_px``/``right_bbox_px`` (4,) x, y, w, h; areas in px; ``disparity_px``;
    ``size_m`` the blob's width in metres (bbox width x Z / f).
    """

    position_m: np.ndarray
    cov_m2: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    left_bbox_px: np.ndarray
    right_bbox_px: np.ndarray
    left_area_px: int
    right_area_px: int
    disparity_px: float
    size_m: float


@dataclass(frozen=True, slots=True)
class TrackerParams:
    """``gate_m``: largest distance (m) from a track's predicted position to join it.
    ``time_base_s``: tau of eq. 21 (s), the span velocity is measured over.
    ``max_coast_s``: how long (s) a track lives unseen. ``confirm_hits``: observations to confirm.
    """

    gate_m: float = 0.35
    time_base_s: float = 0.5
    max_coast_s: float = 0.5
    confirm_hits: int = 3


@dataclass(frozen=True, slots=True)
class TrackState:
    """A track's state at one instant, everything in SI units (m, m/s, deg, s)."""

    track_id: int
    lifecycle: TrackLifecycle
    t_ns: int
    observation: Observation
    velocity_mps: np.ndarray
    velocity_sigma_mps: np.ndarray
    velocity_valid: bool
    speed_mps: float
    speed_sigma_mps: float
    heading_deg: float
    heading_sigma_deg: float
    raw_velocity_mps: np.ndarray | None
    age_s: float


@dataclass
class _Track:
    track_id: int
    first_t_ns: int
    hits: int = 0
    last_seen_ns: int = 0
    history: collections.deque[tuple[int, Observation]] = field(default_factory=collections.deque)
    velocity: np.ndarray | None = None

    @property
    def last(self) -> Observation:
        return self.history[-1][1]


class Tracker:
    """Nearest-neighbour tracker with eq. 21-23 motion; call :meth:`update` once per pair."""

    def __init__(self, params: TrackerParams) -> None:
        self.params = params
        self._tracks: dict[int, _Track] = {}
        self._next_id = 1

    def live_ids(self) -> list[int]:
        return list(self._tracks)

    def update(
        self, t_ns: int, observations: list[Observation]
    ) -> tuple[list[TrackState], list[int]]:
        """Associate one pair's observations at ``t_ns``; return current states and ended ids."""
        p = self.params
        tracks = list(self._tracks.values())
        assigned: dict[int, _Track] = {}
        if tracks and observations:
            pred = np.array([self._predict(tr, t_ns) for tr in tracks])
            obs = np.array([o.position_m for o in observations])
            dist = np.linalg.norm(obs[:, None, :] - pred[None, :, :], axis=2)
            used_t: set[int] = set()
            for flat in np.argsort(dist, axis=None):
                i, j = divmod(int(flat), len(tracks))
                if dist[i, j] > p.gate_m:
                    break
                if i in assigned or j in used_t:
                    continue
                assigned[i] = tracks[j]
                used_t.add(j)
        states: list[TrackState] = []
        for i, ob in enumerate(observations):
            tr = assigned.get(i)
            if tr is None:
                tr = _Track(self._next_id, first_t_ns=t_ns)
                self._next_id += 1
                self._tracks[tr.track_id] = tr
            states.append(self._observe(tr, t_ns, ob))
        seen = {s.track_id for s in states}
        ended = []
        coast_ns = int(p.max_coast_s * 1e9)
        for tid, tr in list(self._tracks.items()):
            if tid not in seen and t_ns - tr.last_seen_ns > coast_ns:
                ended.append(tid)
                del self._tracks[tid]
        return states, ended

    def end_all(self) -> list[int]:
        """End every live track (end of input); return their ids."""
        ids = list(self._tracks)
        self._tracks.clear()
        return ids

    def _predict(self, tr: _Track, t_ns: int) -> np.ndarray:
        last_t, last = tr.history[-1]
        if tr.velocity is None:
            return last.position_m
        return last.position_m + tr.velocity * ((t_ns - last_t) * 1e-9)

    def _observe(self, tr: _Track, t_ns: int, ob: Observation) -> TrackState:
        p = self.params
        tr.history.append((t_ns, ob))
        tr.hits += 1
        tr.last_seen_ns = t_ns
        base_ns = int(p.time_base_s * 1e9)
        # Keep the newest sample at least tau old (eq. 21's p1) and everything after it.
        while len(tr.history) > 2 and t_ns - tr.history[1][0] >= base_ns:
            tr.history.popleft()
        t0 = tr.history[0][0]
        span_ns = t_ns - t0
        raw = None
        valid = False
        if len(tr.history) >= 2:
            times = np.array([(t - t0) * 1e-9 for t, _ in tr.history])
            pos = np.array([o.position_m for _, o in tr.history])
            sig = np.array([np.sqrt(np.diag(o.cov_m2)) for _, o in tr.history])
            vel, vsig = motion.fit_velocity(times, pos, sig)
            tr.velocity = vel
            if span_ns >= base_ns:
                raw = motion.finite_difference(pos[0], pos[-1], span_ns * 1e-9)
                valid = len(tr.history) >= 3
        else:
            vel, vsig = np.zeros(3), np.full(3, np.inf)
            tr.velocity = None
        spd = motion.speed(vel)
        spd_sigma = (
            float(np.sqrt(np.sum(np.square(vel * vsig))) / spd) if spd > 0 else float(np.max(vsig))
        )
        lifecycle = (
            TrackLifecycle.CONFIRMED if tr.hits >= p.confirm_hits else TrackLifecycle.TENTATIVE
        )
        return TrackState(
            track_id=tr.track_id,
            lifecycle=lifecycle,
            t_ns=t_ns,
            observation=ob,
            velocity_mps=vel,
            velocity_sigma_mps=vsig,
            velocity_valid=valid,
            speed_mps=spd,
            speed_sigma_mps=spd_sigma,
            heading_deg=motion.heading_deg(float(vel[0]), float(vel[2])),
            heading_sigma_deg=motion.heading_sigma_deg(
                float(vel[0]), float(vel[2]), float(vsig[0]), float(vsig[2])
            ),
            raw_velocity_mps=raw,
            age_s=(t_ns - tr.first_t_ns) * 1e-9,
        )
