"""Cast shadows and a changed scene: foreground that is the background under other light (its
colour and texture kept), left out of the objects or taken for a change of light or view."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereod.vision.luminance import MEAN_RGB, channel_mean

SHADOW_WINDOW_PX = 7
"""Side (px) of the window a shadow's texture is compared with the background's over (5 px
took the shaded side of a cylinder the colour of the wall for shadow; a long thin shadow's
few sure pixels reach the rest of it through its connected candidates)."""
SHADOW_MIN_TEXTURE = 4.0
"""The background's local standard deviation (grey levels) from which its texture can be
compared: on a flatter background only colour tells a shadow from a dark object."""
SHADOW_MIN_NCC = 0.6
"""The smallest normalised cross-correlation of frame and background over the window for the
texture to count as the background's (a shadow keeps it; an object hides it)."""
SHADOW_RATIO_SPREAD = 0.08
"""The largest standard deviation of frame / background over the window, as a share of its
mean, in a shadow's inside (a shadow darkens by one factor; an object's ratio to the texture
behind it follows that texture)."""
SHADOW_STRIP_WINDOW_PX = (15, 3)
"""A second window (w, h px) for a shadow too thin for the square one: a low lamp's strip."""
SHADOW_STRIP_MIN_NCC = 0.4
"""The strip window's ``SHADOW_MIN_NCC``: through a webcam's MJPEG and 4:2:2 chroma, the square
window's bounds found a low lamp's strip in half the frames only (it came and went, and the
blob's centroid with it, 20 px). Only thin candidates that it fits inside are judged by it."""
SHADOW_STRIP_RATIO_SPREAD = 0.12
"""The strip window's ``SHADOW_RATIO_SPREAD`` (see ``SHADOW_STRIP_MIN_NCC``)."""
_COLUMN = np.ones((SHADOW_WINDOW_PX, 1), np.uint8)
"""A column of the square window's height: candidates in a run this tall have it."""
_SQUARE = np.ones((SHADOW_WINDOW_PX, SHADOW_WINDOW_PX), np.uint8)
"""The square window as a kernel: it fits inside the candidates where their erosion by it is."""
_STRIP = np.ones(SHADOW_STRIP_WINDOW_PX[::-1], np.uint8)
"""The strip window as a kernel: its sure pixels are where it fits inside the thin candidates,
as the square window's are where it fits inside a wide shadow."""
SHADOW_MIN_SURE = (0.09, 0.08)
"""The smallest share of a connected stretch of candidates' judged pixels that must be sure for
the stretch to be a shadow: of those where the square window fits inside the candidates, on
textured background, or, where it fits on textured background at fewer than a window's area
of pixels, of all its pixels on textured background. A
low lamp's shadow's are 10 to 100 % (through a webcam's MJPEG and 4:2:2 chroma 10 to 54 %);
dark trousers in front of a mottled wall, the colour the wall would take in shade, have a few
windows pass by chance (3 to 8 %), and a walking person's dark legs, blurred over the wall in
thin stretches no window fits inside, 0 to 6 % of all."""
SHADOW_CHROMA = 0.06
"""How far (share of the brightness) a shadowed pixel's colour may stray from the background's
scaled by the pixel's own ratio."""


@dataclass(frozen=True)
class _Relit:
    """:func:`_relit`'s masks (uint8 255) on the crop ``sl`` of an image of ``shape`` (h, w px):
    the candidates, the sure ones by the square window and those it could judge (on textured
    background), the thin candidates (in a vertical run shorter than that window's side), and
    the sure ones among those by the strip window (``None`` when the strip window fits nowhere
    inside them)."""

    sl: tuple[slice, slice]
    shape: tuple[int, ...]
    cand: np.ndarray
    core: np.ndarray
    judged: np.ndarray
    thin: np.ndarray
    thin_core: np.ndarray | None

    def full(self, crop: np.ndarray) -> np.ndarray:
        """``crop`` (a mask on ``sl``) placed in an image of ``shape``, zero elsewhere."""
        out = np.zeros(self.shape, np.uint8)
        out[self.sl] = crop
        return out


SHADOW_CELL_PX = 16
"""Side (px) of the cells the candidates are gathered into: the colour and texture tests run
on one rectangle around each 8-connected group of occupied cells, not on the rectangle around
all of them (people spread across a room leave most of that empty)."""
SHADOW_MAX_CROPS = 8
"""More groups than this are judged in one rectangle around all of them (each rectangle costs
some 40 whole-array calls). At most 255: a group's label is kept in a uint8."""
SHADOW_MIN_CELLS = 5
"""A rectangle of fewer cells than this is judged whole (a ball's, or a small image's)."""
SHADOW_MAX_CROPPED = 0.6
"""Groups whose rectangles would cover this share of the whole rectangle or more are judged in
the whole one (splitting it would save too little to pay for more calls)."""


