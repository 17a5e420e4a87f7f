"""3D tracks with stable ids, a lifecycle and a constant-velocity Kalman filter.

Each pair's observations are assigned to tracks globally (minimum total squared Mahalanobis
distance, Hungarian algorithm), gated at a chi-square bound: an observation farther than the
gate from every track's prediction starts a new track. The filter's measurement noise is each
observation's triangulation covariance, so depth noise growing as Z^2 (eq. 12) is weighted
correctly. Velocity, speed and heading come from the filter (eq. 22, 23 on its velocity); the
paper's eq. 21 finite difference over ``time_base_s`` is kept beside them as the raw velocity.

Lifecycle: ``tentative`` until ``confirm_hits`` observations, then ``confirmed``; a confirmed
track not seen in a pair is ``coasting`` (predicted) until ``max_coast_s`` has passed, then it
ends (a tentative track ends at its first miss). Ids are never reused. All times are seconds
computed from timestamps, never frame counts.
"""

from __future__ import annotations

import collections
import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from . import kalman, motion
from .assignment import min_cost_assignment
from .skew import image_velocity, shift_to


def _image_distance(history: EyeHistory, centroid_px: np.ndarray, t_ns: int) -> float:
    """Distance (px) from a centroid to where one eye's 2D track puts the object at ``t_ns``
    (its last centroid moved along its image velocity when it has one)."""
    t_last, last = history[-1]
    predicted = shift_to(last, t_last, image_velocity(history, 10**9), t_ns)
    return float(np.linalg.norm(centroid_px - predicted))


class TrackLifecycle(str, enum.Enum):
    """Where a track is in its life."""

    TENTATIVE = "tentative"
    """Seen fewer than ``confirm_hits`` times: may be noise."""
    CONFIRMED = "confirmed"
    """Seen often enough to be a real object, and seen in the latest pair."""
    COASTING = "coasting"
    """Confirmed but not seen in the latest pair: its state is predicted."""


@dataclass(frozen=True, slots=True)
class Observation:
    """One object triangulated from one stereo pair.

    ``position_m`` (3,) rig frame; ``cov_m2`` (3, 3); ``left_px``/``right_px`` (2,) measured
    centroids in rectified coordinates (the eyes' 2D tracks); ``left_image_px``/
    ``right_image_px`` the same in image coordinates; ``left_bbox_px``/``right_bbox_px`` (4,)
    x, y, w, h; areas in px; ``disparity_px``; ``size_m`` the blob's width in metres (bbox
    width x Z / f).
    """

    position_m: np.ndarray
    cov_m2: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    left_image_px: np.ndarray
    right_image_px: np.ndarray
    left_bbox_px: np.ndarray
    right_bbox_px: np.ndarray
    left_area_px: int
    right_area_px: int
    disparity_px: float
    size_m: float


@dataclass(frozen=True, slots=True)
class TrackerParams:
    """Tracker settings, SI units.

    ``gate_chi2``: largest squared Mahalanobis distance to join a track (3 dof; 16.3 is
    99.9 %). ``min_gate_m``: an observation this close (m) to a prediction may always join
    it, however confident the filter (an object that brakes hard leaves the constant-velocity
    model); a join beyond the chi-square gate is a manoeuvre and re-opens the velocity
    uncertainty. ``gate_px``: largest image distance (px, per eye) to join a track that has
    only seen skewed observations. ``accel_noise``: spectral density q of the white
    acceleration (m^2/s^3). ``time_base_s``: tau of eq. 21 (s), and how long a track's
    filter must run before its velocity is valid. ``max_coast_s``: how long (s) a confirmed
    track lives unseen. ``confirm_hits``: observations to confirm.
    ``init_velocity_sigma_mps``: prior velocity sigma of a new track. ``freeze_s``: how long
    (s) after it was last seen moving an object keeps the background frozen under it.
    ``stationary_mps``: below this speed an object is not moving.
    """

    gate_chi2: float = 16.3
    min_gate_m: float = 0.15
    gate_px: float = 60.0
    accel_noise: float = 0.05
    time_base_s: float = 0.5
    max_coast_s: float = 0.5
    confirm_hits: int = 3
    init_velocity_sigma_mps: float = 2.0
    freeze_s: float = 10.0
    stationary_mps: float = 0.05


@dataclass(frozen=True, slots=True)
class TrackState:
    """A track's state at one instant, everything in SI units (m, m/s, deg, s)."""

    track_id: int
    lifecycle: TrackLifecycle
    t_ns: int
    observation: Observation
    """The latest observation (for a coasting track: the last one seen)."""
    position_m: np.ndarray
    position_cov_m2: np.ndarray
    velocity_mps: np.ndarray
    velocity_cov: np.ndarray
    velocity_valid: bool
    speed_mps: float
    speed_sigma_mps: float
    heading_deg: float
    heading_sigma_deg: float
    raw_velocity_mps: np.ndarray | None
    age_s: float
    freeze_background: bool
    """Whether the background should not learn under this object now: it was seen moving, and
    has not been stopped for longer than ``freeze_s``."""


EyeHistory = collections.deque[tuple[int, np.ndarray]]


