"""Moving-object detection by background subtraction, paper sec. II, on OpenCV whole-array calls.

Per eye and per frame: luminance (eq. 2) or colour, absolute difference to a running-average
background (eq. 4's R), threshold at ``t`` (eq. 4's M), a small opening (removes single-pixel
sensor noise) and closing (joins the pieces of one object), the objects' outlines, and each
object's centre of gravity (eq. 5), bounding box and area. The background is then updated by
eq. 3, ``T_i = T_{i-1} (1 - beta) + L_i beta``, kept in float32 (a uint8 background has a dead
band of 0.5/beta grey levels and never adapts).

Beyond the paper, each one chosen by measurement on two renderers (README, Accuracy):

- **No ghosts.** Eq. 3 learns a moving object into the background wherever it passes, and
  the trail it leaves is detected as objects that are not there. Here a pixel is not learned
  while it is foreground (the mask grown by ``hold_margin_px``), from the first frame it is;
  whatever stays foreground for ``absorb_s`` seconds is learned after all, so a parked object
  or the ghost of something that left becomes background. ``hold_foreground = false`` is eq. 3
  as the paper writes it.
- **Warm-up by the median.** The initial background the paper asks for is the per-pixel
  median of the first ``warmup_frames`` frames, so what passes by during warm-up leaves no
  ghost (``warmup = "mean"``: the running mean).
- **Global gain.** Light that drifts, or a camera's auto-exposure, scales the whole frame; a
  bright wall 10 % brighter differs from its background by more than ``t``. Each frame, the
  median ratio of frame to background over a sparse grid of background pixels is that gain,
  and the background is scaled by it before the difference, so eq. 3 only has to learn what
  changed locally (``gain = false``: eq. 4 against T as learned). A change that a gain does
  not explain (what it leaves is more than noise) is left to the saturation rule below.
- **Hysteresis.** A pixel whose difference is only above ``hysteresis`` times ``t`` is foreground
  when it lies next to one above ``t`` (grown by ``grow_px`` three times), as in an edge
  detector: the part of an object that nearly matches the background behind it stays in its
  support instead of being cut differently in each eye.
- **Colour.** With colour frames and ``color = true`` the difference of eq. 4 is the mean of
  the three channels' absolute differences, so an object as bright as what is behind it but
  of another colour is still found.
- **Whole objects.** An object's support is its outline filled in, so a part of it that
  matches the background (a hole) still counts; pieces of one object split by a stripe are
  joined by the closing. A pinhole (one pixel, its four neighbours foreground) is filled
  before the opening, which would otherwise erase a ball a few pixels across whose centre
  matches the wall behind it. Its centre is eq. 5 over that support, with each edge pixel weighted
  by the share of it the object covers, solved from the pixel, the background behind it and
  the object's colour just inside (``centroid = "matte"``, :func:`matte_centroid`); or by a
  ramp of eq. 4's difference (``"coverage"``); or eq. 5 exactly (``"binary"``).

- **Eq. 3 on every ``learn_stride``-th row, in turn.** Each frame updates one row in
  ``learn_stride`` with ``1 - (1 - beta) ** learn_stride``, so every row follows the same time
  constant as eq. 3 at ``beta`` (on a steady scene it holds what eq. 3 gives after each of its
  updates), for a ``learn_stride``-th of the memory traffic (eq. 3 on a colour frame is the
  detector's largest cost). A row lags by at most ``learn_stride - 1`` frames (a sixth of a
  second at 30 Hz and the default 6), and averages fewer frames: its noise is about 2.5
  times eq. 3's at ``beta`` 0.02 and stride 6 (0.25 of one frame's noise instead of 0.10),
  far under the threshold. ``learn_stride = 1`` is eq. 3 on every frame.

A frame whose foreground covers more than ``max_foreground`` of the image and is what the
photometric model explains (light that changed: the background under another factor, its
texture kept) or covers the image edge to edge (the camera moved), or that holds more than
``max_blobs`` objects, is saturated: it reports nothing, and after ``warmup_frames`` such
frames in a row the background is learned afresh. A large foreground that is neither is an
object close to the camera (a person at 0.8 m fills most of the view), found as any other.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from stereod.vision.disc import disc_centre, is_round


class Centroid(str, enum.Enum):
    """How a blob's centre is computed."""

    BINARY = "binary"
    """Eq. 5 exactly: the mean position of the blob's foreground pixels."""
    COVERAGE = "coverage"
    """Eq. 5 over the filled support, edge pixels weighted by a ramp of eq. 4's difference."""
    MATTE = "matte"
    """Eq. 5 over the filled support, each edge pixel weighted by the share of it the object
    covers, solved from the pixel, the background behind it and the object's colour nearby."""


class Luminance(str, enum.Enum):
    """How a colour frame becomes the luminance matrix L of eq. 2 (when not using colour)."""

    BT601 = "bt601"
    """OpenCV's 0.299 R + 0.587 G + 0.114 B: what a YUYV camera's Y plane already is (free)."""
    MEAN = "mean"
    """The paper's exact eq. 2, (R + G + B) / 3."""


class Warmup(str, enum.Enum):
    """How the initial background is made from the first frames."""

    MEDIAN = "median"
    """Per-pixel median: what passes by during the warm-up leaves nothing behind."""
    MEAN = "mean"
    """Running mean: the average of the frames."""


Rect = tuple[int, int, int, int]
"""A rectangle of an image (x0, y0, x1, y1) px, the end exclusive."""

_GAIN_STEP = 12
"""Pixel step of the grid the global gain is measured on, or a multiple of it in a large image
(see ``_GAIN_POINTS``)."""
_GAIN_POINTS = 500
"""The gain grid's step is the multiple of ``_GAIN_STEP`` that leaves at least this many
points (a median of 500 ratios moves by about 0.05 of one ratio's noise): 12 px up to
about 320x240, 24 px at 640x480."""
_GAIN_MIN_LEVEL = 20.0
"""Background darker than this (grey levels) is left out of the gain: its ratio is noise."""
_GAIN_MAX_MISFIT = 0.25
"""A gain is taken only if the median |frame - gain * background| it leaves is at most this
share of the threshold (sensor noise of a few grey levels passes; an offset of 40 does not)."""
_GAIN_RESCALE = 0.01
"""A gain further than this from 1 scales the stored background itself."""
_ROW_STEPS = (1, 2, 3, 4, 6)
"""Row steps of eq. 4's first pass: divisors of ``_GAIN_STEP``, so the gain's points lie on
its rows."""


