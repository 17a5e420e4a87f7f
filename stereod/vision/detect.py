"""Moving-object detection by background subtraction, paper sec. II, on OpenCV whole-array calls.

Per eye and per frame: luminance (eq. 2) or colour, absolute difference to a running-average
background (eq. 4's R), threshold at ``t`` (eq. 4's M), a small opening (removes single-pixel
sensor noise) and closing (joins the pieces of one object), the objects' outlines, and each
object's centre of gravity (eq. 5), bounding box and area. The background is then updated by
eq. 3, ``T_i = T_{i-1} (1 - beta) + L_i beta``, kept in float32 (a uint8 background has a dead
band of 0.5/beta grey levels and never adapts).

Beyond the paper, each one chosen by measurement on two renderers (docs/accuracy.md):

- **No ghosts.** Eq. 3 learns a moving object into the background wherever it passes, and
  the trail it leaves is detected as objects that are not there. Here a pixel is not learned
  while it is foreground (the mask grown by ``hold_margin_px``), from the first frame it is;
  whatever stays foreground and still for ``absorb_s`` seconds becomes background at once (T
  takes the frame there), so a parked object or the ghost of something that left is gone, not
  learned over tens of frames in which its noise takes pixels out of the foreground and back
  in; what stays foreground but moves in place is learned by eq. 3 after ``absorb_s``.
  ``hold_foreground = false`` is eq. 3 as the paper writes it.
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

import math
from collections.abc import Sequence

import cv2
import numpy as np

from stereod.vision import row_disparity
from stereod.vision.background import GAIN_RESCALE, QUIET_LEVELS, BackgroundModel, negligible
from stereod.vision.blobs import Blobs, groups
from stereod.vision.centroids import coverage_centroid, matte_centroid
from stereod.vision.detect_params import Centroid, DetectorParams
from stereod.vision.disc import Candidate, disc_centres, is_round, warm_start
from stereod.vision.luminance import luminance, mean_channels
from stereod.vision.rects import Rect, above_any, grown_rect
from stereod.vision.shadows import scene_changed, shadow_mask

_CROSS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], np.uint8)
"""A pixel's four neighbours, without the pixel: eroding by it marks the pixels whose four
neighbours are all set."""


def _kernel(side: int) -> np.ndarray | None:
    return cv2.getStructuringElement(cv2.MORPH_RECT, (side, side)) if side > 1 else None


class Detector(BackgroundModel):
    """Background-subtraction detector for one eye (stateful: it owns the background T)."""

    def __init__(self, params: DetectorParams) -> None:
        super().__init__(params)
        self._roi: Rect | None = None
        """The rectangle around this frame's foreground, grown by what the morphology and the
        hold can reach; ``None`` when nothing is foreground."""
        self._part: np.ndarray | None = None
        """This frame's foreground bitmap inside ``_roi`` (uint8, 0 or 255): everything of M
        that is not zero, so no whole-frame bitmap is made unless :attr:`mask` is asked for."""
        self._grown: np.ndarray | None = None
        """``_part`` grown by ``hold_margin_px`` when the closing made it on the way (the
        held foreground, see :meth:`_held`), else ``None``."""
        self._shade: np.ndarray | None = None
        """This frame's cast shadows inside ``_roi`` (uint8 255), left out of the objects but
        held out of eq. 3 with them: learned, a passing shadow would leave a bright trail."""
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
        self._quiet = min(self._find_u8 // 2, QUIET_LEVELS)
        """The first pass's largest difference (grey levels) in a frame that is idle."""
        self.saturated = 0
        """Frames that were saturated (see the module docstring) and reported empty."""
        self._saturated_run = 0
        self._fit_later = False
        self._deferred: list[
            tuple[int, Candidate, tuple[int, int], tuple[float, float, float] | None]
        ] = []
        """The last frame's round blobs left to :func:`fit_round_blobs`: each one's index,
        its candidate in the foreground's rectangle, that rectangle's origin (x, y px) and
        where its fit starts (:func:`stereod.vision.disc.warm_start`, in the rectangle)."""
        self._fitted: list[tuple[float, float, float, float, float, float]] = []
        """The last fitted frame's disc fits, where the next frame's start
        (:func:`stereod.vision.disc.warm_start`): each blob's centre (x, y), its fit's
        centre (x, y) and radius, and the radius of a disc of its area (image px)."""

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
            self._ticks, self._idle = other._ticks, other._idle
            if self.params.learn_stride == other.params.learn_stride:
                self._last = list(other._last)
            else:
                stride = self.params.learn_stride
                self._last = [self._ticks - stride] * stride
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
        self._ticks, self._idle = 0, 0
        self._last = list(range(-self.params.learn_stride, 0))
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
        self._quiet_frame = False

    def find(self, image: np.ndarray, t_ns: int = 0, fit_later: bool = False) -> Blobs:
        """Eq. 2, 4 and 5 against the current background at capture instant ``t_ns`` (ns);
        call :meth:`learn` afterwards. ``fit_later``: the round blobs keep their matte centre
        until :func:`fit_round_blobs` fits them, with another eye's in the same batch.

        Eq. 4 is first taken on every ``_row_step``-th row only, channel by channel, which is
        enough to find the rectangle around the foreground (see ``_row_step`` and
        :func:`above_any`), then on every pixel inside it."""
        self._fit_later, self._deferred = fit_later, []
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
        if cv2.minMaxLoc(coarse.reshape(coarse.shape[0], -1))[1] <= self._quiet and (
            not self.params.gain or self._steady(grid, bg8)
        ):
            # nothing differs from T as learned by more than noise, nor by half the level,
            # and the frame's mean is T's within the gain's rescale: no gain to estimate (a
            # light that drifts slower is learned by eq. 3)
            return self._nothing(shape, idle=True)
        g = self._gain(grid, bg8, shape) if self.params.gain else 1.0
        if negligible(g):
            g = 1.0
        else:  # against g T
            if abs(g - 1.0) > GAIN_RESCALE:  # the light changed: learn at the new gain
                self._rescale(bg, frame, g)
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
        x, y, w, h = above_any(coarse, level)
        box = (x, y * step, w, (h - 1) * step + 1)
        roi = grown_rect(box, self._margin, shape) if h else None
        if roi is None:  # nothing moved: no bitmap, no morphology, no contours
            return self._nothing(shape)
        x0, y0, x1, y1 = roi
        b8 = cv2.convertScaleAbs(bg[y0:y1, x0:x1], alpha=g)
        diff = mean_channels(cv2.absdiff(frame[y0:y1, x0:x1], b8))
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

    def _nothing(self, shape: tuple[int, int], idle: bool = False) -> Blobs:
        """No foreground in this frame (of ``shape`` (h, w) px); ``idle``: nothing differs
        from T by more than noise (eq. 3 may then learn at its idle cadence)."""
        self._set_foreground(shape, None, None)
        self._quiet_frame = idle
        self._saturated_run = 0
        return Blobs.empty()

    def _saturated(self) -> Blobs:
        self.saturated += 1
        self._saturated_run += 1
        if self._saturated_run > self.params.warmup_frames:
            self.reset()  # the scene changed for good: learn it again
        return Blobs.empty()

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
        centres: list[tuple[float, float]] = []
        boxes, areas, supports = [], [], []
        rows: list[np.ndarray] = []
        # the round blobs' disc fits, all in one batch, and where each starts
        fits: list[tuple[int, Candidate, tuple[float, float, float] | None]] = []
        for group in groups(contours, p.merge_gap):
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
            got: list[np.ndarray] = []
            if p.centroid is Centroid.MATTE and frame is not None and background is not None:
                at = (x - origin[0], y - origin[1])
                cx, cy = matte_centroid(own, frame, background, diff, at, p.threshold, got)
                centre = (cx + origin[0], cy + origin[1])
                if max(bw, bh) <= p.disc_max_px and is_round(own, area):
                    start = warm_start(centre, area, self._fitted, max(bw, bh))
                    if start is not None:
                        start = (start[0] - origin[0], start[1] - origin[1], start[2])
                    blob = Candidate(frame, background, (*at, bw, bh), (cx, cy), area)
                    fits.append((len(centres), blob, start))
            elif p.centroid is not Centroid.BINARY:
                at = (x - origin[0], y - origin[1])
                cx, cy = coverage_centroid(own, diff, at, p.threshold, got)
                centre = (cx + origin[0], cy + origin[1])
            else:
                m = cv2.moments(own, binaryImage=True)
                centre = (x + m["m10"] / m["m00"], y + m["m01"] / m["m00"])
            rows.append(row_disparity.moved(got[0], *origin) if got else row_disparity.EMPTY)
            centres.append(centre)
            boxes.append((x, y, bw, bh))
            areas.append(area)
            supports.append(own)
        if not centres:
            return Blobs.empty()
        blobs = Blobs(
            centroid_px=np.asarray(centres, np.float64),
            bbox_px=np.asarray(boxes, np.int32),
            area_px=np.asarray(areas, np.int32),
            support=tuple(supports),
            rows=tuple(rows),
        )
        self._deferred = [(k, c, origin, start) for k, c, start in fits]
        if not fits:
            self._fitted = []
        if fits and not self._fit_later:
            fit_round_blobs([(self, blobs)])
        return blobs


def fit_round_blobs(eyes: Sequence[tuple[Detector, Blobs]]) -> None:
    """Centre the round blobs each detector left for later (:meth:`Detector.find` with
    ``fit_later``) on ``blobs``, its last frame's, by a disc fitted to the image
    (:func:`stereod.vision.disc.disc_centres`): every eye's in one batch, which costs about
    what one eye's alone does. The fitted centres (image px) replace the matte ones in place;
    a fit that is not to be trusted leaves its blob's."""
    jobs = [(det, blobs, job) for det, blobs in eyes for job in det._deferred]
    for det, _ in eyes:
        det._deferred, det._fitted = [], []
    if not jobs:
        return
    radii: list[float] = []
    cands = [c for _, _, (_, c, _, _) in jobs]
    fits = disc_centres(cands, [start for _, _, (*_, start) in jobs], radii)
    for (det, blobs, (k, c, (ox, oy), _)), fit, r in zip(jobs, fits, radii, strict=True):
        if fit is not None:
            blobs.centroid_px[k] = fit[0] + ox, fit[1] + oy
            at = (c.centre[0] + ox, c.centre[1] + oy, fit[0] + ox, fit[1] + oy, r)
            det._fitted.append((*at, math.sqrt(c.area / math.pi)))
