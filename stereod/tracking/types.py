"""The tracker's data: its settings (``TrackerParams``), a track's lifecycle, a detection in
the images, an observation triangulated from it, and a track's reported state."""

from __future__ import annotations

import collections
import enum
from dataclasses import dataclass

import numpy as np

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
    """Confirmed, seen in the latest pair, seen moving before (or parted from an object seen
    moving then) and not for ``still_after_s``:
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
    uncovered: bool = False
    """Both blobs are background a moved object uncovered (along their outlines the background
    model has edges the frame lacks: :mod:`stereod.vision.uncovered`): no track takes it or
    starts on it."""


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

    ``gate_px``: image distance (px, per eye) within which a detection always may join a track's
    prediction; a track that has a velocity adds ``motion_gate`` times how far it moved in the
    image since it was last seen (unseen in the last pair: at most as far as its image
    velocity carries it, whatever its filter predicts). ``max_speed_mps``: the fastest object
    to follow (m/s); it sets the gate of a track with one observation. ``manoeuvre_chi2``: an
    observation whose squared Mahalanobis distance from the filter's prediction exceeds this
    (3 dof; 16.3 is 99.9 %) widens the prediction until it does not (a fading memory).
    ``accel_noise``: spectral density q of the white acceleration (m^2/s^3).
    ``manoeuvre_sigma_mps``: the velocity sigma of a track before its filter starts.
    ``time_base_s``: tau of eq. 21 (s). ``max_coast_s``: how long (s) a confirmed track lives
    unseen. ``max_hidden_s``: how long (s) it lives unseen
    while each eye sees a blob where it should be (a person walking behind another, or in one
    blob with them through a crossing); at least ``max_coast_s``. ``confirm_hits``: observations
    to confirm. ``valid_speed_sigma_mps``, ``valid_speed_sigma_rel``: a velocity is valid once
    the speed's sigma is below the larger of these (m/s; share of the speed), its heading once
    the sigma across it on the ground is too and the heading's within
    ``VALID_HEADING_SIGMA_DEG``. ``hold_still_s``: how long (s) after it was last seen moving an
    object keeps the background held under it (it stays seen, ``stationary``, and keeps its id);
    after that it is part of the scene (120 s: twice the longest stop the people scenes make, so
    a person who stands a minute leaves no ghost of the floor behind them). ``still_after_s``:
    an object not seen moving for this long (s) is ``stationary``. ``stationary_mps``: below
    this speed an object is not moving. ``size_gate``: a track's gate is at least this share of
    its blob's size (the square root of its area, px): the centre of a person, whose arms and
    legs swing, wanders by a fifth of their size from one frame to the next. ``merge_depth_m``,
    ``merge_speed_mps``: confirmed tracks that one detection holds, at one depth and moving
    together within these, are pieces of one object followed apart, and the longest-followed one
    takes it. ``max_member_s``: how long (s) a track so taken into another's object is kept as a
    member of it (not published, not ended): a blob that would start a track, coming out of
    that object's blob, takes the member's id (a box a robot pushed for two seconds, then left);
    a member not seen again by then ends. ``gravity_mps2``: gravity in the rig frame (m/s^2; Y
    points down in a level rig); every moving track is filtered both as moving straight and as
    falling freely, and follows the likelier (a thrown ball falls 5 mm in one frame at 30 Hz,
    and a straight-line filter bends its depth to explain that); (0, 0, 0) turns this off.
    """

    gate_px: float = 6.0
    motion_gate: float = 0.5
    max_speed_mps: float = 30.0
    manoeuvre_chi2: float = 16.3
    manoeuvre_sigma_mps: float = 2.0
    accel_noise: float = 0.02
    time_base_s: float = 0.5
    max_coast_s: float = 0.5
    max_hidden_s: float = 2.0
    confirm_hits: int = 3
    valid_speed_sigma_mps: float = 0.1
    valid_speed_sigma_rel: float = 0.1
    hold_still_s: float = 120.0
    still_after_s: float = 1.0
    size_gate: float = 0.25
    merge_depth_m: float = 0.5
    merge_speed_mps: float = 0.5
    max_member_s: float = 5.0
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