MAX_WARMUP_FRAMES = 1000
"""Most frames the initial background may be made of (the warm-up keeps them all in memory:
1000 BGR frames at 640x480 are 0.9 GB)."""


@dataclass(frozen=True, slots=True)
class DetectorParams:
    """Parameters of sec. II and of what is added to it (module docstring).

    ``beta``: background update coefficient of eq. 3, 0 <= beta << 1 (per frame).
    ``threshold``: t of eq. 4 in 8-bit grey levels (the paper's [0, 1] scale times 255).
    ``min_area_px``: smallest object kept (px); smaller ones are noise.
    ``warmup_frames``: frames that make the initial background before detecting.
    ``open_px``, ``close_px``: sides of the opening and closing kernels (px), 0 or 1 to skip.
    ``luminance``: eq. 2 exactly or the camera's luma; ``centroid``: eq. 5 exactly or with
    the edge pixels weighted (by the share the object covers, or by a ramp).
    ``color``: difference colour frames channel by channel instead of by luminance.
    ``hold_foreground``: do not learn foreground pixels (grown by ``hold_margin_px``) until
    they have stayed foreground ``absorb_s`` seconds.
    ``fill_holes``: an object's support is its filled outline, not only its foreground pixels
    (and a pinhole is foreground before the opening);
    ``convex``: and that outline is the convex hull of the blob (a part of a robot or a ball
    as bright and coloured as the floor behind it leaves a notch, not a hole).
    ``merge_gap``: pieces closer than this share of the smaller one's size are one object.
    ``max_foreground``, ``max_blobs``: beyond these a frame is saturated.
    ``gain``: follow a global change of brightness (lighting drift, auto-exposure) at once.
    ``hysteresis``, ``grow_px``: pixels whose difference reaches ``hysteresis`` times ``t``
    join the foreground within ``grow_px`` of it (three steps), so the part of an object
    nearly the colour of the wall behind it is kept; 0 turns this off.
    ``learn_stride``: eq. 3 updates every ``learn_stride``-th row each frame, in turn (1: all).
    ``disc_max_px``: a round blob (:func:`stereod.vision.disc.is_round`) at most this wide and high
    (px) is centred by fitting a disc to the image (:func:`stereod.vision.disc.disc_centre`) when
    matting; 0 turns this off.
    ``shadows``: foreground that is the background darkened (its brightness times a factor
    within ``shadow_ratio``, its colour's proportions and its texture kept) is a cast shadow,
    not the object (:func:`shadow_mask`), and is left out before the centre is taken.
    ``near_objects``: a foreground over ``max_foreground`` is an object close to the camera
    unless the photometric model explains it or it covers the image edge to edge
    (:func:`scene_changed`); off, any such frame is saturated.
    """

    beta: float = 0.02
    threshold: float = 25.0
    min_area_px: int = 12
    warmup_frames: int = 10
    warmup: Warmup = Warmup.MEDIAN
    open_px: int = 3
    close_px: int = 5
    luminance: Luminance = Luminance.BT601
    centroid: Centroid = Centroid.MATTE
    color: bool = True
    hold_foreground: bool = True
    hold_margin_px: int = 2
    absorb_s: float = 5.0
    fill_holes: bool = True
    convex: bool = True
    merge_gap: float = 0.3
    max_foreground: float = 0.5
    max_blobs: int = 200
    gain: bool = True
    hysteresis: float = 0.65
    grow_px: int = 4
    learn_stride: int = 6
    disc_max_px: int = 24
    shadows: bool = True
    shadow_ratio: tuple[float, float] = (0.15, 0.92)
    near_objects: bool = True


PAPER = DetectorParams(
    warmup=Warmup.MEAN,
    close_px=0,
    centroid=Centroid.BINARY,
    color=False,
    hold_foreground=False,
    shadows=False,
    near_objects=False,
    fill_holes=False,
    convex=False,
    merge_gap=0.0,
    gain=False,
    hysteresis=0.0,
    learn_stride=1,
)
"""The paper's sec. II as written (eq. 2-5 with eq. 3 everywhere), plus only the opening."""


@dataclass(frozen=True, slots=True)
class Blobs:
    """Blobs of one frame as parallel arrays (n rows each).

    ``centroid_px`` (n, 2) float64 image x, y (eq. 5); ``bbox_px`` (n, 4) int32 x, y, w, h;
    ``area_px`` (n,) int32 pixel count of the support; ``support`` n uint8 (h, w) masks (255
    on the object) aligned with each bounding box.
    """

    centroid_px: np.ndarray
    bbox_px: np.ndarray
    area_px: np.ndarray
    support: tuple[np.ndarray, ...] = ()

    def __len__(self) -> int:
        return int(self.area_px.shape[0])

    @staticmethod
    def empty() -> Blobs:
        """No blobs: one shared instance (its arrays are empty and read only)."""
        return _NO_BLOBS


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


_NO_BLOBS = Blobs(
    _frozen(np.zeros((0, 2))), _frozen(np.zeros((0, 4), np.int32)), _frozen(np.zeros(0, np.int32))
)


_MEAN_RGB = np.full((1, 3), 1.0 / 3.0, dtype=np.float32)
_THIRDS = np.full(3, 1.0 / 3.0, dtype=np.float32)


def luminance(image: np.ndarray, mode: Luminance) -> np.ndarray:
    """Eq. 2: the (h, w) uint8 luminance of a (h, w) grey or (h, w, 3) BGR uint8 frame."""
    if image.ndim == 2:
        return image
    if mode is Luminance.MEAN:
        return cv2.transform(image, _MEAN_RGB)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


_CROSS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], np.uint8)
"""A pixel's four neighbours, without the pixel: eroding by it marks the pixels whose four
neighbours are all set."""


def _kernel(side: int) -> np.ndarray | None:
    return cv2.getStructuringElement(cv2.MORPH_RECT, (side, side)) if side > 1 else None


