"""What a moved object leaves behind: a blob whose outline is the background's edges, not the
frame's (a "ghost" of background subtraction).

A real object stands out of what is behind it: along its outline the frame has edges that
the background model lacks. Where an object that was part of the background has moved away
(a box pushed aside, a chair taken), the floor it uncovers differs from the background too,
but along that region's outline the frame shows floor meeting floor, and the background the
object's old outline. :func:`outline_scores` compares the two along each blob's outline, on
the gradient of the logarithm of the brightness (a shadow darkens by one factor and leaves
that gradient as it was), in a small crop around each blob: nothing is computed away from
blobs. :func:`left_behind` finds a pair's uncovered blobs and hands them to the background.
"""

from __future__ import annotations

import cv2
import numpy as np

from stereod.vision.background import BackgroundModel
from stereod.vision.blobs import Blobs

BAND_PX = 2
"""Half the width (px) of the band along a blob's outline that the edges are compared over:
the detector's outline lies within a pixel or two of the object's edge (its closing and
hysteresis move it), and a 3x3 gradient spreads an edge over two pixels."""
LOG_OFFSET = 8.0
"""Grey levels added before the logarithm: below this the brightness's sensor noise (a level
or two) would make a dark area's log-gradient as large as an edge's."""
MIN_EDGE = 0.05
"""The smallest mean log-gradient (per px over the band) that counts as an edge in either
image: a step of 1.3 % of the brightness over the band; the score of a blob whose outline is
flatter than this in both is near 0 (no evidence either way)."""
UNCOVERED_SCORE = -0.45
"""A blob scoring at most this over its whole outline (:func:`outline_scores`), and above
``SECTOR_OBJECT`` in no sector of it, is uncovered background: along its outline the frame's
edges are at most 0.55 of the background model's. On the independent renderer the floor a
pushed box uncovered scores -0.63 to -0.66, a robot, a box or a person +0.3 to +0.9 (a box
still in one blob with the floor it uncovered, about 0), a robot still in one blob with it
down to -0.53."""
SECTOR_OBJECT = 0.0
"""A blob one of whose sectors (:func:`outline_scores`) scores above this has an object's
edges there: not wholly uncovered background, whatever its whole outline scores (on the
independent renderer's pushed box, the floor alone scores at most -0.32 in every sector, the
robot still in one blob with it +0.5 to +0.9 in its own)."""
MAX_CROP_PX = 16384
"""A crop around a blob larger than this (px; 128 x 128) is scored at half its resolution
each way: a near person's blob at 320x240 costs a quarter, and its outline stays long."""
_BAND = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * BAND_PX + 1, 2 * BAND_PX + 1))
_SUM = np.ones((1, 3), np.float32)


def _edges(image: np.ndarray) -> np.ndarray:
    """|grad log I| (per px) of a crop by 3x3 Sobel, scaled so that a step reads its height at
    its edge; of a BGR crop, the channels' gradients together (a ball as bright as the floor
    behind it but of another colour has edges). A shadow scales I by one factor, and leaves
    the gradient of its logarithm as it was."""
    log = cv2.log(image.astype(np.float32) + np.float32(LOG_OFFSET))
    gx = cv2.Sobel(log, cv2.CV_32F, 1, 0, ksize=3, scale=0.25)
    gy = cv2.Sobel(log, cv2.CV_32F, 0, 1, ksize=3, scale=0.25)
    squared = cv2.add(cv2.multiply(gx, gx), cv2.multiply(gy, gy))
    if squared.ndim == 3:
        squared = cv2.transform(squared, _SUM)
    return cv2.sqrt(squared)