def _relit(
    frame: np.ndarray,
    background: np.ndarray,
    foreground: np.ndarray,
    ratio: tuple[float, float],
) -> _Relit | None:
    """Where the foreground is the background under other light: the candidates (uint8 255;
    brightness times a factor within ``ratio``, lower and upper, and in colour each channel
    the background's times that factor within ``SHADOW_CHROMA``: Cucchiara et al.'s V, H and
    S tests without leaving BGR) and, among them, the sure ones, whose window (side
    ``SHADOW_WINDOW_PX``) keeps the background's texture (normalised cross-correlation at
    least ``SHADOW_MIN_NCC``, as much texture as the factor leaves, one factor across it
    within ``SHADOW_RATIO_SPREAD``). Only a textured background can tell: on a flat one a
    darker object of its colour (a shaded side) looks the same. A low lamp's shadow on the
    floor is a strip a few px high that no square window fits in: candidates in a vertical run
    shorter than the window's side (thin) are also judged over a wide, low window
    (``SHADOW_STRIP_WINDOW_PX``) where it fits inside them.
    ``None`` when no pixel is a candidate."""
    lo, hi = ratio
    # The brightness ratio first, on one channel: most of an object is no candidate, and the
    # rest of the test runs only around the candidates.
    fl8 = channel_mean(frame) if frame.ndim == 3 else frame
    bl8 = channel_mean(background) if frame.ndim == 3 else background
    r = fl8.astype(np.float32) / (bl8.astype(np.float32) + np.float32(1.0))
    cand_all = cv2.bitwise_and(cv2.inRange(r, lo, hi), foreground)
    if cv2.countNonZero(cand_all) == 0:
        return None
    x, y, w, h = cv2.boundingRect(cand_all)
    m = SHADOW_WINDOW_PX
    x0, y0 = max(x - m, 0), max(y - m, 0)
    x1, y1 = min(x + w + m, frame.shape[1]), min(y + h + m, frame.shape[0])
    sl = (slice(y0, y1), slice(x0, x1))
    seen, behind, first = frame[sl], background[sl], cand_all[sl]
    cand, core, judged = np.zeros_like(first), np.zeros_like(first), np.zeros_like(first)
    looks: list[tuple[tuple[slice, slice], np.ndarray | None, _Looks]] = []
    # each group of candidates in a rectangle of its own, with room for the widest window's
    # half (the strip's, 15 // 2 = 7 px = m)
    for crop, own in _crops(first, m):
        look = _Looks(seen[crop], behind[crop])
        looks.append((crop, own, look))
        part = look.same_colour(first[crop])
        if own is not None:
            part = cv2.bitwise_and(part, own)
        square, textured = look.keeps_texture(
            (SHADOW_WINDOW_PX, SHADOW_WINDOW_PX), SHADOW_MIN_NCC, SHADOW_RATIO_SPREAD
        )
        cand[crop] = cv2.bitwise_or(cand[crop], part)
        core[crop] = cv2.bitwise_or(core[crop], cv2.bitwise_and(part, _u8(square)))
        judged[crop] = cv2.bitwise_or(judged[crop], cv2.bitwise_and(part, _u8(textured)))
    if cv2.countNonZero(cand) == 0:
        return None
    thin = cv2.subtract(cand, cv2.morphologyEx(cand, cv2.MORPH_OPEN, _COLUMN))
    long = cv2.morphologyEx(thin, cv2.MORPH_OPEN, _STRIP)
    thin_core = None
    if cv2.countNonZero(long):
        thin_core = np.zeros_like(long)
        for crop, own, look in looks:
            part = long[crop] if own is None else cv2.bitwise_and(long[crop], own)
            if cv2.countNonZero(part):
                strip, _ = look.keeps_texture(
                    SHADOW_STRIP_WINDOW_PX, SHADOW_STRIP_MIN_NCC, SHADOW_STRIP_RATIO_SPREAD
                )
                found = cv2.bitwise_and(part, _u8(strip))
                thin_core[crop] = cv2.bitwise_or(thin_core[crop], found)
    return _Relit(sl, cand_all.shape, cand, core, judged, thin, thin_core)


