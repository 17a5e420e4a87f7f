"""3D tracks with stable ids, a lifecycle and Kalman filters (moving straight, or falling).

Association is done in the images, where skew cannot bias it: each track predicts where its
object is in each eye at that eye's own capture instant (its filter's prediction projected
into that eye; before the filter runs, its last centroid moved along that eye's image
velocity, or the line through its first two positions projected), and each stereo detection
is assigned to the track it is nearest to in both eyes at once, globally (Hungarian
algorithm), within a gate: confirmed tracks first, then tentative ones among the detections
left. A track with one observation
has no velocity yet; its gate is how far an object at ``max_speed_mps`` can move in the image at
its depth (its disparity gives the pixels per metre), so an object as fast as a thrown ball is
followed from its second frame. A detection that a live object's prediction explains in both
eyes (a piece of it) starts no track; one that two confirmed tracks fall into (two objects
crossing, one hiding the other) updates neither: both coast until they part.

The filter's measurement is each observation's triangulated position with its covariance, so
depth noise growing as Z^2 (eq. 12) is weighted correctly. It starts at a track's second
observation from the two positions, whose difference is its first velocity (eq. 21 over one
frame); an observation far outside the filter's prediction widens the prediction until it
is not (a fading memory). Beside the constant-velocity filter a free-fall one runs (gravity
``gravity_mps2``), and the track reports whichever has explained its recent positions better:
a thrown ball is followed along its arc. Velocity, speed and heading come from the filter
(eq. 22, 23 on its velocity); the paper's eq. 21 finite difference over ``time_base_s`` is kept
beside them as the raw velocity. A velocity is valid once the track is confirmed and the
speed's own sigma is small (``valid_speed_sigma_mps`` or ``valid_speed_sigma_rel`` of the
speed, whichever is larger); its heading is valid once, besides, the velocity's sigma across
its direction on the ground is within the same bound and the heading's sigma within
``VALID_HEADING_SIGMA_DEG``: a track's first estimates often know the speed long before the
direction (two observations of a ball across the view, each a few cm off in depth, give its
speed to 2 % and its heading to 12 deg), and an object slow on the ground, or falling, may
have a speed known to 0.1 m/s and no direction at all.

Lifecycle: ``tentative`` until ``confirm_hits`` observations and a running filter (two
observations no faster than ``max_speed_mps`` apart), then ``confirmed``; a confirmed track
seen moving that has not moved for ``still_after_s`` is ``stationary`` (held out of the
background for ``hold_still_s``, so it stays seen and keeps its id when it moves on); a confirmed
track not seen in a pair is ``coasting`` (predicted) until ``max_coast_s`` has passed, then it
ends. A tentative track ends at its first miss, except that one seen once waits one pair
(still ``tentative``): an object entering the view is small, and one eye may miss it once.
Ids are never reused. All times are seconds computed from timestamps, never frame counts.
"""

from __future__ import annotations

import collections
import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from stereod.tracking import kalman, motion
from stereod.tracking.assignment import min_cost_assignment
from stereod.tracking.skew import image_velocity, shift_to

EyeHistory = collections.deque[tuple[int, np.ndarray]]
"""One eye's 2D track: (capture instant ns, rectified centroid (2,) px), oldest first."""


class TrackLifecycle(str, enum.Enum):
    """Where a track is in its life."""

    TENTATIVE = "tentative"
    """Seen fewer than ``confirm_hits`` times, or never twice at a believable speed: may be
    noise or a mismatch."""
    CONFIRMED = "confirmed"
    """Seen often enough to be a real object, and seen in the latest pair."""
    COASTING = "coasting"
    """Confirmed but not seen in the latest pair: its state is predicted."""
    STATIONARY = "stationary"
    """Confirmed, seen in the latest pair, seen moving before and not for ``still_after_s``:
    an object that stopped (a person sitting, a robot waiting). It is held out of the
    background for ``hold_still_s`` and keeps its id when it moves on."""


