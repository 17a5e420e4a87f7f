"""One track: its filters (moving straight and falling, started from two observations by
eq. 21 over one frame), its measurement noise learned, its lifecycle and reported state
(speed and heading by eq. 22, 23; the raw eq. 21 velocity beside them)."""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

import numpy as np

from stereod.tracking import kalman, motion
from stereod.tracking.types import (
    VALID_HEADING_SIGMA_DEG,
    EyeHistory,
    Observation,
    TrackerParams,
    TrackLifecycle,
    TrackState,
)


@dataclass
class Track:
    """One track's filter and histories (internal to the tracker, readable by the pipeline)."""

    track_id: int
    first_t_ns: int
    kf: kalman.KalmanState
    """The filter of the likelier motion model (see ``falling``); what the track reports."""
    last: Observation
    image_speed_pxps: float
    area_px: float
    hits: int = 1
    misses: int = 0
    """Pairs in a row in which the track was not seen (a tentative track seen once may
    wait one such pair; see :meth:`stereod.tracking.tracker.Tracker.update`)."""
    last_seen_ns: int = 0
    last_moving_ns: int | None = None
    """When the object was last seen clearly moving (speed above ``stationary_mps`` and three
    sigmas, or its centroid out of reach of where it last moved in the images, see
    :data:`STILL_REACH`); only an object seen moving holds the background, for
    ``hold_still_s`` after that (a track born still, like a ghost of the background, never
    does, unless it parted from an object moving then: it takes that one's instant, see
    ``Tracker._parted``)."""
    moved_at_px: tuple[int, np.ndarray, np.ndarray] | None = None
    """When (ns) and where the object's whole outline's centroids were (left, right image px)
    that its image motion is measured from: where it was last seen moving, or first seen
    whole, or ``still_after_s`` ago (a blob that creeps, or fades, slower than that is still);
    None after a jump of its centroid that was no motion (an end of it segmented or not)."""
    stationary: bool = False
    """Whether the track was last reported ``stationary``: standing still, held out of the
    background."""
    speed_known: bool = False
    """Whether the track was last reported with a valid velocity (``velocity_valid``)."""
    freeze_spent: bool = False
    """Set once the object has been still for ``hold_still_s``: the background then takes it, and
    the apparent motion of a blob fading into the background never re-arms the freeze."""
    updates: int = 0
    """Filter updates so far (the noise scale learns fast at first, then settles)."""
    noise_scale: float = 1.0
    """How much larger (or smaller) this object's measurement noise is than its triangulation
    covariance says, learned from the filter's innovations (1: as said)."""
    recent: collections.deque[tuple[int, np.ndarray, np.ndarray]] = field(
        default_factory=lambda: collections.deque(maxlen=3)
    )
    """The last three whole observations: instant (ns), position (m), covariance (m^2)."""
    whole: bool = False
    """Whether the latest observation was whole (not clipped by the image's edge)."""
    started: bool = False
    """Whether the filter runs (from the second whole observation on)."""
    edge_begun: bool = False
    """Whether the filter was started on an outline cut by the image's side (its depth from
    the free edge, its lateral position loose): it starts afresh at the first whole one."""
    odd_size: bool = False
    """Whether the last blob given to this tentative track was held aside, its width beyond
    ``tracker.REGROWN`` of its last observation's."""
    first: tuple[int, Observation] | None = None
    """The first exact whole observation and its instant, kept until the next starts the
    filter."""
    positions: collections.deque[tuple[int, np.ndarray]] = field(
        default_factory=lambda: collections.deque(maxlen=256)
    )
    left_history: EyeHistory = field(default_factory=lambda: collections.deque(maxlen=8))
    right_history: EyeHistory = field(default_factory=lambda: collections.deque(maxlen=8))
    other: kalman.KalmanState | None = None
    """The filter of the other motion model (straight line or free fall), run alongside."""
    falling: bool = False
    """Whether ``kf`` is the free-fall filter (the object moves as if thrown)."""
    fall_evidence: float = 0.0
    """Log-likelihood of free fall over a straight line, summed over recent updates with a
    fading memory."""
    blended: bool = False
    """Whether the latest observation was of a blob it shared with an object behind it: its 2D
    histories then follow that blob's centroid, not the object's."""
    hidden_in: tuple[np.ndarray, np.ndarray] | None = None
    """While a confirmed track is unseen: the boxes (left, right; x, y, w, h px) of the blobs
    that hid it in the latest pair (where its prediction fell, or what the blob that hid it
    before became: moved on, or parted in two); None when seen, or hidden by nothing. For a
    member of another's object (``member_of``): that object's blobs, followed while they
    overlap, that it may come out of."""
    outline_m: tuple[float, float] | None = None
    """How far its silhouettes' centroid lies from their boxes' left and right edges (m at its
    depth, both eyes' mean), from its latest observation seen whole in a blob of its own: where
    its centre lies from its free edge when another object joins its blob on one side
    (:func:`stereod.tracking.measure.by_edge`). None before it was seen so."""
    member_of: int | None = None
    """The track whose object this one was taken into as a piece (it is then a member: not
    published, not ended, for up to ``max_member_s``), or None."""
    merged_ns: int = 0
    """When it became a member (ns)."""