def _crops(cand: np.ndarray, margin: int) -> list[tuple[tuple[slice, slice], np.ndarray | None]]:
    """Rectangles of ``cand`` (uint8) that hold every candidate with ``margin`` px around it
    (within ``cand``'s own bounds), each with the mask (uint8 255) of the pixels it judges
    where it holds more than those (``None``: all of them): one rectangle per 8-connected group
    of :data:`SHADOW_CELL_PX` cells holding candidates, or one for all when the groups are
    more than :data:`SHADOW_MAX_CROPS` or their rectangles would cover most of ``cand``.
    A pixel's window (``margin`` px around it at most) then lies inside its rectangle, or
    reaches the image's edge where the whole one does: each pixel is judged as it would be
    in the whole (to the last bit as long as OpenCV's box filter sums a window alike wherever
    its image starts, as it does in this build; ``tests/test_shadows.py`` compares the two)."""
    h, w = cand.shape
    c = SHADOW_CELL_PX
    gh, gw = -(-h // c), -(-w // c)
    whole: list[tuple[tuple[slice, slice], np.ndarray | None]] = [
        ((slice(0, h), slice(0, w)), None)
    ]
    if gh * gw < SHADOW_MIN_CELLS:
        return whole
    cells = cv2.copyMakeBorder(cand, 0, gh * c - h, 0, gw * c - w, cv2.BORDER_CONSTANT, value=0)
    occupied = cv2.resize(cells, (gw, gh), interpolation=cv2.INTER_AREA)  # a cell's mean, >0
    n, labels, stats, _ = cv2.connectedComponentsWithStats(occupied, connectivity=8)
    if n - 1 > SHADOW_MAX_CROPS or n <= 2:
        return whole
    boxes = []
    for gx, gy, bw, bh in stats[1:, :4].tolist():
        bx0, by0 = max(gx * c - margin, 0), max(gy * c - margin, 0)
        bx1, by1 = min((gx + bw) * c + margin, w), min((gy + bh) * c + margin, h)
        boxes.append((bx0, by0, bx1, by1))
    if sum((bx1 - bx0) * (by1 - by0) for bx0, by0, bx1, by1 in boxes) >= SHADOW_MAX_CROPPED * h * w:
        return whole
    owner = cv2.resize(  # each pixel's group: labels fit a uint8 (SHADOW_MAX_CROPS <= 255)
        labels.astype(np.uint8), (gw * c, gh * c), interpolation=cv2.INTER_NEAREST
    )
    out: list[tuple[tuple[slice, slice], np.ndarray | None]] = []
    for j, (bx0, by0, bx1, by1) in enumerate(boxes, start=1):
        crop = (slice(by0, by1), slice(bx0, bx1))
        out.append((crop, _u8(owner[crop] == j)))
    return out


class _Looks:
    """A crop of the frame and of the background in float32, with their brightness and its
    ratio, for the colour and texture tests."""

    def __init__(self, frame: np.ndarray, background: np.ndarray) -> None:
        self.colour = frame.ndim == 3
        self.f = frame.astype(np.float32)
        self.b = background.astype(np.float32)
        self.fl = cv2.transform(self.f, MEAN_RGB) if self.colour else self.f
        self.bl = cv2.transform(self.b, MEAN_RGB) if self.colour else self.b
        self.r = self.fl / (self.bl + 1.0)

    def same_colour(self, cand: np.ndarray) -> np.ndarray:
        """The candidates (uint8 255) whose every channel is the background's times their
        brightness ratio within ``SHADOW_CHROMA`` (grey frames: all of them)."""
        if not self.colour:
            return cand
        r = self.r
        # the largest channel's |f - b r|, in OpenCV calls (numpy's max over the last axis of
        # three is several times slower)
        c0, c1, c2 = cv2.split(cv2.absdiff(self.f, cv2.multiply(self.b, cv2.merge((r, r, r)))))
        off = cv2.max(cv2.max(c0, c1), c2)
        same = cv2.compare(off, SHADOW_CHROMA * (self.bl + 1.0) + 3.0, cv2.CMP_LE)
        return cv2.bitwise_and(cand, same)

    def keeps_texture(
        self, k: tuple[int, int], min_ncc: float, spread: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """:func:`_keeps_texture` on this crop."""
        return _keeps_texture(self.fl, self.bl, self.r, k, min_ncc, spread)


def _u8(mask: np.ndarray) -> np.ndarray:
    """A boolean mask as uint8 255."""
    return mask.view(np.uint8) * np.uint8(255)


def _keeps_texture(
    fl: np.ndarray,
    bl: np.ndarray,
    r: np.ndarray,
    k: tuple[int, int],
    min_ncc: float,
    spread: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the window ``k`` (w, h px) keeps the background's texture under one factor: as
    much texture as the factor leaves, normalised cross-correlation at least ``min_ncc``, and
    frame / background within ``spread`` (a share of its mean) across it; and where the
    background has the texture to tell (boolean masks)."""
    mf, mb = cv2.blur(fl, k), cv2.blur(bl, k)
    vf = cv2.blur(fl * fl, k) - mf * mf
    vb = cv2.blur(bl * bl, k) - mb * mb
    cov = cv2.blur(fl * bl, k) - mf * mb
    textured = vb >= SHADOW_MIN_TEXTURE * SHADOW_MIN_TEXTURE
    ncc = cov / np.sqrt(np.maximum(vf * vb, 1e-6))
    gain = mf / (mb + 1.0)  # the window's factor: its texture is the background's times it
    mr = cv2.blur(r, k)
    vr = cv2.blur(r * r, k) - mr * mr  # other light changes its whole window alike
    keeps = (
        textured & (ncc >= min_ncc) & (vf >= 0.25 * gain * gain * vb) & (vr <= (spread * mr) ** 2)
    )
    return keeps, textured


def shadow_mask(
    frame: np.ndarray,
    background: np.ndarray,
    foreground: np.ndarray,
    ratio: tuple[float, float],
) -> np.ndarray | None:
    """The foreground pixels (uint8 255) that are a cast shadow: the background darkened by a
    factor within ``ratio`` with its colour and texture kept (:func:`_relit`), and the
    candidates connected to those (a shadow's edge, where the texture window holds lit floor
    too, and its stretches on flat floor).
    ``frame`` and ``background`` (uint8, the background at the frame's gain) and
    ``foreground`` share one shape; ``None`` when nothing is shadow."""
    found = _relit(frame, background, foreground, ratio)
    if found is None:
        return None
    shade = _reached(found.cand, found.core, found.judged)
    if found.thin_core is not None:
        # What the strip window finds reaches only the thin candidates: through them, one sure
        # pixel would otherwise take an object's tall dark side with it. A strip through a
        # webcam's MJPEG has few sure pixels, and nothing tall is thin: no share is asked.
        shade = cv2.bitwise_or(shade, _reached(found.thin, found.thin_core))
    return found.full(shade) if cv2.countNonZero(shade) else None


def _reached(cand: np.ndarray, core: np.ndarray, judged: np.ndarray | None = None) -> np.ndarray:
    """The candidates (uint8 255) connected to sure pixels of ``core`` (8-neighbours), not
    those across a gap (a dark stripe on the object beside its shadow is a candidate too,
    apart from it); with ``judged`` (where the window could judge), only in stretches where
    at least ``SHADOW_MIN_SURE`` of those are sure, counted where the window fits inside the
    candidates if it fits there at a window's area of pixels or more: a few windows on a dark
    object pass by chance."""
    if cv2.countNonZero(core) == 0:
        return np.zeros_like(cand)
    n, labels = cv2.connectedComponents(cand, connectivity=8, ltype=cv2.CV_32S)
    sure_px = np.bincount(labels[core > 0], minlength=n)
    enough = sure_px > 0
    if judged is not None:
        fits = cv2.erode(cand, _SQUARE, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        inside = cv2.bitwise_and(fits, judged) > 0
        inner_px = np.bincount(labels[inside], minlength=n)
        inner_sure = np.bincount(labels[inside & (core > 0)], minlength=n)
        judged_px = np.bincount(labels[judged > 0], minlength=n)
        share_in, share_all = SHADOW_MIN_SURE
        enough &= np.where(
            inner_px >= _SQUARE.size,
            inner_sure >= share_in * inner_px,
            sure_px >= share_all * judged_px,
        )
    sure = np.where(enough, np.uint8(255), np.uint8(0))
    sure[0] = 0
    return sure[labels]


RELIT_RATIO = (0.2, 5.0)
"""The factors (lower, upper) by which light that changed may darken or brighten the scene."""
SCENE_CHANGE_RELIT = 0.5
"""A large foreground at least this share of which is the background under other light
(:func:`_relit`) is the light that changed, not an object."""
SCENE_CHANGE_COVER = 0.8
"""A large foreground that covers at least this share of the image and reaches all four of its
edges is the scene that changed (the camera knocked, the view blocked), not an object."""


def scene_changed(
    frame: np.ndarray,
    background: np.ndarray,
    foreground: np.ndarray,
    origin: tuple[int, int],
    shape: tuple[int, int],
) -> bool:
    """Whether a large foreground (uint8 255, ``frame`` and ``background`` around it, at
    ``origin`` (x, y px) of an image of ``shape`` (h, w px)) is what the photometric model
    explains (light that changed: most of it the background under another factor) or the whole
    scene changing (it covers nearly all the image, edge to edge), rather than an object close
    to the camera. A person
    at 0.8 m fills most of a 42 deg view but leaves some of it, and hides the background's
    texture."""
    count = cv2.countNonZero(foreground)
    x, y, w, h = cv2.boundingRect(foreground)
    x, y = x + origin[0], y + origin[1]
    edges = x == 0 and y == 0 and x + w == shape[1] and y + h == shape[0]
    if edges and count >= SCENE_CHANGE_COVER * shape[0] * shape[1]:
        return True
    found = _relit(frame, background, foreground, RELIT_RATIO)
    return found is not None and cv2.countNonZero(found.core) >= SCENE_CHANGE_RELIT * count