@dataclass(frozen=True, slots=True)
class Detection:
    """One object as a matched pair of blobs, in rectified image coordinates (before
    triangulation): ``left_px``/``right_px`` (2,) centroids at each eye's own capture instant,
    ``left_bbox_px``/``right_bbox_px`` (4,) x, y, w, h (image px), ``area_px`` the smaller of
    the two blob areas, and ``image_speed_pxps`` the fastest it can move in the images (px/s)
    at ``max_speed_mps`` and its depth."""

    left_px: np.ndarray
    right_px: np.ndarray
    left_bbox_px: np.ndarray
    right_bbox_px: np.ndarray
    area_px: int
    image_speed_pxps: float
    clipped: bool = False
    """A blob touches the image's left or right border in either eye: part of the object is
    out of view and its centroid and disparity are biased."""
    cut: bool = False
    """A blob touches the image's top or bottom border: its height is unknown, its disparity
    holds (both eyes lose the same rectified rows)."""


@dataclass(frozen=True, slots=True)
class Observation:
    """One object triangulated from one stereo pair.

    ``position_m`` (3,) rig frame; ``cov_m2`` (3, 3); ``left_px``/``right_px`` (2,) measured
    centroids in rectified coordinates (the eyes' 2D tracks); ``left_image_px``/
    ``right_image_px`` the same in image coordinates; ``left_bbox_px``/``right_bbox_px`` (4,)
    x, y, w, h; areas in px; ``disparity_px`` at the common instant; ``size_m`` the blob's
    width in metres (bbox width x Z / f); ``exact``: both eyes were brought to one instant
    (False only for a track's first observation with skew); ``depth_factor``: how much
    deeper the object's centre is than where its silhouettes' centroids triangulate (see
    :func:`stereod.vision.geometry.stereo.silhouette_depth`), so a centre at Z is seen where a
    point at Z / ``depth_factor`` would be. ``row_gap_px``: y_L - y_R of the centroids
    triangulated (rectified px, after any calibrated silhouette shift), or None where they
    were not at one instant or were put on one row by appearance matching (``refine``).
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
    exact: bool = True
    clipped: bool = False
    cut: bool = False
    """Cut by the image's top or bottom edge: its height is unknown (its Y variance says so);
    its X and depth hold."""
    depth_factor: float = 1.0
    edge_depth: bool = False
    """Clipped on one side only, its depth taken from the disparity of its outline's other
    side (:func:`stereod.pipeline.edge_disparity_px`): the filter takes it, its lateral
    position loosely."""
    row_gap_px: float | None = None
    extent_m: tuple[np.ndarray, np.ndarray] | None = None
    """The object's 3D box (min and max corners, m) relative to ``position_m``
    (:func:`stereod.vision.grouping.extent_m`)."""


@dataclass(frozen=True, slots=True)
class TrackerParams:
    """Tracker settings, SI units.

    ``gate_px``: image distance (px, per eye) within which a detection always may join a
    track's prediction; a track that has a velocity adds ``motion_gate`` times how far it
    moved in the image since it was last seen. ``max_speed_mps``: the fastest object to
    follow (m/s); it sets the gate of a track with one observation. ``manoeuvre_chi2``: an
    observation whose squared Mahalanobis distance from the filter's prediction exceeds this
    (3 dof; 16.3 is 99.9 %) widens the prediction until it does not (a fading memory).
    ``accel_noise``: spectral density q of the white acceleration (m^2/s^3).
    ``manoeuvre_sigma_mps``: the velocity sigma of a track before its filter starts.
    ``time_base_s``: tau of eq. 21 (s). ``max_coast_s``: how long (s) a confirmed track lives
    unseen. ``confirm_hits``: observations to confirm. ``valid_speed_sigma_mps``,
    ``valid_speed_sigma_rel``: a velocity is valid once the speed's sigma is below the larger
    of these (m/s; share of the speed), its heading once the sigma across it on the ground is
    too and the heading's within ``VALID_HEADING_SIGMA_DEG``. ``hold_still_s``: how long (s)
    after it was last seen moving an object keeps the background held under it (it stays
    seen, ``stationary``, and keeps its id); after that it is part of the scene.
    ``still_after_s``: an object not seen moving for this long (s) is ``stationary``.
    ``stationary_mps``: below this speed an object is not moving. ``size_gate``: a track's
    gate is at least this share of its blob's size (the square root of its area, px): the
    centre of a person, whose arms and legs swing, wanders by a fifth of their size from one
    frame to the next. ``merge_depth_m``, ``merge_speed_mps``: confirmed tracks that one
    detection holds, at one depth and moving together within these, are pieces of one object
    followed apart, and the longest-followed one takes it. ``gravity_mps2``: gravity
    in the rig frame (m/s^2; Y points down in a level rig); every moving track is filtered
    both as moving straight and as falling freely, and follows the likelier (a thrown ball
    falls 5 mm in one frame at 30 Hz, and a straight-line filter bends its depth to explain
    that); (0, 0, 0) turns this off.
    """

    gate_px: float = 6.0
    motion_gate: float = 0.5
    max_speed_mps: float = 30.0
    manoeuvre_chi2: float = 16.3
    manoeuvre_sigma_mps: float = 2.0
    accel_noise: float = 0.02
    time_base_s: float = 0.5
    max_coast_s: float = 0.5
    confirm_hits: int = 3
    valid_speed_sigma_mps: float = 0.1
    valid_speed_sigma_rel: float = 0.1
    hold_still_s: float = 60.0
    still_after_s: float = 1.0
    size_gate: float = 0.25
    merge_depth_m: float = 0.5
    merge_speed_mps: float = 0.5
    stationary_mps: float = 0.05
    gravity_mps2: tuple[float, float, float] = (0.0, 9.81, 0.0)


VALID_HEADING_SIGMA_DEG = 15.0
"""The largest heading sigma (deg) of a valid heading. Above about 0.4 m/s on the ground the
speed's bound across the motion (0.1 m/s, or 10 % of the speed) is the tighter; slower, this
is: a robot creeping at 3 cm/s has its speed known to 0.1 m/s long before its direction."""


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
    """The speed is known: the track is confirmed and the speed's sigma within the bound."""
    heading_valid: bool
    """The heading is known too: the velocity is valid, its sigma across its direction on the
    ground (the heading's sigma times the ground speed) within the same bound, and the
    heading's sigma within ``VALID_HEADING_SIGMA_DEG``."""
    speed_mps: float
    speed_sigma_mps: float
    heading_deg: float
    heading_sigma_deg: float
    raw_velocity_mps: np.ndarray | None
    age_s: float
    freeze_background: bool
    """Whether the background should not learn under this object now: it was seen moving, and
    has not been stopped for longer than ``hold_still_s``."""
    release_background: bool = False
    """Whether the background should learn this object now: it was seen moving, then stood
    still for ``hold_still_s``; it is part of the scene."""


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
    wait one such pair; see :meth:`Tracker.update`)."""
    last_seen_ns: int = 0
    last_moving_ns: int | None = None
    """When the object was last seen clearly moving (speed above ``stationary_mps`` and three
    sigmas); only an object seen moving holds the background, for ``hold_still_s`` after that
    (a track born still, like a ghost of the background, never does)."""
    stationary: bool = False
    """Whether the track was last reported ``stationary``: standing still, held out of the
    background."""
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


Projector = Callable[[float, float, float, bool], tuple[float, float]]
"""A rig-frame point (x, y, z m) to rectified px (x, y) of the left eye (True) or the right
(False), as :meth:`stereod.vision.geometry.stereo.Rectified.project` does."""


def predict_px(history: EyeHistory, t_ns: int, window_ns: int) -> tuple[np.ndarray, float]:
    """Where one eye's 2D track puts the object at ``t_ns`` (px), and how far (px) it moved
    in the image since its last centroid (0 without a velocity)."""
    t_last, last = history[-1]
    v = image_velocity(history, window_ns)
    if v is None:
        return last, 0.0
    moved = shift_to(last, t_last, v, t_ns)
    return moved, _dist(moved, last)


@dataclass(frozen=True, slots=True)
class Prediction:
    """Where a track should be seen in each eye (px): at ``left`` or anywhere on the segment
    to ``left_far`` (likewise right), and how far that is from where each eye last saw it."""

    left: np.ndarray
    left_far: np.ndarray
    right: np.ndarray
    right_far: np.ndarray
    left_motion: float
    right_motion: float


def _dist(a: np.ndarray, b: np.ndarray) -> float:
    """Distance (px) between two image points (2,) (math on two floats: numpy's per-call
    cost is most of the work on a pair of coordinates)."""
    return math.hypot(float(a[0]) - float(b[0]), float(a[1]) - float(b[1]))


def _motion(a: np.ndarray, b: np.ndarray, last: np.ndarray) -> float:
    """The larger distance (px) of two predictions from the last centroid."""
    return max(_dist(a, last), _dist(b, last))


def _to_segment(point: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance (px) from a point to the segment a-b (a point when a == b)."""
    ax, ay, px, py = float(a[0]), float(a[1]), float(point[0]), float(point[1])
    dx, dy = float(b[0]) - ax, float(b[1]) - ay
    n2 = dx * dx + dy * dy
    t = 0.0 if n2 == 0.0 else min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / n2))
    return math.hypot(px - (ax + t * dx), py - (ay + t * dy))