@dataclass
class Track:
    """One track's filter and histories (internal to the tracker, readable by the pipeline)."""

    track_id: int
    first_t_ns: int
    kf: kalman.KalmanState
    last: Observation
    hits: int = 1
    last_seen_ns: int = 0
    kf_since_ns: int = 0
    """When the filter was (re)started: its velocity is trusted ``time_base_s`` after that."""
    last_moving_ns: int | None = None
    """When the object was last seen clearly moving (speed above ``stationary_mps`` and three
    sigmas); only an object seen moving freezes the background, for ``freeze_s`` after that
    (a track born still, like a ghost of the background, never does)."""
    freeze_spent: bool = False
    """Set once the object has been still for ``freeze_s``: the background then takes it, and
    the apparent motion of a blob fading into the background never re-arms the freeze."""
    exact: bool = True
    """Whether the filter has only seen observations taken at one instant (see update)."""
    positions: collections.deque[tuple[int, np.ndarray]] = field(
        default_factory=lambda: collections.deque(maxlen=256)
    )
    left_history: EyeHistory = field(default_factory=lambda: collections.deque(maxlen=8))
    right_history: EyeHistory = field(default_factory=lambda: collections.deque(maxlen=8))


class Tracker:
    """Kalman tracker; per pair call :meth:`associate`, then :meth:`update` with the (possibly
    refined) observations and the assignment it returned."""

    def __init__(self, params: TrackerParams) -> None:
        self.params = params
        self._tracks: dict[int, Track] = {}
        self._next_id = 1

    def live_ids(self) -> list[int]:
        return list(self._tracks)

    def track(self, track_id: int) -> Track:
        return self._tracks[track_id]

    def associate(
        self,
        t_ns: int,
        observations: list[Observation],
        candidates: Callable[[Track], list[Observation]] | None = None,
        eye_times_ns: tuple[int, int] | None = None,
    ) -> list[int | None]:
        """The track id each observation belongs to (``None``: a new object).

        Tracks whose filter holds only exact observations are matched first, by minimum total
        squared Mahalanobis distance within the gate; ``candidates(track)``, when given, returns
        the observations as they would be if they belonged to that track (skew compensation
        along the track's own image motion) and the distance is measured on those. Tracks not
        yet exact (their one observation mixed two instants) are then matched in the images:
        each eye's centroid against the track's last centroid in that eye, within
        ``gate_px``, which no skew can bias.
        """
        out: list[int | None] = [None] * len(observations)
        tracks = list(self._tracks.values())
        if not tracks or not observations:
            return out
        p = self.params
        exact = [tr for tr in tracks if tr.exact]
        if exact:
            cost = np.empty((len(observations), len(exact)))
            dist = np.empty_like(cost)
            for j, tr in enumerate(exact):
                pred = kalman.predict(tr.kf, t_ns, p.accel_noise)
                obs = observations if candidates is None else candidates(tr)
                for i, o in enumerate(obs):
                    cost[i, j] = kalman.mahalanobis2(pred, o.position_m, o.cov_m2)
                    dist[i, j] = float(np.linalg.norm(o.position_m - pred.position_m))
            feasible = (cost <= p.gate_chi2) | (dist <= p.min_gate_m)
            self._assign(np.minimum(cost, 1e5), feasible, exact, out)
        fresh = [tr for tr in tracks if not tr.exact]
        free = [i for i, a in enumerate(out) if a is None]
        if fresh and free:
            t_left, t_right = eye_times_ns if eye_times_ns is not None else (t_ns, t_ns)
            cost = np.empty((len(free), len(fresh)))
            for j, tr in enumerate(fresh):
                for k, i in enumerate(free):
                    o = observations[i]
                    cost[k, j] = max(
                        _image_distance(tr.left_history, o.left_px, t_left),
                        _image_distance(tr.right_history, o.right_px, t_right),
                    )
            sub: list[int | None] = [None] * len(free)
            self._assign(cost, cost <= p.gate_px, fresh, sub)
            for k, i in enumerate(free):
                out[i] = sub[k]
        return out

    @staticmethod
    def _assign(
        cost: np.ndarray, feasible: np.ndarray, tracks: list[Track], out: list[int | None]
    ) -> None:
        """Minimum-cost assignment of rows (observations) to feasible columns (tracks)."""
        big = 1e9
        gated = np.where(feasible, cost, big)
        rows, cols = min_cost_assignment(gated)
        for i, j in zip(rows, cols, strict=True):
            if feasible[i, j]:
                out[i] = tracks[j].track_id

    def update(
        self,
        t_ns: int,
        observations: list[Observation],
        assignment: list[int | None],
        eye_times_ns: tuple[int, int],
        exact: list[bool] | None = None,
    ) -> tuple[list[TrackState], list[int]]:
        """Fold in one pair's observations at ``t_ns``; ``eye_times_ns`` are the left and right
        capture instants of the centroids (for the eyes' 2D histories). ``exact[i]`` is False
        when observation i mixes two capture instants (skew not compensated: a new track has
        no image motion yet); a track's filter starts afresh at its first exact observation so
        the biased ones never reach its velocity. Returns the state of every live track
        (observed or coasting) and the ids of the tracks that ended."""
        p = self.params
        seen: set[int] = set()
        states: list[TrackState] = []
        t_left, t_right = eye_times_ns
        flags = exact if exact is not None else [True] * len(observations)
        for ob, tid, ok in zip(observations, assignment, flags, strict=True):
            if tid is None:
                kf = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.init_velocity_sigma_mps)
                tr = Track(
                    self._next_id,
                    first_t_ns=t_ns,
                    kf=kf,
                    last=ob,
                    last_seen_ns=t_ns,
                    kf_since_ns=t_ns,
                )
                tr.exact = ok
                self._next_id += 1
                self._tracks[tr.track_id] = tr
            else:
                tr = self._tracks[tid]
                if ok and not tr.exact:
                    tr.kf = kalman.initiate(
                        ob.position_m, ob.cov_m2, t_ns, p.init_velocity_sigma_mps
                    )
                    tr.kf_since_ns = t_ns
                    tr.exact = True
                else:
                    pred = kalman.predict(tr.kf, t_ns, p.accel_noise)
                    if kalman.mahalanobis2(pred, ob.position_m, ob.cov_m2) > p.gate_chi2:
                        pred = kalman.inflate_velocity(pred, p.init_velocity_sigma_mps)
                    tr.kf = kalman.update(pred, ob.position_m, ob.cov_m2)
                tr.hits += 1
                tr.last = ob
                tr.last_seen_ns = t_ns
            tr.positions.append((t_ns, ob.position_m))
            tr.left_history.append((t_left, ob.left_px))
            tr.right_history.append((t_right, ob.right_px))
            seen.add(tr.track_id)
            states.append(self._state(tr, t_ns, observed=True))
        ended = []
        coast_ns = int(p.max_coast_s * 1e9)
        for tid, tr in list(self._tracks.items()):
            if tid in seen:
                continue
            if tr.hits < p.confirm_hits or t_ns - tr.last_seen_ns > coast_ns:
                ended.append(tid)
                del self._tracks[tid]
            else:
                tr.kf = kalman.predict(tr.kf, t_ns, p.accel_noise)
                states.append(self._state(tr, t_ns, observed=False))
        return states, ended

    def continue_after(self, other: Tracker) -> None:
        """Number new tracks after ``other``'s, so ids are never reused while running."""
        self._next_id = max(self._next_id, other._next_id)

    def end_all(self) -> list[int]:
        """End every live track (end of input); return their ids."""
        ids = list(self._tracks)
        self._tracks.clear()
        return ids

    def _raw_velocity(self, tr: Track, t_ns: int) -> np.ndarray | None:
        """Eq. 21 between the newest position and the newest one at least tau older."""
        base_ns = int(self.params.time_base_s * 1e9)
        t_now, p_now = tr.positions[-1]
        old = None
        for t, pos in reversed(tr.positions):
            if t_now - t >= base_ns:
                old = (t, pos)
                break
        if old is None:
            return None
        return motion.finite_difference(old[1], p_now, (t_now - old[0]) * 1e-9)

    def _state(self, tr: Track, t_ns: int, *, observed: bool) -> TrackState:
        p = self.params
        vel = tr.kf.velocity_mps.copy()
        vcov = tr.kf.velocity_cov.copy()
        spd = motion.speed(vel)
        spd_sigma = (
            math.sqrt(float(vel @ vcov @ vel)) / spd
            if spd > 0
            else math.sqrt(float(np.trace(vcov)))
        )
        confirmed = tr.hits >= p.confirm_hits
        age = (t_ns - tr.first_t_ns) * 1e-9
        valid = confirmed and (t_ns - tr.kf_since_ns) * 1e-9 >= p.time_base_s
        if valid and spd > max(p.stationary_mps, 3.0 * spd_sigma):
            tr.last_moving_ns = t_ns
        still_for = None if tr.last_moving_ns is None else (t_ns - tr.last_moving_ns) * 1e-9
        if still_for is not None and still_for >= p.freeze_s:
            tr.freeze_spent = True
        if not observed:
            lifecycle = TrackLifecycle.COASTING
        elif confirmed:
            lifecycle = TrackLifecycle.CONFIRMED
        else:
            lifecycle = TrackLifecycle.TENTATIVE
        return TrackState(
            track_id=tr.track_id,
            lifecycle=lifecycle,
            t_ns=t_ns,
            observation=tr.last,
            position_m=tr.kf.position_m.copy(),
            position_cov_m2=tr.kf.P[:3, :3].copy(),
            velocity_mps=vel,
            velocity_cov=vcov,
            velocity_valid=valid,
            speed_mps=spd,
            speed_sigma_mps=spd_sigma,
            heading_deg=motion.heading_deg(float(vel[0]), float(vel[2])),
            heading_sigma_deg=motion.heading_sigma_deg(
                float(vel[0]), float(vel[2]), math.sqrt(vcov[0, 0]), math.sqrt(vcov[2, 2])
            ),
            raw_velocity_mps=self._raw_velocity(tr, t_ns),
            age_s=age,
            freeze_background=still_for is not None and not tr.freeze_spent,
        )