def outline_scores(
    frame: np.ndarray, background: np.ndarray, support: np.ndarray, at: tuple[int, int]
) -> tuple[float, float]:
    """How much more the frame than the background has edges along one blob's outline, in
    [-1, 1]: (F - B) / max(F, B, ``MIN_EDGE``), F and B the mean log-gradients of each over the
    band within ``BAND_PX`` of the outline; over the whole band, and the highest over any of
    its sectors (the band cut by a 3 x 3 grid over the blob's box). Positive: an object stands
    there; negative: the background had an edge there the frame lacks (uncovered by a moved
    object); near 0: both alike (a shadow, a flat floor). A region uncovered has no sector
    where the frame's edges win; one still in a blob with the object that uncovered it has
    that object's. ``frame`` (uint8) and ``background`` (float32 or uint8), grey or BGR, are
    whole images; ``support`` (uint8 255 on the blob) is the blob's mask, its top-left corner
    at ``at`` (x, y px). Everything is computed on the crop around the blob (at half
    resolution beyond ``MAX_CROP_PX``)."""
    h_img, w_img = frame.shape[:2]
    sh, sw = support.shape[:2]
    m = BAND_PX + 1  # the band, and the gradient's reach beyond it
    x0, y0 = max(at[0] - m, 0), max(at[1] - m, 0)
    x1, y1 = min(at[0] + sw + m, w_img), min(at[1] + sh + m, h_img)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return 0.0, 0.0
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    mask[at[1] - y0 : at[1] - y0 + sh, at[0] - x0 : at[0] - x0 + sw] = support
    crops = [frame[y0:y1, x0:x1], background[y0:y1, x0:x1]]
    if mask.size > MAX_CROP_PX:  # a large blob: its outline is long, and half the pixels tell
        half = ((x1 - x0 + 1) // 2, (y1 - y0 + 1) // 2)
        crops = [cv2.resize(c, half, interpolation=cv2.INTER_AREA) for c in crops]
        mask = cv2.resize(mask, half, interpolation=cv2.INTER_NEAREST)
    band = cv2.morphologyEx(mask, cv2.MORPH_GRADIENT, _BAND)
    f, b = _edges(crops[0]), _edges(crops[1])
    # The band's share of each cell of a 3 x 3 grid over the crop, and the edges' means over
    # the band there (as shares of the cell: the cells are of one size, so their ratios hold).
    on = band.astype(np.float32) * np.float32(1.0 / 255.0)
    cells = (3, 3)
    ns = cv2.resize(on, cells, interpolation=cv2.INTER_AREA).ravel().astype(np.float64)
    fs = cv2.resize(cv2.multiply(f, on), cells, interpolation=cv2.INTER_AREA).ravel()
    bs = cv2.resize(cv2.multiply(b, on), cells, interpolation=cv2.INTER_AREA).ravel()
    fs, bs = fs.astype(np.float64), bs.astype(np.float64)
    total = ns.sum()
    if total <= 0:
        return 0.0, 0.0
    whole = (fs.sum() - bs.sum()) / max(fs.sum(), bs.sum(), MIN_EDGE * total)
    used = ns > 1e-3 * total
    parts = (fs - bs)[used] / np.maximum(np.maximum(fs, bs), MIN_EDGE * ns)[used]
    return float(whole), float(parts.max())


def _at(blobs: Blobs, i: int) -> tuple[int, int]:
    """Blob ``i``'s top-left corner (x, y px), where its support mask starts."""
    return int(blobs.bbox_px[i, 0]), int(blobs.bbox_px[i, 1])


def uncovered(scores: tuple[float, float]) -> bool:
    """Whether a blob's :func:`outline_scores` say it is uncovered background."""
    return scores[0] <= UNCOVERED_SCORE and scores[1] <= SECTOR_OBJECT


def left_behind(
    left: Blobs, right: Blobs, matches: np.ndarray, eyes: tuple[BackgroundModel, BackgroundModel]
) -> list[bool]:
    """Which matched blob pairs (``matches`` (n, 2): left, right index) are background a moved
    object uncovered: both blobs are (:func:`uncovered`, against each eye's model in ``eyes``
    and the frame it was last given; the right blob is scored only when the left one is).
    Both blobs of each such pair are handed to their eye's background at once
    (:meth:`stereod.vision.background.BackgroundModel.relearn`): the next frame shows none."""
    out = [False] * len(matches)
    sides = tuple(zip(eyes, (left, right), strict=True))
    for k, pair in enumerate(matches):
        for (eye, blobs), i in zip(sides, pair, strict=True):
            frame, background = eye.frame, eye.background
            if frame is None or background is None or len(blobs.support) != len(blobs):
                break
            if not uncovered(outline_scores(frame, background, blobs.support[i], _at(blobs, i))):
                break
        else:
            out[k] = True
            for (eye, blobs), i in zip(sides, pair, strict=True):
                eye.relearn(blobs.support[i], _at(blobs, i))
    return out