def _inside(point: np.ndarray, bbox: np.ndarray, grow: float) -> bool:
    x, y, w, h = (float(v) for v in bbox)
    mx, my = grow * w, grow * h
    return bool(x - mx <= point[0] <= x + w + mx and y - my <= point[1] <= y + h + my)


def _moved(bbox: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """A box (x, y, w, h) moved by ``shift`` (2,) px."""
    return np.array([bbox[0] + shift[0], bbox[1] + shift[1], bbox[2], bbox[3]], np.float64)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boxes (x, y, w, h)."""
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = float(a[2] * a[3] + b[2] * b[3]) - inter
    return inter / union if union > 0 else 0.0


def _piece(
    d: Detection, detections: list[Detection], owners: list[int | None], tracks: list[Track]
) -> bool:
    """Whether a detection lies within a larger one of this pair, or within the box of a
    track that was found this pair, in both eyes: a piece of that object, not another."""
    for other in detections:
        if (
            other is not d
            and other.area_px > d.area_px
            and (
                _inside(d.left_px, other.left_bbox_px, 0.0)
                and _inside(d.right_px, other.right_bbox_px, 0.0)
            )
        ):
            return True
    found = {tid for tid in owners if tid is not None}
    return any(
        _inside(d.left_px, tr.last.left_bbox_px, 0.25)
        and _inside(d.right_px, tr.last.right_bbox_px, 0.25)
        for tr in tracks
        if tr.track_id in found
    )


class Tracker:
    """Per pair: :meth:`associate` detections in the images, then :meth:`update` with the
    observations triangulated from them (after skew compensation) and the same assignment."""

    WINDOW_NS = 150_000_000
    """How much of an eye's 2D track its image velocity is fitted over (ns)."""

    def __init__(self, params: TrackerParams, project: Projector | None = None) -> None:
        """``project`` maps a rig-frame point (m) to rectified px in one eye; with it,
        a track whose filter runs is looked for where its 3D prediction projects (which
        follows perspective: an object coming at the camera speeds up in the image), else
        where its image velocity leads."""
        self.params = params
        self._project = project
        self._merging: dict[int, int] = {}
        """Tracks the last :meth:`associate` found to be pieces of another's object (absorbed
        id -> keeper id): they end in :meth:`update` once the keeper is seen."""
        self.line_ns = 0.0
        """How much later a rolling shutter reads each image row than the one above (ns); 0
        for a global shutter (set by the pipeline from ``readout_s``)."""
        g = np.asarray(params.gravity_mps2, dtype=np.float64)
        self._gravity: np.ndarray | None = g if np.any(g != 0.0) else None
        self._tracks: dict[int, Track] = {}
        self._next_id = 1

    def live_ids(self) -> list[int]:
        return list(self._tracks)

    def track(self, track_id: int) -> Track:
        return self._tracks[track_id]

    def associate(
        self, detections: list[Detection], eye_times_ns: tuple[int, int]
    ) -> tuple[list[int | None], list[bool]]:
        """The track each detection belongs to (``None``: none), and whether a detection
        without a track may start one (not a piece of a live object, not two objects merged)."""
        p = self.params
        n = len(detections)
        out: list[int | None] = [None] * n
        may_start = [True] * n
        tracks = list(self._tracks.values())
        self._merging = {}
        if not detections:
            return out, may_start
        if not tracks:
            return out, [not _piece(d, detections, out, []) for d in detections]
        cost = np.full((n, len(tracks)), np.inf)
        inside = np.zeros((2, n, len(tracks)), bool)
        confirmed_j = [self._confirmed(tr) for tr in tracks]
        boxes = []
        for j, tr in enumerate(tracks):
            t_left, t_right = self._row_instants(tr, eye_times_ns)
            pred = self._predict_px(tr, t_left, t_right)
            pl, pr, ml, mr = pred.left, pred.right, pred.left_motion, pred.right_motion
            boxes.append(
                (
                    _moved(tr.last.left_bbox_px, pl - tr.left_history[-1][1]),
                    _moved(tr.last.right_bbox_px, pr - tr.right_history[-1][1]),
                )
            )
            if len(tr.left_history) >= 2 and len(tr.right_history) >= 2:
                gate = p.gate_px + p.motion_gate * max(ml, mr)
            else:
                dt = max(t_left - tr.left_history[-1][0], t_right - tr.right_history[-1][0])
                gate = p.gate_px + tr.image_speed_pxps * dt * 1e-9
            gate = max(gate, p.size_gate * math.sqrt(tr.area_px))
            for i, d in enumerate(detections):
                dist = max(
                    _to_segment(d.left_px, pl, pred.left_far),
                    _to_segment(d.right_px, pr, pred.right_far),
                )
                if dist <= gate:
                    cost[i, j] = dist / gate
                elif confirmed_j[j] and _resumes(d, tr.last):
                    cost[i, j] = RESUME_COST
                inside[0, i, j] = _inside(pl, d.left_bbox_px, 0.0)
                inside[1, i, j] = _inside(pr, d.right_bbox_px, 0.0)
        confirmed = np.array([self._confirmed(tr) for tr in tracks])
        for i, d in enumerate(detections):
            in_left, in_right = inside[0, i] & confirmed, inside[1, i] & confirmed
            if in_left.sum() < 2 and in_right.sum() < 2:
                continue
            hosts = np.flatnonzero(in_left | in_right)
            if self._one_object([tracks[j] for j in hosts]):
                # Pieces of one object that were followed apart (an arm, a torso) now seen
                # whole: the longest-followed track takes it, the others end into it.
                held = [int(h) for h in hosts]
                keeper = max(held, key=lambda h: (tracks[h].hits, -tracks[h].track_id))
                keep = min(cost[i, keeper], RESUME_COST)
                cost[i, :] = np.inf
                cost[i, keeper] = keep
                for h in held:
                    if h != keeper:
                        self._merging[tracks[h].track_id] = tracks[keeper].track_id
                may_start[i] = False
                continue
            # Two objects in one blob, in one eye or both. It is one of them (the other hidden
            # behind it) only if it looks like that one alone: its box where that one's box
            # should be, in both eyes; else a centroid is a blend of both, and both coast
            # until they part in both eyes.
            alone = [
                j
                for j in hosts
                if np.isfinite(cost[i, j])
                and _iou(d.left_bbox_px, boxes[j][0]) >= 0.9
                and _iou(d.right_bbox_px, boxes[j][1]) >= 0.9
            ]
            keep = cost[i, alone[0]] if len(alone) == 1 else np.inf
            cost[i, :] = np.inf
            if len(alone) == 1:
                cost[i, alone[0]] = keep
            may_start[i] = False
        # Confirmed tracks choose first, then tentative ones among what is left: a tentative
        # track seen once has a gate as wide as max_speed_mps allows, so its cost (distance
        # over gate) is small, and it would take a confirmed object's detection from it.
        for group in (confirmed, ~confirmed):
            cols_in = np.flatnonzero(group)
            rows_in = np.array([i for i in range(n) if out[i] is None], np.intp)
            sub = cost[np.ix_(rows_in, cols_in)]
            feasible = np.isfinite(sub)
            if not feasible.any():
                continue
            rows, cols = min_cost_assignment(np.where(feasible, sub, 1e9))
            for i, j in zip(rows, cols, strict=True):
                if feasible[i, j]:
                    out[rows_in[i]] = tracks[cols_in[j]].track_id
        for i, d in enumerate(detections):
            if out[i] is None and may_start[i]:
                may_start[i] = not _piece(d, detections, out, tracks)
        return out, may_start

    def _one_object(self, tracks: list[Track]) -> bool:
        """Whether confirmed tracks that one detection holds are pieces of one object: at one
        depth (within ``merge_depth_m``) and moving together (velocities within
        ``merge_speed_mps``). Two balls crossing at different depths, or two people crossing
        each other's path, are not."""
        p = self.params
        if len(tracks) < 2 or not all(tr.started for tr in tracks):
            return False
        for a in range(len(tracks)):
            for b in range(a + 1, len(tracks)):
                ka, kb = tracks[a].kf, tracks[b].kf
                if abs(float(ka.position_m[2] - kb.position_m[2])) > p.merge_depth_m:
                    return False
                if float(np.linalg.norm(ka.velocity_mps - kb.velocity_mps)) > p.merge_speed_mps:
                    return False
        return True

    def _row_instants(self, tr: Track, eye_times_ns: tuple[int, int]) -> tuple[int, int]:
        """When each eye's rolling shutter reads the rows a track was last seen on (ns): the
        frame's instant plus that row times ``line_ns``."""
        if self.line_ns <= 0.0:
            return eye_times_ns
        rows = (float(tr.last.left_image_px[1]), float(tr.last.right_image_px[1]))
        return (
            eye_times_ns[0] + round(max(rows[0], 0.0) * self.line_ns),
            eye_times_ns[1] + round(max(rows[1], 0.0) * self.line_ns),
        )

    def _predict_px(self, tr: Track, t_left: int, t_right: int) -> Prediction:
        """Where each eye should see a track at its capture instant (px), and how far that is
        from where it last saw it (px). A track whose filter runs: the filter's prediction
        projected. Before that: its image velocity's lead, and with two positions, also the
        line through them projected (a fast object's image motion speeds up, but its first
        position may be off by the eyes' skew): it may be anywhere between the two. A track
        last seen cut by the image's edge (its filter only predicted, its centroid moving with
        the cut) may be anywhere between its filter's projection and its image velocity's
        lead."""
        last_l, last_r = tr.left_history[-1][1], tr.right_history[-1][1]
        far: tuple[np.ndarray, np.ndarray] | None = None
        if self._project is not None and tr.started:
            accel = self._accel(tr.falling)
            at = [kalman.position_at(tr.kf, t, accel) for t in (t_left, t_right)]
            far = self._projected(at[0], at[1], tr.last.depth_factor)
            if far is not None and not tr.last.clipped:
                pl, pr = far
                return Prediction(pl, pl, pr, pr, _motion(pl, pl, last_l), _motion(pr, pr, last_r))
        elif self._project is not None and len(tr.positions) >= 2:
            (t0, p0), (t1, p1) = tr.positions[-2], tr.positions[-1]
            v = (p1 - p0) / ((t1 - t0) * 1e-9)
            at_l, at_r = (p1 + v * ((t - t1) * 1e-9) for t in (t_left, t_right))
            far = self._projected(at_l, at_r, tr.last.depth_factor)
        pl, ml = predict_px(tr.left_history, t_left, self.WINDOW_NS)
        pr, mr = predict_px(tr.right_history, t_right, self.WINDOW_NS)
        pl2, pr2 = far if far is not None else (pl, pr)
        return Prediction(
            pl, pl2, pr, pr2, max(ml, _motion(pl2, pl2, last_l)), max(mr, _motion(pr2, pr2, last_r))
        )

    def _projected(
        self, at_left: np.ndarray, at_right: np.ndarray, depth_factor: float
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Where each eye sees the silhouette's centroid (px) of an object centred at rig-frame
        positions (3,) m at that eye's instant: the centre projected from ``depth_factor``
        times nearer (a 10 cm ball at 1 m, at the edge of a 640 px wide image, is seen 3 px
        further out than its centre projects); ``None`` behind the cameras."""
        xl, yl, zl = at_left.tolist()
        xr, yr, zr = at_right.tolist()
        if self._project is None or zl <= 0 or zr <= 0:
            return None
        left = self._project(xl, yl, zl / depth_factor, True)
        right = self._project(xr, yr, zr / depth_factor, False)
        return np.array(left), np.array(right)

    def histories(self, track_id: int | None) -> tuple[EyeHistory, EyeHistory] | None:
        """A track's two eye histories (for skew compensation), None for no track."""
        if track_id is None:
            return None
        tr = self._tracks[track_id]
        return tr.left_history, tr.right_history

    def update(
        self,
        t_ns: int,
        observations: list[Observation | None],
        assignment: list[int | None],
        eye_times_ns: tuple[int, int],
        detections: list[Detection],
        blob_times_ns: list[tuple[int, int]] | None = None,
    ) -> tuple[list[TrackState], list[int]]:
        """Fold in one pair's observations at ``t_ns`` (``None`` in ``observations`` is a
        detection that neither joins nor starts a track); ``eye_times_ns`` are the left and
        right capture instants of the frames, and ``blob_times_ns`` each detection's own (a
        rolling shutter reads its rows later; default: the frames'). Returns the state of
        every live track (observed or coasting) and the ids of the tracks that ended. A track
        whose filter puts it behind the rig (Z <= 0, where no camera sees) ends there: its
        filter has lost the object, and what it would publish means nothing."""
        p = self.params
        seen: set[int] = set()
        states: list[TrackState] = []
        ended: list[int] = []
        times = blob_times_ns if blob_times_ns is not None else [eye_times_ns] * len(detections)
        for ob, tid, det, (t_left, t_right) in zip(
            observations, assignment, detections, times, strict=True
        ):
            if ob is None:
                continue
            if tid is None:
                kf = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.manoeuvre_sigma_mps)
                tr = Track(
                    self._next_id,
                    first_t_ns=t_ns,
                    kf=kf,
                    last=ob,
                    image_speed_pxps=det.image_speed_pxps,
                    area_px=float(det.area_px),
                    last_seen_ns=t_ns,
                )
                self._next_id += 1
                self._tracks[tr.track_id] = tr
                self._begin(tr, t_ns, ob)
            else:
                tr = self._tracks[tid]
                if not tr.started:
                    self._begin(tr, t_ns, ob)
                elif ob.clipped and not ob.edge_depth:  # part of it out of view: predicted
                    self._predict(tr, t_ns)
                else:
                    self._filter(tr, t_ns, ob)
                tr.hits += 1
                tr.misses = 0
                tr.last = ob
                tr.last_seen_ns = t_ns
                tr.image_speed_pxps = det.image_speed_pxps
                tr.area_px = 0.8 * tr.area_px + 0.2 * det.area_px
            if not ob.clipped:
                tr.positions.append((t_ns, ob.position_m))
            tr.left_history.append((t_left, ob.left_px))
            tr.right_history.append((t_right, ob.right_px))
            seen.add(tr.track_id)
            if _behind(tr):
                ended.append(tr.track_id)
                del self._tracks[tr.track_id]
            elif tr.started or tr.whole:  # a track seen only cut by the image's edge is quiet
                states.append(self._state(tr, t_ns, observed=True))
        coast_ns = int(p.max_coast_s * 1e9)
        for tid, keeper in self._merging.items():
            if tid in self._tracks and tid not in seen and keeper in seen:
                ended.append(tid)  # a piece of the keeper's object, now seen whole
                del self._tracks[tid]
        self._merging = {}
        for tid, tr in list(self._tracks.items()):
            if tid in seen:
                continue
            tr.misses += 1
            if not self._confirmed(tr):
                # An object entering the view is small, and one eye may miss it once: a track
                # seen once waits one pair for it. Any other tentative track ends unseen (a
                # blob that flickers on and off never gathers the hits to be confirmed).
                if tr.hits > 1 or tr.misses > 1:
                    ended.append(tid)
                    del self._tracks[tid]
                elif tr.started or tr.whole:
                    states.append(self._state(tr, t_ns, observed=False))
            elif t_ns - tr.last_seen_ns > coast_ns:
                ended.append(tid)
                del self._tracks[tid]
            else:
                self._predict(tr, t_ns)
                if _behind(tr):
                    ended.append(tid)
                    del self._tracks[tid]
                elif tr.started or tr.whole:
                    states.append(self._state(tr, t_ns, observed=False))
        return states, ended

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
        tr.fall_evidence = self.FALL_MEMORY * tr.fall_evidence + gain
        if tr.falling != (tr.fall_evidence > 0.0) and abs(tr.fall_evidence) > self.FALL_SWITCH:
            tr.kf, tr.other = tr.other, tr.kf
            tr.falling = not tr.falling

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
        """A track before its filter runs. A clipped observation only places it. The first
        whole one after that starts the eyes' 2D histories afresh (so what follows is brought
        to one instant with clean image motion) and places it too. The first exact whole one
        (both eyes at one instant) is kept, and the next exact one starts the filter from the
        two: eq. 21 over one frame. Without skew the first two whole observations do; with
        skew the first cannot be brought to one instant, and the filter starts one frame
        later rather than from a guessed position. Two observations further apart than
        ``max_speed_mps`` allows (beyond three sigmas of their noise along the step) are not
        one object moving: the newer one is kept instead."""
        p = self.params
        if ob.clipped or not tr.whole:
            tr.whole = not ob.clipped
            tr.first = None
            if tr.whole:
                tr.left_history.clear()
                tr.right_history.clear()
                tr.positions.clear()
        if ob.clipped or not ob.exact or tr.first is None:
            tr.kf = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.manoeuvre_sigma_mps)
            if not ob.clipped and ob.exact:
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
        tr.positions.clear()
        tr.positions.append((t0, ob0.position_m))

    def _confirmed(self, tr: Track) -> bool:
        """Seen ``confirm_hits`` times, and its filter runs."""
        return tr.started and tr.hits >= self.params.confirm_hits

    def continue_after(self, other: Tracker) -> None:
        """Number new tracks after ``other``'s, so ids are never reused while running."""
        self._next_id = max(self._next_id, other._next_id)

    def end_all(self) -> list[int]:
        """End every live track (end of input); return their ids."""
        ids = list(self._tracks)
        self._tracks.clear()
        return ids

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
        # The direction: across it within the speed's bound, and a heading sigma within
        # VALID_HEADING_SIGMA_DEG (the speed's absolute floor would otherwise give anything
        # slow on the ground, or falling, a "known" direction).
        heading_valid = valid and across <= bound and heading_sigma <= VALID_HEADING_SIGMA_DEG
        # Seen moving: confirmed, and its speed clearly above nil (three sigmas), even where
        # the velocity is too uncertain to publish as valid (a walking person's centre jumps
        # as arms and legs swing, and their speed's sigma stays above the valid bound).
        if started and confirmed and spd > max(p.stationary_mps, 3.0 * spd_sigma):
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


