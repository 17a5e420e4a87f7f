"""A small round blob's centre from a disc fitted to the image, not to its segmentation.

A ball a few pixels across is where eq. 5's centroid errs most: where part of the ball is as
bright and coloured as the background behind it, the thresholded support (eq. 4) loses that
part, and so does the centroid of :func:`stereod.vision.centroids.matte_centroid`, by 0.1-0.3 px,
and differently in each eye (each sees the ball against another patch of background), which is
0.2 px of disparity and centimetres of depth. A disc is fitted instead to every pixel around
the blob: each pixel is modelled as a f = a o + (1 - a) b, with a the share of it a disc of
centre c and radius r covers, b the stored background and o the object's colour, a smooth
function of position (shading) fitted along. Where o is close to b a pixel says little about
the edge and weighs little in the fit by itself, so the disc's centre comes from the parts of
its outline that can be seen, in both eyes alike.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

PAD_PX = 2
"""Pixels of background around the blob's box that the fit sees."""
_ITERATIONS = 6
_CONVERGED_PX = 5e-3
"""The fit stops when its centre moves less than this (px)."""
_MAX_SHIFT_PX = 1.0
"""A fit whose centre moves further than this from the blob's centroid is not trusted."""
_RADIUS_TOLERANCE = 0.3
"""A fit whose radius differs by more than this share (plus half a pixel) from the support's
equivalent radius is not trusted."""
_FILL = (0.65, 0.97)
"""A disc covers pi/4 = 0.785 of its box, and up to 0.95 when a few pixels across (its outline
is drawn through the edge pixels' centres); a larger support outside this range is not
round."""
_ASPECT = 0.7
"""A support whose box is narrower than this ratio either way is not round."""
_SMALL_PX = 7
"""A support at most this many pixels across is drawn by a handful of pixels: a disc 4 px
across fills its whole box, and a pixel more or less on one side moves its aspect by a
quarter, so there a fill of ``_FILL[0]`` and sides within ``_SMALL_ASPECT`` are enough. At
that size a ball's support and a half disc's look alike (4 x 6 px, filled 0.92, nearly
symmetric): the fit takes both for a ball, which is right for what this daemon follows and
puts a small half disc's centre 0.4 px off (rms) where the matte puts it 0.15 px off. A box
that small is centred by the fit as well as by its outline: both are symmetric."""
_SMALL_ASPECT = 0.6


