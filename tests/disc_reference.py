"""The disc fit of a small round blob's centre as it was first written: one blob at a time,
one Gauss-Newton step per call of OpenCV's LU. Kept to check that the batched fit
(:func:`stereod.vision.disc.disc_centres`) gives the same centres; never used by the daemon."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from stereod.vision.disc import (
    _CONVERGED_PX,
    _ITERATIONS,
    _MAX_SHIFT_PX,
    _RADIUS_TOLERANCE,
    PAD_PX,
    coverage,
)


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
