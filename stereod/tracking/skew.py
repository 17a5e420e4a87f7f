"""Skew compensation: bring both eyes' blob centroids to one instant before triangulating.

The Minoru's eyes free-run, so the two frames of a pair are up to half a frame period apart
(design sec. 7); an object moving sideways at 1 m/s moves 17 mm in 16.7 ms, a disparity error
that becomes a 28 % depth error at typical range. The later eye's centroid is brought back to
the earlier eye's capture instant, which becomes the measurement's time: that eye saw the
object one frame before, and that earlier frame and this one bracket the instant, so the
centroid there is interpolated between two measurements, not extrapolated from a fitted
velocity. Only past frames are used, so compensation adds no latency.

Interpolation follows the projection, not a straight line. An object moving at a constant
velocity has X, Y and Z linear in time, so each image coordinate ``f X / Z + c`` is a
fractional-linear (Moebius) function of time, which three samples determine; a straight line
through two samples misses it wherever Z changes fast (a ball thrown at the camera at 10 m/s
seen at 15 Hz: 0.3 to 2 px of disparity, 4 to 14 % of its speed). With three frames of the
eye whose samples move monotonically, the coordinate is the Moebius function through them
(its cross-ratio with time is preserved), which then lies between the two bracketing samples;
otherwise, or when its motion per frame barely changed (the curve would only add the third
sample's noise), the straight line. With only the two bracketing frames (a track's second
sight), the curve is the two samples mixed in homogeneous coordinates, weighted by the
object's depth at each, whose ratio the blob's size in that eye gives where it changed beyond
its noise, once its angle off the axis is taken out (:func:`size_depth_ratio`,
:func:`projective_weight`); a ball thrown across or at the rig at 20 m/s and seen
at 15 Hz is then placed within a few cm at its second frame, not 0.3 to 1.5 m off, and is
tracked from there. Without the earlier frame (it was dropped), the eye's image
velocity over its 2D track moves it.

This is the one stage every detection passes through, once, after it was associated with a
track in the images (:meth:`stereod.tracking.tracker.Tracker.associate`, which needs no compensation
since it compares each eye at its own instant) and before it is triangulated.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from stereod.tracking.motion import fit_velocity


def image_velocity(history: Sequence[tuple[int, np.ndarray]], max_age_ns: int) -> np.ndarray | None:
    """Least-squares image velocity (2,) px/s of one eye's centroids (t_ns, (2,) px), using the
    samples no older than ``max_age_ns`` before the newest, or the newest two when fewer are
    that recent (after the object was hidden for a while); ``None`` with fewer than two."""
    if len(history) < 2:
        return None
    t_last = history[-1][0]
    recent = [(t, c) for t, c in history if t_last - t <= max_age_ns]
    if len(recent) < 2:
        recent = list(history)[-2:]
    t = np.array([(t - t_last) * 1e-9 for t, _ in recent])
    p = np.zeros((len(recent), 3))
    p[:, :2] = [c for _, c in recent]
    v, _ = fit_velocity(t, p)
    return v[:2]


def common_instant(t_left_ns: int, t_right_ns: int) -> int:
    """The instant both eyes are brought to: the earlier capture (the later eye's previous
    frame and this one bracket it)."""
    return min(t_left_ns, t_right_ns)


def at_instant(
    history: EyeTrack,
    t_ns: int,
    centroid_px: np.ndarray,
    target_ns: int,
    window_ns: int,
    depth_ratio: float | None = None,
) -> np.ndarray | None:
    """One eye's centroid (2,) px taken at ``t_ns`` brought to ``target_ns``: interpolated
    with its previous centroid when that is at or before the target (with only that one,
    along the projection of a straight path whose depth changed by ``depth_ratio``, Z now
    over Z then, when known: :func:`projective_weight`), else moved along the eye's image
    velocity; ``None`` when the eye has no history to do either."""
    if t_ns == target_ns:
        return centroid_px
    if history:
        t0, c0 = history[-1]
        if t0 <= target_ns < t_ns:
            if len(history) >= 2 and t_ns - history[-2][0] <= window_ns:
                ta, ca = history[-2]
                return moebius((ta, t0, t_ns), (ca, c0, centroid_px), target_ns)
            w = projective_weight((target_ns - t0) / (t_ns - t0), depth_ratio)
            return c0 + (centroid_px - c0) * w
    v = image_velocity([*history, (t_ns, centroid_px)], window_ns)
    return None if v is None else shift_to(centroid_px, t_ns, v, target_ns)


SIZE_NOISE = 1.0
"""A blob's area wobbles by its outline's jitter, so half the log of a ratio of two of its
sizes (the log of the depth ratio) wobbles by about k / sqrt(A) for a blob of A px. Measured
against the true depths on the independent renderer's thrown balls
(``benchmarks/size_noise.py``), k has a standard deviation of 0.18 to 0.37 and a 95th
percentile of 0.38 to 0.73 by mode, the most at 320x240, 60 deg, where a ball is 4 to 8 px
across (largest 1.15). A depth change is taken from sizes only beyond ``SIZE_NOISE /
sqrt(A)`` (0.13 for a 56 px blob): at 0.75 a ball crossing at 20 m/s was read as coming 10 %
closer between two frames, and placed 0.5 m short. The pipeline's test for a part of an
object lost in one eye allows the same noise
(:func:`stereod.vision.geometry.errors.segmentation_error_px`)."""


def size_depth_ratio(
    area_then_px: float,
    area_now_px: float,
    cos_then: float = 1.0,
    cos_now: float = 1.0,
    max_change: float = math.inf,
) -> float | None:
    """Z now over Z then of one object from its blob's areas in one eye at two instants, seen
    at angles whose cosines from the optical axis are ``cos_then`` and ``cos_now``: a ball's
    image area goes as 1 / (Z^2 cos), its image stretched along the ray off the axis. ``None``
    when the sizes do not differ beyond their noise (``SIZE_NOISE``), when the ratio is
    further from 1 than ``max_change`` (faster in depth than any object followed: a blob that
    merged, split or was partly hidden), or without two areas."""
    if area_then_px <= 0 or area_now_px <= 0:
        return None
    log_ratio = 0.5 * math.log((area_then_px * cos_then) / (area_now_px * cos_now))
    if abs(log_ratio) <= SIZE_NOISE / math.sqrt(min(area_then_px, area_now_px)):
        return None
    ratio = math.exp(log_ratio)
    return ratio if abs(ratio - 1.0) <= max_change else None


def projective_weight(w: float, depth_ratio: float | None) -> float:
    """The share ``w`` of the time from one sample to the next, as a share of the image
    motion between them. An object moving straight at a constant velocity has X and Z, so
    also Z x (x = f X / Z + c), linear in time: in homogeneous coordinates the image point is
    the samples' mix
    weighted by their depths: ``w r / ((1 - w) + w r)`` with ``r`` = Z at the second over Z at
    the first (a ball thrown at the camera, 20 m/s at 15 Hz: 1.1 px of disparity against 0.1).
    An unknown depth change leaves ``w`` as it is."""
    if depth_ratio is None:
        return w
    return w * depth_ratio / ((1.0 - w) + w * depth_ratio)


MOEBIUS_MIN_CHANGE_PX = 0.5
"""How much a coordinate's motion per frame must change between the last two intervals (px)
before the fractional-linear curve is used instead of the line. The change is a second
difference, sqrt(6) times one centroid's error: 0.12 px for a ball centred by the disc fit,
so noise alone never takes the curve there, and 0.37 px at ``centroid_sigma_px`` (0.15 px),
where it takes it in about one frame in six and adds about 0.02 px rms to the interpolated
centroid. At 1.0 px a ball thrown at the rig (20 m/s, 4 m off, 320x240 at 30 Hz) was
interpolated along the line while its image motion grew from 2.5 to 3.5 px a frame, 0.1 px
of disparity off; over every cell of ``make accuracy`` 0.5 px did better (heading error
median 0.050 to 0.040 deg, speed error mean 0.25 to 0.22 %)."""


def moebius(
    times_ns: tuple[int, int, int], centroids_px: tuple[np.ndarray, ...], target_ns: int
) -> np.ndarray:
    """Each coordinate of three centroids (2,) px taken at increasing ``times_ns``, evaluated
    at ``target_ns`` in [t1, t2] on the fractional-linear curve through them (exact for an
    object at constant 3D velocity); a coordinate whose samples do not move monotonically
    (noise on a slow object), or whose motion per frame changed by at most
    ``MOEBIUS_MIN_CHANGE_PX``, is interpolated linearly between the last two."""
    ta, tb, tc = times_ns
    w = (target_ns - tb) / (tc - tb)
    a, b, c = (np.asarray(x, dtype=np.float64) for x in centroids_px)
    out = b + (c - b) * w
    # cross-ratio of the times: (t - ta)(tb - tc) / ((t - tc)(tb - ta)), finite since t < tc
    k = ((target_ns - ta) * (tb - tc)) / ((target_ns - tc) * (tb - ta))
    rise, run = b - a, c - b
    # The curve only where the image motion clearly changed between the two intervals (a
    # third sample otherwise adds its noise and nothing else).
    change = np.abs(run - rise * ((tc - tb) / (tb - ta)))
    curved = (rise * run > 0.0) & (change > MOEBIUS_MIN_CHANGE_PX)
    den = run + k * rise
    ok = curved & (np.abs(den) > 1e-12)
    out[ok] = ((a * run + k * c * rise) / np.where(ok, den, 1.0))[ok]
    return out


def shift_to(
    centroid_px: np.ndarray, t_ns: int, velocity_pxps: np.ndarray | None, target_ns: int
) -> np.ndarray:
    """Centroids (2,) or (n, 2) px taken at ``t_ns`` moved along ``velocity_pxps`` to
    ``target_ns``."""
    if velocity_pxps is None or t_ns == target_ns:
        return centroid_px
    return centroid_px + velocity_pxps * ((target_ns - t_ns) * 1e-9)


EyeTrack = Sequence[tuple[int, np.ndarray]]


def compensate(
    histories: tuple[EyeTrack, EyeTrack] | None,
    left_px: np.ndarray,
    right_px: np.ndarray,
    eye_times_ns: tuple[int, int],
    target_ns: int,
    window_ns: int,
    depth_ratios: tuple[float | None, float | None] = (None, None),
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Both eyes' centroids (2,) px brought to ``target_ns`` (:func:`at_instant`) with their
    track's 2D history in that eye, and how much its depth changed since that eye last saw it
    (``depth_ratios``, left and right: :func:`size_depth_ratio`). Returns the two centroids
    and whether they now refer to one instant (False when an eye had no history to bring it
    there)."""
    t_left, t_right = eye_times_ns
    if t_left == t_right == target_ns:
        return left_px, right_px, True
    if histories is None:
        return left_px, right_px, False
    left = at_instant(histories[0], t_left, left_px, target_ns, window_ns, depth_ratios[0])
    right = at_instant(histories[1], t_right, right_px, target_ns, window_ns, depth_ratios[1])
    exact = left is not None and right is not None
    return (
        left_px if left is None else left,
        right_px if right is None else right,
        exact,
    )