def coverage(s: np.ndarray, nx: np.ndarray, ny: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Share of a unit pixel on the inner side of a straight edge at signed distance ``s``
    (px, positive when the pixel's centre is inside) with unit normal (``nx``, ``ny``), and its
    derivative in ``s``: linear while the edge crosses two opposite sides of the pixel,
    quadratic while it cuts off a corner (closed form for a square and a half-plane)."""
    ax, ay, d = np.abs(nx), np.abs(ny), np.abs(s)
    a, b = np.maximum(ax, ay), np.minimum(ax, ay)
    linear = d <= (a - b) / 2
    corner = np.maximum((a + b) / 2 - d, 0.0)
    ab = np.maximum(a * b, 1e-9)
    tail = corner * corner / (2 * ab)
    share = np.where(linear, 0.5 + s / a, np.where(s > 0, 1.0 - tail, tail))
    slope = np.where(linear, 1.0 / a, corner / ab)
    return share, slope


@functools.lru_cache(maxsize=64)
def _grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (px) of each pixel of a (height, width) window, row by row: the same
    few window sizes come back frame after frame (read only)."""
    ys, xs = np.divmod(np.arange(width * height, dtype=np.float64), float(width))
    xs.setflags(write=False)
    ys.setflags(write=False)
    return xs, ys


def _least_squares(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The x that minimises |a x - y| (columns of ``y`` apart): through the normal equations
    (OpenCV's LU), a fraction of an SVD's time on the fit's well-posed systems, and by SVD where
    they are singular."""
    solved, x = cv2.solve(a.T @ a, a.T @ y)
    if solved:
        return np.asarray(x)
    return np.linalg.lstsq(a, y, rcond=None)[0]


def is_round(support: np.ndarray, area: int) -> bool:
    """Whether a blob's support (h, w) of ``area`` px is shaped like a disc: its box nearly
    square and filled about pi/4 (a box or an upright cylinder fills its box, and so does a
    disc a few pixels across: below ``_SMALL_PX`` a full box is round too, and so is one a
    row longer than wide)."""
    h, w = support.shape
    fill = area / float(h * w)
    aspect = min(w, h) / max(w, h)
    if max(h, w) <= _SMALL_PX:
        return aspect >= _SMALL_ASPECT and fill >= _FILL[0]
    return aspect >= _ASPECT and _FILL[0] <= fill <= _FILL[1]


def disc_centre(
    frame: np.ndarray,
    background: np.ndarray,
    box: tuple[int, int, int, int],
    centre: tuple[float, float],
    area: int,
) -> tuple[float, float] | None:
    """Centre (x, y px) of the disc that best explains the (H, W[, 3]) uint8 ``frame`` around
    a blob's ``box`` (x, y, w, h px) against the ``background`` (at the frame's gain), started
    from the blob's ``centre`` and the radius of a disc of ``area`` px; None where the box
    with its margin leaves the image or the fit is not to be trusted (it moved more than a
    pixel, or its radius is not the blob's). Gauss-Newton over the centre, the radius and the
    object's colour (per channel: a quadratic in position plus the sphere's sqrt(1 - rho^2),
    which holds a Lambertian ball's shading)."""
    x, y, w, h = box
    height, width = frame.shape[:2]
    x0, y0, x1, y1 = x - PAD_PX, y - PAD_PX, x + w + PAD_PX, y + h + PAD_PX
    if x0 < 0 or y0 < 0 or x1 > width or y1 > height:
        return None
    n = (y1 - y0) * (x1 - x0)
    f = frame[y0:y1, x0:x1].reshape(n, -1).astype(np.float64)
    b = background[y0:y1, x0:x1].reshape(f.shape).astype(np.float64)
    channels = f.shape[1]
    xs, ys = _grid(x1 - x0, y1 - y0)
    r0 = math.sqrt(area / math.pi)
    cx0, cy0 = centre[0] - x0, centre[1] - y0
    u, v = (xs - cx0) / r0, (ys - cy0) / r0
    k = 7
    basis = np.empty((n, k))
    basis[:, 0] = 1.0
    basis[:, 1], basis[:, 2] = u, v
    np.sqrt(np.maximum(1.0 - u * u - v * v, 0.0), out=basis[:, 3])  # the sphere's shading
    basis[:, 4], basis[:, 5], basis[:, 6] = u * u, v * v, u * v
    diff = f - b
    theta = np.array([cx0, cy0, r0])
    beta: np.ndarray | None = None
    # The Jacobian's columns that differ between channels: d model / d theta per channel (the
    # edge's motion times that channel's contrast), then d model / d beta, the same for all;
    # one product gives every block of the normal equations.
    g = 3 * channels
    jac = np.empty((n, g + k))
    grad = jac[:, :g].reshape(n, channels, 3)
    normal = np.zeros((3 + k * channels,) * 2)
    edge = np.empty((n, 3))
    rhs = np.empty((3 + k * channels, 1))
    for _ in range(_ITERATIONS):
        dx, dy = xs - theta[0], ys - theta[1]
        dist = np.hypot(dx, dy)
        centred = dist < 1e-9  # a pixel at the centre (a small blob's start): any normal will do
        if centred.any():
            safe = np.where(centred, 1.0, dist)
            nx, ny = np.where(centred, 1.0, dx / safe), dy / safe
        else:
            nx, ny = dx / dist, dy / dist
        share, slope = coverage(theta[2] - dist, nx, ny)
        covered = np.multiply(share[:, None], basis, out=jac[:, g:])
        if beta is None:  # the colour that best explains the pixels for the starting disc
            beta = _least_squares(covered, diff + share[:, None] * b)
        contrast = basis @ beta - b
        residual = diff - share[:, None] * contrast
        np.multiply(nx, slope, out=edge[:, 0])
        np.multiply(ny, slope, out=edge[:, 1])
        edge[:, 2] = slope
        np.multiply(contrast[:, :, None], edge[:, None, :], out=grad)
        # normal equations of the Jacobian [d model / d theta, d model / d beta] by blocks:
        # theta couples to every channel, each channel's beta only to its own pixels
        full = jac.T @ jac
        right = jac.T @ residual
        if channels == 1:
            normal[:] = full
            rhs[:] = right
        else:
            normal[:3, :3] = 0.0
            rhs[:3] = 0.0
            own = full[g:, g:]
            for c in range(channels):
                rows = slice(3 * c, 3 * c + 3)
                cols = slice(3 + c * k, 3 + (c + 1) * k)
                normal[:3, :3] += full[rows, rows]
                normal[:3, cols] = full[rows, g:]
                normal[cols, :3] = full[g:, rows]
                normal[cols, cols] = own
                rhs[:3, 0] += right[rows, c]
                rhs[cols, 0] = right[g:, c]
        solved, step = cv2.solve(normal, rhs)  # OpenCV's LU: a quarter of numpy's call
        if not solved:  # singular
            return None
        step = step[:, 0]
        if not np.isfinite(step).all():
            return None
        theta += step[:3]
        beta = beta + step[3:].reshape(channels, k).T
        if abs(step[0]) < _CONVERGED_PX and abs(step[1]) < _CONVERGED_PX:
            break
    cx, cy, r = float(theta[0]) + x0, float(theta[1]) + y0, float(theta[2])
    if math.hypot(cx - centre[0], cy - centre[1]) > _MAX_SHIFT_PX:
        return None
    if abs(r - r0) > _RADIUS_TOLERANCE * r0 + 0.5:
        return None
    return cx, cy