class Detector:
    """Background-subtraction detector for one eye (stateful: it owns the background T)."""

    def __init__(self, params: DetectorParams) -> None:
        if not 0.0 <= params.beta < 1.0:
            raise ValueError(f"beta must be in [0, 1), got {params.beta}")
        if params.learn_stride < 1:
            raise ValueError(f"learn_stride must be at least 1, got {params.learn_stride}")
        self.params = params
        self._background: np.ndarray | None = None
        self._coarse: np.ndarray | None = None
        """T on the first pass's rows rounded to grey levels (uint8), kept in step with T row
        by row as eq. 3 learns (:meth:`_learned_rows`); ``None`` until first taken, and after
        T is replaced (a new background, a rescale, a stride whose rows are not the first
        pass's) until taken again."""
        self._coarse_version = 0
        """Counts the changes to ``_coarse``: what the gain keeps of it is of this version."""
        self._over_range = False
        """Whether T may exceed 255.5 somewhere (a rescale brightened it past what a frame can
        hold), so that rounded and clipped to grey levels it may be more than half a level
        off: set at each rescale, and only a rescale can raise T past the frames' range."""
        self._gain_base: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None
        """The version of ``_coarse`` and, on the gain's grid, T's mean over the channels there
        (float32, 1 where it is too dark to count), where it is bright enough to count (bool),
        and its values there."""
        self._learned = 0
        """Frames eq. 3 has learned (after the warm-up): which rows the next one updates."""
        self._beta = 1.0 - (1.0 - params.beta) ** params.learn_stride
        self._frame: np.ndarray | None = None
        self._warm: list[np.ndarray] = []
        self._seen = 0
        self._t_s = 0.0
        self._t0_ns: int | None = None
        self._since: np.ndarray | None = None
        """When each pixel was last background (s), kept up to date inside ``_held_roi``."""
        self._held_roi: Rect | None = None
        self._held_t: float | None = None
        """The instant (s) of the last frame :meth:`_held` saw."""
        self._roi: Rect | None = None
        """The rectangle around this frame's foreground, grown by what the morphology and the
        hold can reach; ``None`` when nothing is foreground."""
        self._part: np.ndarray | None = None
        """This frame's foreground bitmap inside ``_roi`` (uint8, 0 or 255): everything of M
        that is not zero, so no whole-frame bitmap is made unless :attr:`mask` is asked for."""
        self._grown: np.ndarray | None = None
        self._shade: np.ndarray | None = None
        """This frame's cast shadows inside ``_roi`` (uint8 255), left out of the objects but
        held out of eq. 3 with them: learned, a passing shadow would leave a bright trail."""
        """``_part`` grown by ``hold_margin_px`` when the closing made it on the way (the
        held foreground, see :meth:`_held`), else ``None``."""
        self._shape: tuple[int, int] | None = None
        """(h, w) px of the frame M belongs to; ``None`` before M exists."""
        self._mask: np.ndarray | None = None
        m = 3 * params.grow_px + params.open_px + params.close_px + 2 * params.hold_margin_px
        self._margin = m + 2 + (max(params.open_px, 1) - 1)
        self._open = _kernel(params.open_px)
        self._close = _kernel(params.close_px)
        self._hold = _kernel(2 * params.hold_margin_px + 1)
        self._hold_is_close = (
            params.close_px > 1 and params.close_px == 2 * params.hold_margin_px + 1
        )
        """Whether the closing's kernel is the hold's: then the closing's dilation is the held
        foreground (a dilation is unchanged by an opening with its own kernel, so dilating
        the closed bitmap gives the dilation the closing started from)."""
        low = params.hysteresis * params.threshold
        self._grow = _kernel(2 * params.grow_px + 1) if 0 < low < params.threshold else None
        self._low_u8 = float(math.ceil(low) - 1)
        self._thresh_u8 = float(math.ceil(params.threshold) - 1)
        """d >= t on integer grey levels is d > ceil(t) - 1 (THRESH_BINARY is strict)."""
        self._find_u8 = self._low_u8 if self._grow is not None else self._thresh_u8
        self._row_step = max(d for d in _ROW_STEPS if d <= max(params.open_px, 1))
        """Rows apart that the first pass of eq. 4 looks at. A pixel the opening keeps lies in
        an ``open_px`` square of pixels, inside the image, each at least the weak level (the
        threshold without hysteresis), so any ``open_px`` rows in a row hold part of it: the
        rectangle around what those rows show, grown by ``_margin`` (what the hysteresis and
        the morphology reach, plus the rows skipped), holds the whole foreground, and the
        result is that of every pixel for a third of the whole-frame work (``open_px`` 3).
        The rows are views of the frame: nothing is copied to look at them."""
        self._grid_of: tuple[int, ...] = ()
        """The image size (h, w px) ``_gain_step`` was found for."""
        self._gain_step = _GAIN_STEP
        """Pixel step of the gain's grid in this image (``_GAIN_POINTS``)."""
        self._touches_coarse = math.gcd(params.learn_stride, self._row_step)
        """Eq. 3 changes the first pass's rows on the frames whose phase (``_learned`` modulo
        ``learn_stride``) is a multiple of this."""
        self.saturated = 0
        """Frames that were saturated (see the module docstring) and reported empty."""
        self._saturated_run = 0

    @property
    def warming_up(self) -> bool:
        return self._seen < self.params.warmup_frames

    @property
    def mask(self) -> np.ndarray | None:
        """The last foreground bitmap M of eq. 4 (uint8 (h, w), 0 or 255), after opening and
        closing; ``None`` before the first detection. Made on demand (the detector itself
        works on the rectangle around the foreground), a new array each frame, never
        modified afterwards (overlays may hold it)."""
        if self._mask is None and self._shape is not None:
            mask = np.zeros(self._shape, np.uint8)
            if self._roi is not None and self._part is not None:
                x0, y0, x1, y1 = self._roi
                mask[y0:y1, x0:x1] = self._part
            self._mask = mask
        return self._mask

    @property
    def background(self) -> np.ndarray | None:
        """The float32 background T (grey levels, one channel or three), ``None`` before the
        first frame."""
        return self._background

    def adopt(self, other: Detector) -> None:
        """Take over another detector's background (its parameters may differ)."""
        if other._background is not None and not other.warming_up:
            if other._background.ndim == 3 and not self.params.color:
                self._background = cv2.cvtColor(other._background, cv2.COLOR_BGR2GRAY)
            else:  # a grey background of grey frames serves a colour detector too
                self._background = other._background.copy()
            self._coarse = None
            self._over_range = other._over_range
            self._learned = other._learned  # the rows' turn goes on where it was
            self._seen = self.params.warmup_frames
            self._t0_ns = other._t0_ns
            if other._since is not None:
                self._since = other._since.copy()
                self._held_roi = other._held_roi
                self._held_t = other._held_t

    def reset(self) -> None:
        """Forget the background (after a lighting jump or a camera re-plug); the next frames
        are its warm-up again."""
        self._background = None
        self._coarse = None
        self._over_range = False
        self._learned = 0
        self._warm = []
        self._seen = 0
        self._since = None
        self._held_roi = None
        self._held_t = None
        self._set_foreground(None, None, None)
        self._saturated_run = 0

    def detect(self, image: np.ndarray, frozen: Sequence[Rect] = (), t_ns: int = 0) -> Blobs:
        """Find moving blobs in one frame, then update the background (eq. 2-5).

        ``frozen``: rectangles (x0, y0, x1, y1 px, end exclusive) where eq. 3 must not update T.
        """
        blobs = self.find(image, t_ns)
        self.learn(frozen)
        return blobs

    def _prepare(self, image: np.ndarray) -> np.ndarray:
        """The frame as the background stores it: BGR when detecting in colour, else grey."""
        if self.params.color and image.ndim == 3:
            return image
        return luminance(image, self.params.luminance)

    def _set_foreground(
        self,
        shape: tuple[int, int] | None,
        roi: Rect | None,
        part: np.ndarray | None,
        grown: np.ndarray | None = None,
    ) -> None:
        self._shape, self._roi, self._part, self._mask = shape, roi, part, None
        self._grown = grown
        self._shade = None

    def find(self, image: np.ndarray, t_ns: int = 0) -> Blobs:
        """Eq. 2, 4 and 5 against the current background at capture instant ``t_ns`` (ns);
        call :meth:`learn` afterwards.

        Eq. 4 is first taken on every ``_row_step``-th row only, channel by channel, which is
        enough to find the rectangle around the foreground (see ``_row_step`` and
        :func:`_above_any`), then on every pixel inside it."""
        frame = self._prepare(image)
        self._frame = frame
        if self._t0_ns is None:
            self._t0_ns = t_ns
        self._t_s = (t_ns - self._t0_ns) * 1e-9
        bg = self._background
        if (bg is not None and bg.shape != frame.shape) or (
            self._warm and self._warm[0].shape != frame.shape
        ):  # another size (a camera re-plugged in another mode): learn it afresh
            self.reset()
            bg = None
        if bg is None or self.warming_up:
            return Blobs.empty()
        step = self._row_step
        shape = (frame.shape[0], frame.shape[1])
        bg8 = self._coarse_background(bg)
        grid = frame[::step]
        coarse = cv2.absdiff(grid, bg8)
        level = self._find_u8
        g = self._gain(grid, bg8, shape) if self.params.gain else 1.0
        if _negligible(g):
            g = 1.0
        else:  # against g T
            if abs(g - 1.0) > _GAIN_RESCALE:  # the light changed: learn at the new gain
                np.multiply(bg, np.float32(g), out=bg)
                self._over_range = float(bg.max()) >= 255.5
                g = 1.0
                self._coarse = None  # T changed: round it again
                scaled = self._coarse_background(bg)
            elif self._over_range:  # T clipped at 255 on its rows: scale T itself
                scaled = cv2.convertScaleAbs(bg[::step], alpha=g)
            else:  # g times T rounded is g T rounded within one level: look one level lower
                scaled = cv2.convertScaleAbs(bg8, alpha=g)
                level -= 1.0
            coarse = cv2.absdiff(grid, scaled)
        x, y, w, h = _above_any(coarse, level)
        box = (x, y * step, w, (h - 1) * step + 1)
        roi = _grown_rect(box, self._margin, shape) if h else None
        if roi is None:  # nothing moved: no bitmap, no morphology, no contours
            return self._nothing(shape)
        x0, y0, x1, y1 = roi
        b8 = cv2.convertScaleAbs(bg[y0:y1, x0:x1], alpha=g)
        diff = _mean_channels(cv2.absdiff(frame[y0:y1, x0:x1], b8))
        _, part = cv2.threshold(diff, self._thresh_u8, 255, cv2.THRESH_BINARY)
        if self._grow is not None:
            _, weak = cv2.threshold(diff, self._low_u8, 255, cv2.THRESH_BINARY)
            count = cv2.countNonZero(part)
            if count == 0:  # no seed: nothing can grow
                return self._nothing(shape)
            for _ in range(3):  # (what is above t is weak too, and the kernel holds its centre,
                part = cv2.bitwise_and(weak, cv2.dilate(part, self._grow))  # so part stays)
                count, before = cv2.countNonZero(part), count
                if count == before:  # nothing weak left within reach
                    break
        shade = None
        if self.params.shadows:
            shade = shadow_mask(frame[y0:y1, x0:x1], b8, part, self.params.shadow_ratio)
            if shade is not None:
                part = cv2.subtract(part, shade)
                if cv2.countNonZero(part) == 0:  # only shadow: nothing found, all held
                    self._set_foreground(shape, roi, part)
                    self._shade = shade
                    self._saturated_run = 0
                    return Blobs.empty()
        if self._open is not None and self.params.fill_holes:
            # A pinhole (a pixel the colour of the background behind it, all four neighbours
            # foreground) is foreground: the opening's square would otherwise fit nowhere in
            # a ball a few pixels across, and it would vanish. Its row neighbours are
            # foreground, so the first pass still sees every row the opening keeps.
            pins = cv2.erode(part, _CROSS, borderType=cv2.BORDER_CONSTANT, borderValue=0)
            part = cv2.bitwise_or(part, pins)
        if self._open is not None:
            # Outside the rectangle is background to the opening (OpenCV's default border
            # counts it as foreground for the erosion): a strip thinner than ``open_px`` goes
            # at the image's and the rectangle's edges as it does anywhere else.
            part = cv2.morphologyEx(
                part, cv2.MORPH_OPEN, self._open, borderType=cv2.BORDER_CONSTANT, borderValue=0
            )
        grown = None
        if self._close is not None:  # the closing, keeping its dilation for the hold
            dilated = cv2.dilate(part, self._close)
            part = cv2.erode(dilated, self._close)
            if self._hold_is_close:
                grown = dilated
        count = cv2.countNonZero(part)
        if count == 0:
            return self._nothing(shape)
        self._set_foreground(shape, roi, part, grown)
        self._shade = shade
        if count > self.params.max_foreground * shape[0] * shape[1] and (
            not self.params.near_objects
            or scene_changed(frame[y0:y1, x0:x1], b8, part, (x0, y0), shape)
        ):
            return self._saturated()
        contours, _ = cv2.findContours(
            part, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE, offset=(x0, y0)
        )
        if len(contours) > self.params.max_blobs:
            return self._saturated()
        self._saturated_run = 0
        if self.params.centroid is Centroid.MATTE:
            return self._blobs(contours, part, (x0, y0), diff, frame[y0:y1, x0:x1], b8)
        return self._blobs(contours, part, (x0, y0), diff)

    def _coarse_background(self, bg: np.ndarray) -> np.ndarray:
        """T on the first pass's rows rounded to grey levels (uint8): the cached copy, or
        taken from the whole of ``bg`` when there is none. Eq. 3's rows are brought up to date
        in the cache by :meth:`_learned_rows` as they are learned."""
        if self._coarse is None:
            if self._grid_of != bg.shape[:2]:
                self._grid_of = bg.shape[:2]
                points = bg.shape[0] * bg.shape[1] / (_GAIN_STEP * _GAIN_STEP * _GAIN_POINTS)
                self._gain_step = _GAIN_STEP * max(1, int(math.sqrt(points)))
            self._coarse = cv2.convertScaleAbs(bg[:: self._row_step])
            self._coarse_version += 1
        return self._coarse

    def _nothing(self, shape: tuple[int, int]) -> Blobs:
        """No foreground in this frame (of ``shape`` (h, w) px)."""
        self._set_foreground(shape, None, None)
        self._saturated_run = 0
        return Blobs.empty()

    def _gain(self, grid: np.ndarray, grid8: np.ndarray, shape: tuple[int, int]) -> float:
        """Median of frame / background over every ``_gain_step``-th pixel each way that was
        background in the last frame and is not dark: the global gain, 1.0 when unknown.
        ``grid`` is the frame of ``shape`` (h, w) px on the first pass's rows and ``grid8``
        T there rounded to grey levels, as eq. 4 has just used them (rounding moves a ratio
        by at most 2.5 % at the darkest level counted, 0.5 % at mid-grey, and evenly both
        ways)."""
        s = self._gain_step
        ky = s // self._row_step
        f = grid[::ky, ::s]  # the pixels (s i, s j)
        f = f @ _THIRDS if f.ndim == 3 else f.astype(np.float32)  # (numpy sums a short last
        if self._gain_base is None or self._gain_base[0] != self._coarse_version:  # axis slowly)
            b = grid8[::ky, ::s].astype(np.float32)  # T there changes on a third of frames
            if b.ndim == 3:
                b = b @ _THIRDS
            bright = b > _GAIN_MIN_LEVEL
            self._gain_base = (self._coarse_version, np.where(bright, b, 1.0), bright, b[bright])
        _, b, use, bs = self._gain_base
        if self._roi is not None and self._part is not None and self._shape == shape:
            # not the grid points inside the last foreground's rectangle that were foreground
            x0, y0 = self._roi[0], self._roi[1]
            gx, gy = -(-x0 // s), -(-y0 // s)
            fg = self._part[gy * s - y0 :: s, gx * s - x0 :: s]
            use = use.copy()
            use[gy : gy + fg.shape[0], gx : gx + fg.shape[1]] &= fg == 0
            bs = b[use]
        if bs.size < 32:
            return 1.0
        k = bs.size // 2  # numpy's vectorised sort beats its partition on these few points
        g = float(np.sort((f / b)[use])[k])
        if _negligible(g):
            return g  # not applied: nothing to check
        # A gain must explain the change: what is left must look like sensor noise. A light
        # switched on unevenly, or a scene that changed, is not a gain: left alone, it
        # saturates the frame and the background is learned afresh.
        misfit = np.abs(f[use] - g * bs)
        if float(np.sort(misfit)[k]) > _GAIN_MAX_MISFIT * self.params.threshold:
            return 1.0
        return g

    def _saturated(self) -> Blobs:
        self.saturated += 1
        self._saturated_run += 1
        if self._saturated_run > self.params.warmup_frames:
            self.reset()  # the scene changed for good: learn it again
        return Blobs.empty()

    def learn(self, frozen: Sequence[Rect] = (), released: Sequence[Rect] = ()) -> None:
        """Eq. 3 with the frame last given to :meth:`find`: during warm-up the frames are kept
        for the initial background, then T = T (1 - beta) + L beta where allowed: not in the
        ``frozen`` rectangles (objects the tracker freezes), and not on held foreground unless
        in a ``released`` one (an object the tracker knows has stopped for good). Rectangles
        are (x0, y0, x1, y1) px, end exclusive. Eq. 3 runs on every ``learn_stride``-th row, in
        turn, in one call; what it must not have changed there (:meth:`_kept`: the learned rows
        under the frozen and held rectangles' union) is copied before and put back after."""
        frame = self._frame
        if frame is None:
            return
        self._frame = None
        p = self.params
        if self.warming_up:
            self._warmup(frame)
            return
        bg = self._background
        assert bg is not None
        h, w = bg.shape[:2]
        held = self._held() if p.hold_foreground else None
        boxes = [r for r in (_clipped(b, w, h) for b in frozen) if r is not None]
        phase = self._learned % p.learn_stride
        self._learned += 1
        rows = slice(phase, None, p.learn_stride)
        kept = self._kept(bg, phase, held, boxes, released)
        cv2.accumulateWeighted(frame[rows], bg[rows], self._beta)
        if kept is not None:
            region, before, keep = kept
            cv2.copyTo(before, keep, region)  # in place: ``region`` is a view of T
        self._learned_rows(bg, phase)

    def _kept(
        self,
        bg: np.ndarray,
        phase: int,
        held: tuple[Rect, np.ndarray] | None,
        boxes: list[Rect],
        released: Sequence[Rect],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """What eq. 3 must not change among the rows of ``phase``: the view of T over them
        around the rectangles, a copy of it, and where to put the copy back (uint8 255: in
        the ``boxes`` and on held foreground outside the ``released`` rectangles); ``None``
        when nothing there is to be kept."""
        stride = self.params.learn_stride
        rects = [*boxes, held[0]] if held is not None else boxes
        if not rects:
            return None
        ux0, uy0, ux1, uy1 = rects[0]
        for x0, y0, x1, y1 in rects[1:]:
            ux0, uy0, ux1, uy1 = min(ux0, x0), min(uy0, y0), max(ux1, x1), max(uy1, y1)
        first = uy0 + (phase - uy0) % stride  # the first of its rows eq. 3 learns now
        if first >= uy1:
            return None
        mine = slice(first - uy0, None, stride)
        region = bg[uy0:uy1, ux0:ux1][mine]
        keep = np.zeros(region.shape[:2], np.uint8)
        if held is not None:
            (x0, y0, x1, y1), mask = held
            if released:
                mask = mask.copy()  # it may be the detector's own (``_grown``)
                for r in released:
                    c = _clipped(r, x1, y1, x0, y0)
                    if c is not None:
                        mask[c[1] - y0 : c[3] - y0, c[0] - x0 : c[2] - x0] = 0
            _put_rows(keep, mask, x0 - ux0, y0 - uy0, first - uy0, stride)
        for x0, y0, x1, y1 in boxes:
            keep[_rows_within(y0 - uy0, y1 - uy0, first - uy0, stride), x0 - ux0 : x1 - ux0] = 255
        return region, region.copy(), keep

    def _learned_rows(self, bg: np.ndarray, phase: int) -> None:
        """After eq. 3 updated the rows of ``phase``: round the first pass's rows of T again if
        they were among them (only those, when every row learned is one of them)."""
        if phase % self._touches_coarse != 0 or phase >= bg.shape[0]:
            return  # none of its rows are the first pass's (or there are none)
        stride, step = self.params.learn_stride, self._row_step
        if self._coarse is None or stride % step != 0:
            self._coarse = None
            self._coarse_background(bg)
            return
        rows = slice(phase // step, None, stride // step)  # rows phase + stride k of T
        self._coarse[rows] = cv2.convertScaleAbs(bg[phase::stride])
        self._coarse_version += 1

    def _warmup(self, frame: np.ndarray) -> None:
        p = self.params
        self._seen += 1
        if p.warmup is Warmup.MEDIAN:
            self._warm.append(frame)
            if not self.warming_up:
                stack = np.stack(self._warm)  # uint8: partitioned in place, no float copy
                n = len(self._warm)
                k = n // 2
                stack.partition((k - 1, k) if n % 2 == 0 and n > 1 else k, axis=0)
                median = stack[k].astype(np.float32)
                if n % 2 == 0 and n > 1:
                    median = (median + stack[k - 1]) * np.float32(0.5)
                self._background = median
                self._coarse = None
                self._warm = []
        elif self._background is None:
            self._background = frame.astype(np.float32)
        else:
            cv2.accumulateWeighted(frame, self._background, 1.0 / self._seen)
        self._coarse = None

    def _held(self) -> tuple[Rect, np.ndarray] | None:
        """Inside the rectangle around this frame's foreground, where eq. 3 must not learn
        (uint8 255): the foreground grown by ``hold_margin_px``, less what has stayed
        foreground ``absorb_s`` seconds (it is still: make it background). Outside it
        everything may be learned; ``None`` when nothing is foreground. Keeps ``_since`` up to
        date inside the rectangle: for each pixel held now, the last frame it was not (for a
        pixel outside the last frame's rectangle, that frame, whatever the rectangle's
        reach), and for every other pixel, now."""
        shape = self._shape
        assert shape is not None
        now, before = self._t_s, self._held_t
        self._held_t = now
        if self._since is None or self._since.shape != shape:
            self._since = np.full(shape, now, np.float32)
            self._held_roi = None
            before = None
        prev, roi = self._held_roi, self._roi
        self._held_roi = roi
        if roi is None or self._part is None:
            return None
        x0, y0, x1, y1 = roi
        grown = self._grown
        if grown is None:
            grown = cv2.dilate(self._part, self._hold) if self._hold is not None else self._part
        if self._shade is not None:
            grown = cv2.bitwise_or(grown, self._shade)
        since = self._since[y0:y1, x0:x1]
        old = None
        if prev is not None:
            kx0, ky0 = max(prev[0] - x0, 0), max(prev[1] - y0, 0)
            kx1, ky1 = min(prev[2] - x0, x1 - x0), min(prev[3] - y0, y1 - y0)
            if kx1 > kx0 and ky1 > ky0:
                old = since[ky0:ky1, kx0:kx1].copy()
        since.fill(now)
        held_since = now if before is None else before
        if held_since != now:
            np.putmask(since, grown != 0, held_since)  # held, not in the last rectangle: then
        if old is not None:  # held, and in the last rectangle: its time as it was kept
            cv2.copyTo(old, grown[ky0:ky1, kx0:kx1], since[ky0:ky1, kx0:kx1])  # in place
        limit = now - self.params.absorb_s
        if min(held_since, float(old.min()) if old is not None else held_since) >= limit:
            return roi, grown  # no time kept is that old: nothing is still
        if since.size == 1:  # OpenCV takes a one-element array for a scalar: give it two arrays
            stale = cv2.compare(since, np.full(since.shape, limit, np.float32), cv2.CMP_LT)
        else:
            stale = cv2.compare(since, np.float64(limit), cv2.CMP_LT)
        return roi, cv2.subtract(grown, stale)

    def _blobs(
        self,
        contours: Sequence[np.ndarray],
        part: np.ndarray,
        origin: tuple[int, int],
        diff: np.ndarray,
        frame: np.ndarray | None = None,
        background: np.ndarray | None = None,
    ) -> Blobs:
        """Each object's support, centre, box and area; ``part`` is M and ``diff`` R (eq. 4)
        inside the foreground's rectangle, at ``origin`` (x, y px) of the image, and
        ``frame`` and ``background`` (uint8, at the frame's gain) there when matting."""
        p = self.params
        centres, boxes, areas, supports = [], [], [], []
        for group in _groups(contours, p.merge_gap):
            points = group[0] if len(group) == 1 else np.concatenate(group)
            x, y, bw, bh = cv2.boundingRect(points)
            if bw * bh < p.min_area_px:
                continue
            own: np.ndarray = np.zeros((bh, bw), np.uint8)
            outlines = [cv2.convexHull(points)] if p.convex else list(group)
            cv2.drawContours(own, outlines, -1, 255, -1, offset=(-x, -y))
            if not p.fill_holes:
                px, py = x - origin[0], y - origin[1]
                own = cv2.bitwise_and(own, part[py : py + bh, px : px + bw])
            area = cv2.countNonZero(own)
            if area < p.min_area_px:
                continue
            if p.centroid is Centroid.MATTE and frame is not None and background is not None:
                at = (x - origin[0], y - origin[1])
                cx, cy = matte_centroid(own, frame, background, diff, at, p.threshold)
                centre = (cx + origin[0], cy + origin[1])
                if max(bw, bh) <= p.disc_max_px and is_round(own, area):
                    fit = disc_centre(frame, background, (*at, bw, bh), (cx, cy), area)
                    if fit is not None:
                        centre = (fit[0] + origin[0], fit[1] + origin[1])
            elif p.centroid is not Centroid.BINARY:
                cx, cy = coverage_centroid(own, diff, (x - origin[0], y - origin[1]), p.threshold)
                centre = (cx + origin[0], cy + origin[1])
            else:
                m = cv2.moments(own, binaryImage=True)
                centre = (x + m["m10"] / m["m00"], y + m["m01"] / m["m00"])
            centres.append(centre)
            boxes.append((x, y, bw, bh))
            areas.append(area)
            supports.append(own)
        if not centres:
            return Blobs.empty()
        return Blobs(
            centroid_px=np.asarray(centres, np.float64),
            bbox_px=np.asarray(boxes, np.int32),
            area_px=np.asarray(areas, np.int32),
            support=tuple(supports),
        )


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
SHADOW_CHROMA = 0.06
"""How far (share of the brightness) a shadowed pixel's colour may stray from the background's
scaled by the pixel's own ratio."""


def _relit(
    frame: np.ndarray,
    background: np.ndarray,
    foreground: np.ndarray,
    ratio: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the foreground is the background under other light: the candidates (uint8 255;
    brightness times a factor within ``ratio``, lower and upper, and in colour each channel
    the background's times that factor within ``SHADOW_CHROMA``: Cucchiara et al.'s V, H and
    S tests without leaving BGR) and, among them, the sure ones, whose window (side
    ``SHADOW_WINDOW_PX``) keeps the background's texture (normalised cross-correlation at
    least ``SHADOW_MIN_NCC``, as much texture as the factor leaves, one factor across it
    within ``SHADOW_RATIO_SPREAD``). Only a textured background can tell: on a flat one a
    darker object of its colour (a shaded side) looks the same. ``None`` when no pixel is a
    candidate."""
    lo, hi = ratio
    colour = frame.ndim == 3
    # The brightness ratio first, on one channel: most of an object is no candidate, and the
    # rest of the test runs only around the candidates.
    fl8 = cv2.transform(frame, _MEAN_RGB) if colour else frame
    bl8 = cv2.transform(background, _MEAN_RGB) if colour else background
    r = fl8.astype(np.float32) / (bl8.astype(np.float32) + np.float32(1.0))
    cand_all = cv2.bitwise_and(cv2.inRange(r, lo, hi), foreground)
    if cv2.countNonZero(cand_all) == 0:
        return None
    x, y, w, h = cv2.boundingRect(cand_all)
    m = SHADOW_WINDOW_PX
    x0, y0 = max(x - m, 0), max(y - m, 0)
    x1, y1 = min(x + w + m, frame.shape[1]), min(y + h + m, frame.shape[0])
    sl = (slice(y0, y1), slice(x0, x1))
    f = frame[sl].astype(np.float32)
    b = background[sl].astype(np.float32)
    fl = cv2.transform(f, _MEAN_RGB) if colour else f
    bl = cv2.transform(b, _MEAN_RGB) if colour else b
    r = fl / (bl + 1.0)
    cand = cand_all[sl]
    if colour:
        off = np.abs(f - b * r[..., None]).max(axis=2)
        same_colour = off <= SHADOW_CHROMA * (bl + 1.0) + 3.0
        cand = cv2.bitwise_and(cand, same_colour.view(np.uint8) * np.uint8(255))
    if cv2.countNonZero(cand) == 0:
        return None
    k = (SHADOW_WINDOW_PX, SHADOW_WINDOW_PX)
    mf, mb = cv2.blur(fl, k), cv2.blur(bl, k)
    vf = cv2.blur(fl * fl, k) - mf * mf
    vb = cv2.blur(bl * bl, k) - mb * mb
    cov = cv2.blur(fl * bl, k) - mf * mb
    textured = vb >= SHADOW_MIN_TEXTURE * SHADOW_MIN_TEXTURE
    ncc = cov / np.sqrt(np.maximum(vf * vb, 1e-6))
    gain = mf / (mb + 1.0)  # the window's factor: its texture is the background's times it
    mr = cv2.blur(r, k)
    vr = cv2.blur(r * r, k) - mr * mr  # other light changes its whole window alike
    keeps_texture = (
        textured
        & (ncc >= SHADOW_MIN_NCC)
        & (vf >= 0.25 * gain * gain * vb)
        & (vr <= (SHADOW_RATIO_SPREAD * mr) ** 2)
    )
    core = cv2.bitwise_and(cand, keeps_texture.view(np.uint8) * np.uint8(255))
    full_cand = np.zeros_like(cand_all)
    full_core = np.zeros_like(cand_all)
    full_cand[sl] = cand
    full_core[sl] = core
    return full_cand, full_core


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
    cand, core = found
    if cv2.countNonZero(core) == 0:
        return None
    # The candidates connected to a sure shadow pixel (8-neighbours), not those across a gap:
    # a dark stripe on the object beside its shadow is a candidate too, apart from it.
    n, labels = cv2.connectedComponents(cand, connectivity=8, ltype=cv2.CV_16U)
    if n <= 1:
        return None
    sure = np.zeros(n, np.uint8)
    sure[np.unique(labels[core > 0])] = 255
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
    return found is not None and cv2.countNonZero(found[1]) >= SCENE_CHANGE_RELIT * count


def _mean_channels(diff: np.ndarray) -> np.ndarray:
    """The colour difference of eq. 4: the mean of the three channels' absolute differences
    (uint8); a one-channel difference as it is."""
    return cv2.transform(diff, _MEAN_RGB) if diff.ndim == 3 else diff


def _negligible(gain: float) -> bool:
    """Whether a gain moves no grey level (0-255) by half a level: T is then used as learned."""
    return abs(gain - 1.0) * 255.0 < 0.5


def _above_any(diff: np.ndarray, level: float) -> tuple[int, int, int, int]:
    """The bounding box (x, y, w, h px) of the pixels of ``diff`` where any channel is above
    ``level`` (see :func:`_above`). Every pixel whose mean over the channels is above it is
    among them, so the box holds eq. 4's colour foreground; a channel alone may add a little
    to it, and the every-pixel pass inside decides. Taking the channels as they lie, as one
    row of bytes, saves averaging them over the whole grid."""
    if diff.ndim == 2:
        return _above(diff, level)
    n = diff.shape[2]
    x, y, w, h = _above(diff.reshape(diff.shape[0], -1), level)
    if h == 0:
        return (0, 0, 0, 0)
    return (x // n, y, (x + w - 1) // n - x // n + 1, h)


def _above(diff: np.ndarray, level: float) -> tuple[int, int, int, int]:
    """The bounding box (x, y, w, h px) of the pixels of ``diff`` above ``level``, (0, 0, 0, 0)
    when there are none: the columns' maxima give its sides, and the bitmap of only the
    columns between them its top and bottom (no whole-frame bitmap)."""
    cols = diff.max(axis=0) > level
    x0 = int(cols.argmax())
    if not cols[x0]:
        return (0, 0, 0, 0)
    x1 = cols.size - int(cols[::-1].argmax())
    _, slab = cv2.threshold(diff[:, x0:x1], level, 255, cv2.THRESH_BINARY)
    _, y, _, h = cv2.boundingRect(slab)
    return (x0, y, x1 - x0, h)


def _rows_within(y0: int, y1: int, first: int, stride: int) -> slice:
    """The rows ``first + stride k`` (k >= 0) that lie in [y0, y1), as indices k."""
    lo = max(0, -(-(y0 - first) // stride))
    hi = max(lo, -(-(y1 - first) // stride))
    return slice(lo, hi)


def _put_rows(dst: np.ndarray, src: np.ndarray, x: int, y: int, first: int, stride: int) -> None:
    """Into ``dst``, whose rows are ``first + stride k`` of a plane, the rows of ``src`` (at
    (``x``, ``y``) of that plane) that are among them."""
    k = _rows_within(y, y + src.shape[0], first, stride)
    if k.stop > k.start:
        top = first + stride * k.start - y
        dst[k, x : x + src.shape[1]] = src[top::stride][: k.stop - k.start]


def _clipped(rect: Sequence[int], x1: int, y1: int, x0: int = 0, y0: int = 0) -> Rect | None:
    """A rectangle (x0, y0, x1, y1 px) cut to the window [x0, x1) x [y0, y1); ``None`` if
    nothing is left."""
    cx0, cy0 = max(int(rect[0]), x0), max(int(rect[1]), y0)
    cx1, cy1 = min(int(rect[2]), x1), min(int(rect[3]), y1)
    return (cx0, cy0, cx1, cy1) if cx1 > cx0 and cy1 > cy0 else None


def _grown_rect(rect: Sequence[int], margin: int, shape: tuple[int, ...]) -> Rect | None:
    """A rectangle (x, y, w, h) grown by ``margin`` px and clipped to the image, as (x0, y0,
    x1, y1); ``None`` for an empty one."""
    x, y, w, h = rect
    if w == 0 or h == 0:
        return None
    return (
        max(x - margin, 0),
        max(y - margin, 0),
        min(x + w + margin, shape[1]),
        min(y + h + margin, shape[0]),
    )


def _groups(contours: Sequence[np.ndarray], gap: float) -> list[list[np.ndarray]]:
    """The outlines grouped into objects: two outlines whose boxes are closer than ``gap``
    times the smaller one's size (px) are pieces of one object (a stripe, a shadowed band as
    bright as the floor behind it, split it)."""
    n = len(contours)
    if n <= 1 or gap <= 0:
        return [[c] for c in contours]
    boxes = np.array([cv2.boundingRect(c) for c in contours], np.float64)
    x0, y0 = boxes[:, 0], boxes[:, 1]
    x1, y1 = x0 + boxes[:, 2], y0 + boxes[:, 3]
    size = np.maximum(boxes[:, 2], boxes[:, 3])
    gx = np.maximum(
        0.0, np.maximum(x0[:, None], x0[None, :]) - np.minimum(x1[:, None], x1[None, :])
    )
    gy = np.maximum(
        0.0, np.maximum(y0[:, None], y0[None, :]) - np.minimum(y1[:, None], y1[None, :])
    )
    near = np.maximum(gx, gy) <= gap * np.minimum(size[:, None], size[None, :])
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(near, 1)), strict=True):
        parent[root(int(i))] = root(int(j))
    groups: dict[int, list[np.ndarray]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(contours[i])
    return list(groups.values())


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
    support: np.ndarray, diff: np.ndarray, origin: tuple[int, int], threshold: float
) -> tuple[float, float]:
    """Sub-pixel centre of one object (px): eq. 5 over its support, with eq. 4's hard
    threshold softened into a ramp at the edge. Interior pixels (the support eroded by one
    pixel) weigh 1 whatever their difference, so shading inside the object, or a patch of it
    that matches the background, does not pull the centre; each pixel of the edge band (one
    pixel either side of the outline) weighs (d - t/2) / t clipped to [0, 1], the share of it
    the object covers. ``support`` is (h, w) uint8 at ``origin`` (x, y) of ``diff``."""
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
    ``diff``."""
    x, y = origin
    bh, bw = support.shape
    x0, y0, x1, y1, own, inner = _padded(support, origin, diff.shape)
    if cv2.countNonZero(inner) < _MATTE_MIN_INTERIOR:
        return coverage_centroid(support, diff, origin, threshold)
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
    ob, fb = cv2.subtract(o, b, dtype=cv2.CV_32F), cv2.subtract(f, b, dtype=cv2.CV_32F)
    if f.ndim == 3:
        num, den = cv2.transform(fb * ob, _ONES3), cv2.transform(ob * ob, _ONES3)
        channels = 3
    else:
        num, den = fb * ob, ob * ob
        channels = 1
    usable = found & (den >= channels * (0.5 * threshold) ** 2) & (band > 0)
    np.divide(num, den, out=weight, where=usable)  # the ramp's weight where it is not usable
    np.clip(weight, 0.0, 1.0, out=weight)
    np.putmask(weight, inner, 1.0)
    m = cv2.moments(weight)
    if m["m00"] <= 0:
        return (x + (bw - 1) / 2.0, y + (bh - 1) / 2.0)
    return (x0 + m["m10"] / m["m00"], y0 + m["m01"] / m["m00"])
