"""Sub-pixel centres of one object (eq. 5 over its support): edge pixels weighted by a ramp of
eq. 4's difference, or by the share of them the object covers, solved from the colours."""

from __future__ import annotations

import functools

import cv2
import numpy as np

from stereod.vision import row_disparity

_RING = np.ones((3, 3), np.uint8)


@functools.lru_cache(maxsize=8)
def _ramp(threshold: float) -> np.ndarray:
    """The edge weight of each difference d = 0..255 (float32): (d - t/2) / t clipped to
    [0, 1], so 0 below t/2 and 1 from 3t/2."""
    d = np.arange(256, dtype=np.float32)
    return np.clip((d - 0.5 * threshold) * (1.0 / threshold), 0.0, 1.0).astype(np.float32)


def _padded(
    support: np.ndarray, origin: tuple[int, int], shape: tuple[int, ...]
) -> tuple[int, int, int, int, np.ndarray, np.ndarray]:
    """A blob's support at ``origin`` (x, y) of an image of ``shape``, grown by one pixel
    each way within it: its rectangle (x0, y0, x1, y1), the support there (uint8) and its
    interior (the support eroded by one pixel)."""
    x, y = origin
    bh, bw = support.shape
    H, W = shape[0], shape[1]
    x0, y0 = max(x - 1, 0), max(y - 1, 0)
    x1, y1 = min(x + bw + 1, W), min(y + bh + 1, H)
    own = cv2.copyMakeBorder(
        support, y - y0, y1 - y - bh, x - x0, x1 - x - bw, cv2.BORDER_CONSTANT, value=0
    )
    return x0, y0, x1, y1, own, cv2.erode(own, _RING)


def coverage_centroid(
    support: np.ndarray,
    diff: np.ndarray,
    origin: tuple[int, int],
    threshold: float,
    rows_out: list[np.ndarray] | None = None,
) -> tuple[float, float]:
    """Sub-pixel centre of one object (px): eq. 5 over its support, with eq. 4's hard
    threshold softened into a ramp at the edge. Interior pixels (the support eroded by one
    pixel) weigh 1 whatever their difference, so shading inside the object, or a patch of it
    that matches the background, does not pull the centre; each pixel of the edge band (one
    pixel either side of the outline) weighs (d - t/2) / t clipped to [0, 1], the share of it
    the object covers. ``support`` is (h, w) uint8 at ``origin`` (x, y) of ``diff``;
    ``rows_out``, if given, gets the weights' row profile (:mod:`row_disparity`, px of
    ``diff``) appended."""
    x, y = origin
    bh, bw = support.shape
    x0, y0, x1, y1, own, inner = _padded(support, origin, diff.shape)
    band = cv2.dilate(own, _RING)
    ramp = _ramp(threshold)
    edge = cv2.bitwise_and(diff[y0:y1, x0:x1], band)
    if ramp[255] == 1.0:  # t <= 170: a difference of 255 weighs 1, as the interior must
        weight = cv2.LUT(cv2.bitwise_or(edge, inner), ramp)
    else:
        weight = cv2.LUT(edge, ramp)
        cv2.copyTo(np.ones(weight.shape, np.float32), inner, weight)
    if rows_out is not None:
        rows_out.append(row_disparity.profile(weight, x0, y0))
    m = cv2.moments(weight)
    if m["m00"] <= 0:
        return (x + (bw - 1) / 2.0, y + (bh - 1) / 2.0)
    return (x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"])


_MATTE_MIN_INTERIOR = 12
"""Fewest interior pixels (the support eroded by one pixel) a blob needs for matting: in a
smaller one (about 4 x 4 px or less) the interior pixels are themselves partly background, so
they do not give the object's colour, and the ramp is used instead."""
_ONES3 = np.ones((1, 3), np.float32)


def matte_centroid(
    support: np.ndarray,
    frame: np.ndarray,
    background: np.ndarray,
    diff: np.ndarray,
    origin: tuple[int, int],
    threshold: float,
    rows_out: list[np.ndarray] | None = None,
) -> tuple[float, float]:
    """Sub-pixel centre of one object (px): eq. 5 over its support, interior pixels (the
    support eroded by one pixel) weighing 1 and each pixel of the edge band (one pixel either
    side of the outline) the share a of it the object covers. A pixel the object covers in
    part mixes the object's colour o and the background's b: f = a o + (1 - a) b, so
    a = (f - b).(o - b) / |o - b|^2 over the channels (least squares; with one channel, the
    ratio), with b the stored background there and o the mean of the interior pixels within
    two pixels. Unlike the ramp of :func:`coverage_centroid`, this does not depend on how far
    the object's colour is from the background's, which differs between the eyes (each sees
    the object against another patch of background). Where the object is too close to the
    background (|o - b| under half of eq. 4's threshold per channel) or no interior pixel is
    near, the ramp is used; a blob with fewer than ``_MATTE_MIN_INTERIOR`` interior pixels is
    left to :func:`coverage_centroid`. ``support`` is (h, w) uint8 at ``origin`` (x, y) of
    the (H, W[, 3]) uint8 ``frame``, ``background`` (at the frame's gain) and eq. 4's
    ``diff``; ``rows_out`` as for :func:`coverage_centroid`."""
    x, y = origin
    bh, bw = support.shape
    x0, y0, x1, y1, own, inner = _padded(support, origin, diff.shape)
    if cv2.countNonZero(inner) < _MATTE_MIN_INTERIOR:
        return coverage_centroid(support, diff, origin, threshold, rows_out)
    band = cv2.dilate(own, _RING)
    ramp = _ramp(threshold)
    weight = cv2.LUT(cv2.bitwise_and(diff[y0:y1, x0:x1], band), ramp)
    f = frame[y0:y1, x0:x1]
    b = background[y0:y1, x0:x1]
    # the object's colour near each pixel: the mean of the interior pixels within two pixels
    near = (5, 5)
    count = cv2.boxFilter(inner, cv2.CV_32F, near, normalize=False, borderType=cv2.BORDER_CONSTANT)
    total = cv2.boxFilter(
        cv2.bitwise_and(f, f, mask=inner),
        cv2.CV_32F,
        near,
        normalize=False,
        borderType=cv2.BORDER_CONSTANT,
    )
    count *= np.float32(1.0 / 255.0)  # interior pixels are 255
    found = count > 0.5
    np.maximum(count, 1.0, out=count)
    o: np.ndarray = total / (count[..., None] if f.ndim == 3 else count)
    ob, fb = o - b, np.subtract(f, b, dtype=np.float32)  # (exact in float32)
    if f.ndim == 3:
        num, den = cv2.transform(fb * ob, _ONES3), cv2.transform(ob * ob, _ONES3)
        channels = 3
    else:
        num, den = fb * ob, ob * ob
        channels = 1
    usable = found & (den >= channels * (0.5 * threshold) ** 2) & (band > 0)
    np.divide(num, den, out=weight, where=usable)  # the ramp's weight where it is not usable
    np.maximum(weight, 0.0, out=weight)  # clipped to [0, 1] (np.clip costs more a call)
    np.minimum(weight, 1.0, out=weight)
    np.putmask(weight, inner, 1.0)
    if rows_out is not None:
        rows_out.append(row_disparity.profile(weight, x0, y0))
    m = cv2.moments(weight)
    if m["m00"] <= 0:
        return (x + (bw - 1) / 2.0, y + (bh - 1) / 2.0)
    return (x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"])