class TrackFilters:
    """The tracker's work on one track at a time: its two filters' predict and update, their
    start, its noise scale, whether it is confirmed, and the state it reports."""

    params: TrackerParams
    _gravity: np.ndarray | None

    NOISE_RATE = 0.05
    """How fast a track's measurement noise scale follows its innovations once settled (per
    update; at first it follows the running mean)."""
    NOISE_BOUNDS = (0.25, 20.0)
    """A track's noise scale stays within these: its positions at most 1.4 times as precise as
    the triangulation covariance says (a tighter filter follows the noise: headings jitter),
    at most 4.5 times less."""

    FALL_MEMORY = 0.8
    """Per update, the share of the free-fall evidence kept (a memory of about five frames)."""
    FALL_SWITCH = 2.0
    """Evidence (log-likelihood) beyond which a track changes model: odds of e^2, about 7:1."""
    FALL_GAIN_MAX = 5.0
    """The most evidence one update may add either way (log-likelihood): a thrown ball's
    first updates still switch it at once, but one outlying position does not switch a track
    that has moved straight for seconds (a person standing still, whose centroid dropped
    0.26 m when their legs showed again: the free-fall filter took it at -26 m/s, 0.3 m
    from the rig). From a track's steady straight-line evidence, a real fall switches it
    within four updates."""

    def _filter(self, tr: Track, t_ns: int, ob: Observation) -> None:
        """One predict/update of the filter, and of the other motion model's alongside; the
        track follows whichever has explained its recent positions better. The measurement
        covariance is the triangulation's times the track's noise scale (:meth:`_learn_noise`).
        An innovation beyond ``manoeuvre_chi2`` is a manoeuvre, or a prediction too sure of
        itself: the prediction's covariance is widened by as much as it takes to bring the
        innovation back to that bound (a fading memory), so the update leans on the
        measurement as much as the surprise calls for, and no more."""
        if not ob.clipped:  # a clipped outline's centroid moves with the cut, not the object
            self._learn_noise(tr, t_ns, ob)
        r = ob.cov_m2 * tr.noise_scale
        q = self._q(tr)
        tr.kf, ll = self._step(tr.kf, t_ns, ob, r, q, self._accel(tr.falling))
        if tr.other is None:
            return
        tr.other, ll_other = self._step(tr.other, t_ns, ob, r, q, self._accel(not tr.falling))
        gain = (ll - ll_other) if tr.falling else (ll_other - ll)  # evidence for free fall
        if not math.isfinite(gain):
            return
        gain = min(max(gain, -self.FALL_GAIN_MAX), self.FALL_GAIN_MAX)
        tr.fall_evidence = self.FALL_MEMORY * tr.fall_evidence + gain
        if tr.falling != (tr.fall_evidence > 0.0) and abs(tr.fall_evidence) > self.FALL_SWITCH:
            tr.kf, tr.other = tr.other, tr.kf
            tr.falling = not tr.falling

    def _piece(self, tr: Track, t_ns: int, ob: Observation) -> None:
        """A piece of the object seen, the rest hidden: its position lies within the object's
        last whole outline (``tr.last``'s extent, or its width each way) around the centre.
        Where the prediction is that close to it (on each axis, within half the outline and
        three sigmas of the piece's own noise), the filter is only predicted: the piece's
        centroid says less than the motion does. Where it is not, the filter's motion was a
        guess that left the object (a pedestrian's, started on a mismatch at 16 m/s, once ran
        40 m off in 2 s while pieces of them kept it seen), and the piece is folded in with
        half the outline as further noise on each axis."""
        last = tr.last
        if last.extent_m is not None:
            half = 0.5 * (last.extent_m[1] - last.extent_m[0])
        else:
            half = np.full(3, 0.5 * last.size_m)
        r = ob.cov_m2 * tr.noise_scale
        predicted = np.array(kalman.point_at(tr.kf, t_ns, self._accel(tr.falling)))
        off = np.abs(ob.position_m - predicted)
        if bool(np.all(off <= half + 3.0 * np.sqrt(np.diag(r)))):
            self._predict(tr, t_ns)
            return
        r = r + np.diag(half * half)
        q = self._q(tr)
        tr.kf, _ = self._step(tr.kf, t_ns, ob, r, q, self._accel(tr.falling))
        if tr.other is not None:
            tr.other, _ = self._step(tr.other, t_ns, ob, r, q, self._accel(not tr.falling))

    def _step(
        self,
        kf: kalman.KalmanState,
        t_ns: int,
        ob: Observation,
        r: np.ndarray,
        q: float,
        accel: np.ndarray | None,
    ) -> tuple[kalman.KalmanState, float]:
        """One filter's predict and update, and the measurement's log-likelihood under the
        prediction (before any widening)."""
        pred = kalman.predict(kf, t_ns, q, accel)
        return kalman.correct(pred, ob.position_m, r, self.params.manoeuvre_chi2)

    def _accel(self, falling: bool) -> np.ndarray | None:
        """The known acceleration of a motion model: gravity when falling, else none."""
        return self._gravity if falling else None

    def _predict(self, tr: Track, t_ns: int) -> None:
        """Both of a track's filters moved to ``t_ns`` without a measurement."""
        q = self._q(tr)
        tr.kf = kalman.predict(tr.kf, t_ns, q, self._accel(tr.falling))
        if tr.other is not None:
            tr.other = kalman.predict(tr.other, t_ns, q, self._accel(not tr.falling))

    def _q(self, tr: Track) -> float:
        """The track's process noise density (m^2/s^3): ``accel_noise`` for an object at walking
        pace, growing with the square of its speed above 1 m/s, since a fast object (a thrown
        ball falls at 9.8 m/s^2) leaves a straight line faster."""
        v = motion.speed(tr.kf.velocity_mps) if tr.started else 0.0
        return self.params.accel_noise * max(1.0, v * v)

    def _learn_noise(self, tr: Track, t_ns: int, ob: Observation) -> None:
        """Follow how noisy this object's positions really are. The middle of three
        consecutive positions is compared with the straight line through the other two: for
        an object that moves steadily between frames, that residual is pure measurement noise,
        so its squared Mahalanobis distance under the scaled covariances has mean 3 (3 dof),
        whatever the filter believes. The scale moves towards that, quickly at first, then at
        ``NOISE_RATE`` per observation, within ``NOISE_BOUNDS``."""
        tr.recent.append((t_ns, ob.position_m, ob.cov_m2))
        if len(tr.recent) < 3:
            return
        (t0, p0, r0), (t1, p1, r1), (t2, p2, r2) = tr.recent
        a = (t2 - t1) / (t2 - t0)
        b = (t1 - t0) / (t2 - t0)
        residual = p1 - (a * p0 + b * p2)
        if (
            tr.falling and self._gravity is not None
        ):  # a free fall's positions bend by g (t1 - t0)(t2 - t1) / 2 off the line
            residual = residual + 0.5 * (t1 - t0) * (t2 - t1) * 1e-18 * self._gravity
        cov = (r1 + a * a * r0 + b * b * r2) * tr.noise_scale
        inv = kalman.inverse3(cov)
        d2 = kalman.quadratic3(residual, inv[0] if inv else np.linalg.inv(cov))
        lo, hi = self.NOISE_BOUNDS
        rate = max(self.NOISE_RATE, 1.0 / (tr.updates + 2))
        scale = tr.noise_scale * (1.0 + rate * (min(d2, 30.0) / 3.0 - 1.0))
        tr.noise_scale = min(max(scale, lo), hi)
        tr.updates += 1

    def _begin(self, tr: Track, t_ns: int, ob: Observation) -> None:
        """A track before its filter runs. A clipped observation without a depth from its
        outline's free edge only places it (one with it counts as whole: a person walking in
        past the image's side starts their filter there). The first
        whole one after that starts the eyes' 2D histories afresh (so what follows is brought
        to one instant with clean image motion) and places it too. The first exact whole one
        (both eyes at one instant) is kept, and the next exact one starts the filter from the
        two: eq. 21 over one frame. Without skew the first two whole observations do; with
        skew the first cannot be brought to one instant, and the filter starts one frame
        later rather than from a guessed position. Two observations further apart than
        ``max_speed_mps`` allows (beyond three sigmas of their noise along the step) are not
        one object moving: the newer one is kept instead."""
        p = self.params
        clipped = ob.clipped and not ob.edge_depth  # cut, and no depth from its free edge
        if clipped or not tr.whole:
            tr.whole = not clipped
            tr.first = None
            if tr.whole:
                tr.left_history.clear()
                tr.right_history.clear()
                tr.positions.clear()
        if clipped or not ob.exact or tr.first is None:
            tr.kf = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.manoeuvre_sigma_mps)
            if not clipped and ob.exact:
                tr.first = (t_ns, ob)
            return
        t0, ob0 = tr.first
        delta = ob.position_m - ob0.position_m
        step = float(np.linalg.norm(delta))
        unit = delta / step if step > 0 else delta
        noise = math.sqrt(max(float(unit @ (ob.cov_m2 + ob0.cov_m2) @ unit), 0.0))
        if step > p.max_speed_mps * (t_ns - t0) * 1e-9 + 3.0 * noise:  # a mismatch
            tr.kf = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.manoeuvre_sigma_mps)
            tr.first = (t_ns, ob)
            tr.positions.clear()
            return
        tr.kf = kalman.initiate_two(ob0.position_m, ob0.cov_m2, t0, ob.position_m, ob.cov_m2, t_ns)
        tr.falling, tr.fall_evidence, tr.other = False, 0.0, None
        if self._gravity is not None:
            tr.other = kalman.initiate_two(
                ob0.position_m, ob0.cov_m2, t0, ob.position_m, ob.cov_m2, t_ns, self._gravity
            )
        tr.first = None
        tr.started = True
        tr.edge_begun = ob.clipped or ob0.clipped
        tr.positions.clear()
        tr.positions.append((t0, ob0.position_m))

    def _anchor(self, tr: Track, t_ns: int, ob: Observation) -> None:
        """Both filters predicted to ``t_ns`` and moved onto ``ob``'s ray at the depth each
        predicts, their covariances and velocities kept: the centroid of a blob that gained or
        lost one end of its object jumped across the image by a change of shape, not of depth
        or motion (folded in as a measurement, a person's 0.26 m drop as their legs showed
        again widened the filter until it put them 0.3 m from the rig)."""
        self._predict(tr, t_ns)
        tr.moved_at_px = None  # (nor is the jump an image motion)
        oz = float(ob.position_m[2])
        for kf in (tr.kf, tr.other):
            if kf is not None and oz > 0 and float(kf.x[2]) > 0:
                kf.x = kf.x.copy()
                kf.x[:3] = ob.position_m * (float(kf.x[2]) / oz)
        tr.recent.clear()

    def _afresh(self, tr: Track, t_ns: int, ob: Observation) -> None:
        """A track whose filter started on outlines cut by the image's side, seen whole at
        last: its filters start afresh at this observation (their velocity from the cut
        outlines' loose lateral positions would bias its heading and speed for seconds: a box
        pushed in past the image's side read 2.5 deg and 3.5 % off), its noise scale and
        histories too; it stays started, its velocity unknown until the filter learns it."""
        p = self.params
        tr.edge_begun, tr.falling, tr.fall_evidence = False, False, 0.0
        tr.kf = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.manoeuvre_sigma_mps)
        if tr.other is not None:
            tr.other = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.manoeuvre_sigma_mps)
        tr.noise_scale, tr.updates = 1.0, 0
        tr.positions.clear()
        tr.left_history.clear()
        tr.right_history.clear()
        tr.moved_at_px = None

    def _anew(self, tr: Track, t_ns: int, ob: Observation) -> None:
        """A tentative track given blobs of another width two pairs running
        (``tracker._regrown``) begins again at this observation, as a new track would, keeping
        its id: what it saw before says nothing of this object's position or motion."""
        self._afresh(tr, t_ns, ob)
        tr.started, tr.first, tr.hits, tr.first_t_ns = False, None, 0, t_ns
        tr.member_of, tr.other = None, None
        tr.recent.clear()
        self._begin(tr, t_ns, ob)

    def _confirmed(self, tr: Track) -> bool:
        """Seen ``confirm_hits`` times, and its filter runs."""
        return tr.started and tr.hits >= self.params.confirm_hits

    def _raw_velocity(self, tr: Track) -> np.ndarray | None:
        """Eq. 21 between the newest position and the newest one at least tau older."""
        if not tr.positions:
            return None
        base_ns = int(self.params.time_base_s * 1e9)
        t_now, p_now = tr.positions[-1]
        for t, pos in reversed(tr.positions):
            if t_now - t >= base_ns:
                return motion.finite_difference(pos, p_now, (t_now - t) * 1e-9)
        return None

    def _state(self, tr: Track, t_ns: int, *, observed: bool) -> TrackState:
        p = self.params
        started = tr.started
        vel = tr.kf.velocity_mps.copy() if started else np.zeros(3)
        vcov = tr.kf.velocity_cov.copy()
        vx, vy, vz = vel.tolist()
        spd = math.sqrt(vx * vx + vy * vy + vz * vz)
        (sxx, _, sxz), (_, syy, _), (_, _, szz) = vcov.tolist()
        spd_sigma = (
            math.sqrt(kalman.quadratic3(vel, vcov)) / spd if spd > 0 else math.sqrt(sxx + syy + szz)
        )
        ground = math.hypot(vx, vz)
        heading_sigma = motion.heading_sigma_deg(vx, vz, math.sqrt(sxx), math.sqrt(szz), sxz)
        across = math.radians(heading_sigma) * ground if ground > 0 else math.inf
        confirmed = self._confirmed(tr)
        bound = max(p.valid_speed_sigma_mps, p.valid_speed_sigma_rel * spd)
        valid = started and confirmed and spd_sigma <= bound
        tr.speed_known = valid
        # The direction: across it within the speed's bound, and a heading sigma within
        # VALID_HEADING_SIGMA_DEG (the speed's absolute floor would otherwise give anything
        # slow on the ground, or falling, a "known" direction).
        heading_valid = valid and across <= bound and heading_sigma <= VALID_HEADING_SIGMA_DEG
        # Seen moving: confirmed, and its speed clearly above nil (three sigmas), even where
        # the velocity is too uncertain to publish as valid (a walking person's centre jumps
        # as arms and legs swing, and their speed's sigma stays above the valid bound); or,
        # where depth is too coarse for the speed to tell (a walker 11 m off, their speed's
        # sigma 1 m/s), gone across the images from where it last moved.
        if started and confirmed and spd > max(p.stationary_mps, 3.0 * spd_sigma):
            tr.last_moving_ns = t_ns
            tr.moved_at_px = None
        if observed and confirmed and _left_its_place(tr, t_ns, p.still_after_s):
            tr.last_moving_ns = t_ns
        still_for = None if tr.last_moving_ns is None else (t_ns - tr.last_moving_ns) * 1e-9
        if still_for is not None and still_for >= p.hold_still_s:
            tr.freeze_spent = True
        tr.stationary = False
        if not observed and confirmed:
            lifecycle = TrackLifecycle.COASTING
        elif confirmed and still_for is not None and still_for >= p.still_after_s:
            lifecycle = TrackLifecycle.STATIONARY
            tr.stationary = True
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
            heading_valid=heading_valid,
            speed_mps=spd,
            speed_sigma_mps=spd_sigma,
            heading_deg=motion.heading_deg(vx, vz),
            heading_sigma_deg=heading_sigma,
            raw_velocity_mps=self._raw_velocity(tr),
            age_s=(t_ns - tr.first_t_ns) * 1e-9,
            freeze_background=still_for is not None and not tr.freeze_spent,
            release_background=tr.freeze_spent,
        )


