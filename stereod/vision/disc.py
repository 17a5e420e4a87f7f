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
from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np

PAD_PX = 2
"""Pixels of background around the blob's box that the fit sees."""
_ITERATIONS = 3
"""Gauss-Newton steps at most. A ball's fit moves about 0.04, 0.05, 0.02 px in its first
three and 0.003 px (median; 0.014 px at most on the latency benchmark's ball) in a fourth:
a tenth of the fit's own error against the truth (0.04 px median), which a fourth step does
not change."""
_CONVERGED_PX = 1e-2
"""The fit stops earlier when its centre moves less than this (px) in a step, and its radius
less than five times this (the radius moves the centre only through their coupling): a
tenth of the fit's own error against the truth. On the shaded-ball fixtures this moves no
centre by more than 0.012 px from the fit that stops at 0.005 px of the centre alone."""
_WARM_CONVERGED_PX = 0.02
"""A fit started from the last frame's (:func:`warm_start`) stops after a step that moves its
centre less than this (px), and its radius less than five times this: started a few
hundredths of a pixel from its optimum, it takes one or two steps, and lands within 0.025
px (0.004 px median) of where the fit from the blob's centre lands, on the 320x240 ball
scenes. (At 0.05 px a single step was the rule, and a ball thrown at the rig at 10 m/s had
its speed off by 0.2 % more.)"""
_WARM_GROWTH = 0.05
"""A blob whose area's radius differs by more than this share from the previous blob's (a
ball coming towards the rig or going away, or another blob) is fitted from its own centre:
its fit's offset from that centre changes with its size."""
_WARM_SHIFT_PX = 0.5
"""A previous fit further than this (px) from its blob's centre does not start the next."""
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
    with its margin leaves the image or the fit is not to be trusted. One blob of
    :func:`disc_centres`."""
    return disc_centres([Candidate(frame, background, box, centre, area)])[0]


class Candidate(NamedTuple):
    """A blob to centre by :func:`disc_centres`: its eye's (H, W[, 3]) uint8 ``frame`` and
    ``background`` (at the frame's gain), its ``box`` (x, y, w, h px) in them, its starting
    ``centre`` (x, y px) and its ``area`` (px)."""

    frame: np.ndarray
    background: np.ndarray
    box: tuple[int, int, int, int]
    centre: tuple[float, float]
    area: int


def warm_start(
    centre: tuple[float, float], area: int, last: Sequence[tuple[float, ...]], gate_px: float
) -> tuple[float, float, float] | None:
    """Where a blob's disc fit starts (x, y, radius px): its ``centre`` (x, y px) moved by
    the offset of the fit from its blob's centre in the eye's previous frame, and the radius
    of a disc of its ``area`` (px) scaled as that fit's was; ``last`` holds the previous
    frame's fits as (blob x, y, fit x, y, fit radius, area radius) px, and the nearest blob
    within ``gate_px`` is taken for the same ball (None where there is none). A ball's fit
    sits up to 0.3 px off its matte centroid, by shading and by what the background hides,
    which changes little from one frame to the next: started there, the fit is within a few
    hundredths of a pixel of its optimum, and one or two steps find it instead of
    three (:data:`_WARM_CONVERGED_PX`)."""
    best, near = None, gate_px * gate_px
    for prev in last:
        d2 = (prev[0] - centre[0]) ** 2 + (prev[1] - centre[1]) ** 2
        if d2 <= near:
            best, near = prev, d2
    if best is None:
        return None
    dx, dy = best[2] - best[0], best[3] - best[1]
    r0 = math.sqrt(area / math.pi)
    if dx * dx + dy * dy > _WARM_SHIFT_PX**2 or abs(r0 / best[5] - 1.0) > _WARM_GROWTH:
        return None
    return centre[0] + dx, centre[1] + dy, r0 * best[4] / best[5]


def disc_centres(
    blobs: Sequence[Candidate],
    starts: Sequence[tuple[float, float, float] | None] | None = None,
    radii: list[float] | None = None,
) -> list[tuple[float, float] | None]:
    """:func:`disc_fits`' centres (x, y px); their radii (px, nan where there is no fit)
    are appended to ``radii`` where it is given."""
    fits = disc_fits(blobs, starts)
    if radii is not None:
        radii.extend(math.nan if f is None else f[2] for f in fits)
    return [None if f is None else (f[0], f[1]) for f in fits]


def disc_fits(
    blobs: Sequence[Candidate], starts: Sequence[tuple[float, float, float] | None] | None = None
) -> list[tuple[float, float, float] | None]:
    """Centre and radius (x, y, r px) of the disc that best explains each blob's frame
    around its box against its background, started from its entry of ``starts`` (x, y,
    radius px in the blob's frame, from :func:`warm_start`) where it has one, else from its
    centre and the radius of a disc of its area (the model and the checks are those of the
    centre and the area either way: a start only shortens the path to the optimum);
    None where the box with its margin leaves the image or the fit is not to be trusted (it
    moved more than a pixel, or its radius is not the blob's). Gauss-Newton over the centre,
    the radius and the object's colour (per channel: a quadratic in position plus the
    sphere's sqrt(1 - rho^2), which holds a Lambertian ball's shading), every blob's fit in
    the same few whole-array calls (blobs of both eyes alike: all frames must have the same
    channels). Each window is padded with zeros to the largest; a padded pixel has a zero
    Jacobian and a zero residual, so it changes no fit."""
    out: list[tuple[float, float, float] | None] = [None] * len(blobs)
    windows: list[tuple[int, int, int, int, int]] = []  # index, x0, y0, width, height
    for i, (frame, _, (x, y, w, h), _, _) in enumerate(blobs):
        height, width = frame.shape[:2]
        x0, y0, x1, y1 = x - PAD_PX, y - PAD_PX, x + w + PAD_PX, y + h + PAD_PX
        if x0 >= 0 and y0 >= 0 and x1 <= width and y1 <= height:
            windows.append((i, x0, y0, x1 - x0, y1 - y0))
    if not windows:
        return out
    nb = len(windows)
    channels = 1 if blobs[windows[0][0]].frame.ndim == 2 else blobs[windows[0][0]].frame.shape[2]
    n = max(ww * wh for _, _, _, ww, wh in windows)
    k = 7
    # Every array has its pixels last: numpy's loops then run along them, not along a
    # channel's or the edge's few values.
    f = np.zeros((nb, channels, n))
    b = np.zeros((nb, channels, n))
    xs = np.zeros((nb, n))
    ys = np.zeros((nb, n))
    inside = np.zeros((nb, n))
    start = np.empty((nb, 3))
    for j, (i, x0, y0, ww, wh) in enumerate(windows):
        blob, m = blobs[i], ww * wh
        f[j, :, :m] = blob.frame[y0 : y0 + wh, x0 : x0 + ww].reshape(m, channels).T
        b[j, :, :m] = blob.background[y0 : y0 + wh, x0 : x0 + ww].reshape(m, channels).T
        xs[j, :m], ys[j, :m] = _grid(ww, wh)
        inside[j, :m] = 1.0
        start[j] = blob.centre[0] - x0, blob.centre[1] - y0, math.sqrt(blob.area / math.pi)
    r0 = start[:, 2:3]
    u, v = (xs - start[:, 0:1]) / r0, (ys - start[:, 1:2]) / r0
    basis = np.empty((nb, k, n))
    basis[:, 0] = inside
    basis[:, 1], basis[:, 2] = u, v
    np.multiply(u, u, out=basis[:, 4])
    np.multiply(v, v, out=basis[:, 5])
    np.multiply(u, v, out=basis[:, 6])
    shading = np.subtract(1.0, basis[:, 4])
    shading -= basis[:, 5]
    np.sqrt(np.maximum(shading, 0.0, out=shading), out=basis[:, 3])  # the sphere's shading
    if any(ww * wh < n for _, _, _, ww, wh in windows):
        basis *= inside[:, None]  # a padded pixel: a zero column
    diff = f - b
    theta = start.copy()
    warm = [False] * nb  # started from the last frame's fit: one step, if a short one
    for j, (i, x0, y0, _, _) in enumerate(windows):
        at = None if starts is None else starts[i]
        if at is not None:
            theta[j] = at[0] - x0, at[1] - y0, at[2]
            warm[j] = True
    # The Jacobian's rows (one per unknown, pixels along) that differ between channels:
    # d model / d theta per channel (the edge's motion times that channel's contrast), then
    # d model / d beta, the same for all; then a row of zeros and the residuals per channel.
    # One product per blob gives every block of the normal equations and of their right side,
    # gathered by ``_blocks``. (One product of the whole stacked Jacobian would be 2.3 times
    # as large, and large enough for a BLAS to split it over threads, which costs more than
    # it saves on a busy host.)
    g = 3 * channels
    rows = np.empty((nb, g + k + 1 + channels, n))  # every row is written below but the zero row
    rows[:, g + k] = 0.0
    jac = rows[:, : g + k]
    residual = rows[:, g + k + 1 :]
    rows_t = rows.transpose(0, 2, 1)
    grad = rows[:, :g].reshape(nb, channels, 3, n)
    edge = np.empty((nb, 1, 3, n))
    pick = _blocks(channels, k)
    p = 3 + k * channels
    todo = list(range(nb))  # the blobs still fitted: not converged, not failed
    failed: set[int] = set()
    beta: np.ndarray | None = None  # (blob, channel, k)
    for _ in range(_ITERATIONS):
        dx, dy = xs - theta[:, :1], ys - theta[:, 1:2]
        dist = np.sqrt(dx * dx + dy * dy)
        # a pixel at the centre (a small blob's start): any normal will do
        if np.minimum.reduce(dist, axis=None) < 1e-9:
            centred = dist < 1e-9
            safe = np.where(centred, 1.0, dist)
            nx, ny = np.where(centred, 1.0, dx / safe), dy / safe
        else:
            nx, ny = dx / dist, dy / dist
        share, slope = coverage(theta[:, 2:3] - dist, nx, ny)
        share_c = share[:, None]
        covered = np.multiply(share_c, basis, out=jac[:, g:])
        if beta is None:  # the colour that best explains the pixels for the starting disc
            beta = _least_squares(covered, diff + share_c * b)
        contrast = beta @ basis - b
        np.subtract(diff, share_c * contrast, out=residual)
        np.multiply(nx, slope, out=edge[:, 0, 0])
        np.multiply(ny, slope, out=edge[:, 0, 1])
        edge[:, 0, 2] = slope
        np.multiply(contrast[:, :, None], edge, out=grad)
        # normal equations by blocks: theta couples to every channel, each channel's beta
        # only to its own pixels
        # (the right side first, so that the centre-radius block beside it is one slice)
        blocks = (rows @ rows_t).reshape(nb, -1).take(pick, axis=1)
        system = blocks[:, : p * (p + 1)].reshape(nb, p, p + 1)
        if channels > 1:
            sums = blocks[:, p * (p + 1) :].reshape(nb, channels, 3, 4)
            system[:, :3, :4] = np.add.reduce(sums, axis=1)
        for j in list(todo):
            solved, step = cv2.solve(system[j, :, 1:], system[j, :, :1])
            if not solved or not cv2.checkRange(step):  # singular
                failed.add(j)
                todo.remove(j)
                continue
            theta[j] += step[:3, 0]
            beta[j] += step[3:, 0].reshape(channels, k)
            sx, sy, sr = step[:3, 0].tolist()
            moved = max(abs(sx), abs(sy), abs(sr) / 5)
            if moved < (_WARM_CONVERGED_PX if warm[j] else _CONVERGED_PX):
                todo.remove(j)
        if not todo:
            break
    for j, (i, x0, y0, _, _) in enumerate(windows):
        if j in failed:
            continue
        cx, cy, r = float(theta[j, 0]) + x0, float(theta[j, 1]) + y0, float(theta[j, 2])
        centre, r0j = blobs[i].centre, float(start[j, 2])
        if math.hypot(cx - centre[0], cy - centre[1]) > _MAX_SHIFT_PX:
            continue
        if abs(r - r0j) > _RADIUS_TOLERANCE * r0j + 0.5:
            continue
        out[i] = cx, cy, r
    return out


def _least_squares(a: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per blob, the x (channel, k) that minimises |x a - y| (``a`` (blob, k, pixel), ``y``
    (blob, channel, pixel)): through the normal equations (OpenCV's LU), and by SVD where
    they are singular."""
    at = a.transpose(0, 2, 1)
    normal, right = a @ at, a @ y.transpose(0, 2, 1)
    x = np.empty((a.shape[0], y.shape[1], a.shape[1]))
    for j in range(a.shape[0]):
        solved, xj = cv2.solve(normal[j], right[j])
        x[j] = xj.T if solved else np.linalg.lstsq(at[j], y[j].T, rcond=None)[0].T
    return x


@functools.lru_cache(maxsize=4)
def _blocks(channels: int, k: int) -> np.ndarray:
    """Where each entry of the right side of the normal equations and, beside it, their
    matrix (centre, radius, then each channel's ``k`` colour terms), then the ``channels``
    right sides and centre-radius blocks summed into the top ones, are in the flattened
    product of the rows of :func:`disc_centres` (``3 channels + k`` Jacobian rows, a zero
    row, ``channels`` residual rows) with themselves. One channel's colour terms do not meet
    another's: those entries are the zero row's."""
    g = 3 * channels
    m = g + k + 1 + channels
    zero, p = g + k, 3 + k * channels

    def row(i: int, c: int) -> int:
        """The Jacobian row of unknown ``i`` on channel ``c``'s pixels."""
        return 3 * c + i if i < 3 else g + (i - 3) % k

    def channel(i: int) -> int:
        return -1 if i < 3 else (i - 3) // k

    pick = np.zeros((p, p + 1), np.intp)
    for i in range(p):
        for j in range(p + 1):
            ci, cj = channel(i), (channel(j) if j < p else -2)
            at = (i, 0 if j == p else j + 1)
            if cj == -2:  # the right side: unknown i against its channel's residuals
                pick[at] = row(i, max(ci, 0)) * m + g + k + 1 + max(ci, 0)
            elif ci >= 0 and cj >= 0 and ci != cj:
                pick[at] = row(i, ci) * m + zero
            else:
                c = max(ci, cj, 0)
                pick[at] = row(i, c) * m + row(j, c)
    sums = [
        [
            [(3 * c + i) * m + (3 * c + j - 1 if j else g + k + 1 + c) for j in range(4)]
            for i in range(3)
        ]
        for c in range(channels)
    ]
    return np.concatenate([pick.ravel(), np.ravel(sums)])