RESUME_COST = 0.99
"""The association cost (of at most 1, the gate's edge) of a stationary track and a
detection it did not predict that overlaps where it stood (:func:`_resumes`): the worst
acceptable, so any detection the track's prediction explains is preferred."""
RESUME_IOU = 0.3
"""How much a detection's box must overlap a stationary track's last box, in each eye, to be
that object moving on (a person or robot starting off moves a fraction of its size in a
frame; a ball 17 px across that sets off at 0.4 m/s, 7 px a frame, keeps 0.4)."""


def _resumes(d: Detection, last: Observation) -> bool:
    """Whether a detection overlaps a stationary track's last boxes in both eyes enough to be
    the object setting off again: it stood still, so its filter predicts it where it was, and
    the first step of a start can lie outside the gate of an object at rest."""
    return (
        _iou(d.left_bbox_px, last.left_bbox_px) >= RESUME_IOU
        and _iou(d.right_bbox_px, last.right_bbox_px) >= RESUME_IOU
    )


def _behind(tr: Track) -> bool:
    """Whether a track's running filter puts it behind the rig (Z <= 0 m). Before the filter
    runs a track's position is its first sight, which for a fast object seen with the eyes'
    skew may well lie there; that only places it."""
    return tr.started and not float(tr.kf.position_m[2]) > 0.0