def behind(tr: Track) -> bool:
    """Whether a track's running filter puts it behind the rig (Z <= 0 m). Before the filter
    runs a track's position is its first sight, which for a fast object seen with the eyes'
    skew may well lie there; that only places it."""
    return tr.started and not float(tr.kf.position_m[2]) > 0.0


STILL_REACH = 0.5
"""How far an object's centroid may wander in the images, as a share of its size (the square
root of its blob's area, px), and still be where it was: a seated person waving, a robot
turning on the spot, a segmentation that takes in an arm or leaves out a leg. A walker
leaves it within half a second at any range."""
STILL_REACH_MIN_PX = 3.0
"""The least reach (px): a small blob's centroid is a pixel or two off from frame to frame."""


def _left_its_place(tr: Track, t_ns: int, within_s: float) -> bool:
    """Whether the track's last whole outline (``tr.last``) lies, in either eye, further than
    :data:`STILL_REACH` of its size from where it was ``tr.moved_at_px`` says, within
    ``within_s`` (s) of then: it moved, and is measured from here on. Where that is not known,
    or longer ago, it is measured from here on, and has not moved. A clipped outline's
    centroid moves with the cut: it says nothing."""
    ob = tr.last
    if ob.clipped:
        return False
    at = tr.moved_at_px
    if at is None or t_ns - at[0] > within_s * 1e9:
        tr.moved_at_px = (t_ns, ob.left_image_px, ob.right_image_px)
        return False
    reach = max(STILL_REACH_MIN_PX, STILL_REACH * math.sqrt(tr.area_px))
    for now, then in ((ob.left_image_px, at[1]), (ob.right_image_px, at[2])):
        if math.hypot(float(now[0] - then[0]), float(now[1] - then[1])) > reach:
            tr.moved_at_px = (t_ns, ob.left_image_px, ob.right_image_px)
            return True
    return False
