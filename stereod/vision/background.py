"""The detector's background model T: the warm-up, the global gain, eq. 3 on every
``learn_stride``-th row in turn, and the holds that keep it off foreground."""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from stereod.vision.detect_params import DetectorParams, Warmup
from stereod.vision.rects import Rect, clipped, put_rows, rows_within

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
GAIN_RESCALE = 0.01
"""A gain further than this from 1 scales the stored background itself."""
CLIP_LEVEL = 240
"""A frame's channel at or above this level (of 255) may be clipped, and tells only that the
light there is at least that: a webcam's MJPEG and 4:2:2 chroma spread a clip at 255 over the
levels just below it. When the light dims, T is not scaled below such a channel by more
than :data:`CLIP_SLACK` (:meth:`BackgroundModel._rescale`)."""
CLIP_SLACK = 8.0
"""How far (grey levels) T may stay below a clipped channel of the frame: a third of the
default threshold, and above sensor noise, so that T there does not climb on noise at each of a
flickering light's rescales."""
_ROW_STEPS = (1, 2, 3, 4, 6)
"""Row steps of eq. 4's first pass: divisors of ``_GAIN_STEP``, so the gain's points lie on
its rows."""
_THIRDS = np.full(3, 1.0 / 3.0, dtype=np.float32)
QUIET_LEVELS = 10
"""A frame whose first pass differs from T by at most this (grey levels), and by at most half
the level it looks for, and whose mean is T's within ``GAIN_RESCALE``, is idle: sensor
noise's largest excursion over the first pass's grid is 7-9 levels at a noise of 2 levels."""
IDLE_AFTER = 30
"""Idle frames in a row (a second at 30 Hz) before eq. 3 slows to :data:`IDLE_EVERY`."""
IDLE_EVERY = 2
"""On an idle frame (:data:`QUIET_LEVELS`) with nothing frozen, after ``IDLE_AFTER`` in a row,
eq. 3 runs on one such frame in this many: each row is then learned every ``IDLE_EVERY *
learn_stride`` frames, with the weight of that many frames, so T keeps eq. 3's time constant
(its noise is 0.35 of one frame's instead of 0.25 at ``beta`` 0.02 and stride 6)."""


def negligible(gain: float) -> bool:
    """Whether a gain moves no grey level (0-255) by half a level: T is then used as learned."""
    return abs(gain - 1.0) * 255.0 < 0.5


class BackgroundModel:
    """The background T of one eye's :class:`stereod.vision.detect.Detector`, the class it
    extends: made by the warm-up, scaled by the global gain, learned by eq. 3 where nothing is
    held. It reads the last frame's foreground, which the detector sets."""

    # the last frame's foreground, set by the detector's find: the gain leaves it out, and
    # eq. 3 holds it
    _shape: tuple[int, int] | None
    _roi: Rect | None
    _part: np.ndarray | None
    _grown: np.ndarray | None
    _shade: np.ndarray | None
    _hold: np.ndarray | None
    _quiet_frame: bool
    """Whether the last frame was idle (see :data:`QUIET_LEVELS`)."""

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
        self._coarse_mean = (-1, 0.0)
        """The version of ``_coarse`` and its mean (the channels' means summed)."""
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
        self._quiet_frame = False
        self._ticks = 0
        """Frames eq. 3 was given (after the warm-up), learned or skipped as idle."""
        self._last = list(range(-params.learn_stride, 0))
        """For each phase of the rows, the tick it was last learned at: the weight of its
        next update is that of the frames since."""
        self._idle = 0
        """Frames in a row with nothing foreground and nothing frozen."""
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
        self._stale: tuple[Rect, np.ndarray] | None = None
        """Where :meth:`_held` found foreground held ``absorb_s``, for :meth:`learn` to absorb."""
        self._moved_at: np.ndarray | None = None
        """When each pixel last changed by more than t from one learned frame to the next (s),
        kept up to date inside the foreground's rectangle."""
        self._last_seen: tuple[Rect, np.ndarray] | None = None
        """The last learned frame over its foreground's rectangle (a copy): where the frame
        has not changed since, what is held there is still."""
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

    @property
    def warming_up(self) -> bool:
        return self._seen < self.params.warmup_frames

    @property
    def background(self) -> np.ndarray | None:
        """The float32 background T (grey levels, one channel or three), ``None`` before the
        first frame."""
        return self._background

    @property
    def frame(self) -> np.ndarray | None:
        """The frame last given to :meth:`stereod.vision.detect.Detector.find`, as T stores it
        (grey or BGR uint8), until :meth:`learn` takes it; ``None`` then."""
        return self._frame

    def relearn(self, support: np.ndarray, at: tuple[int, int]) -> None:
        """Make T the last frame at once under a blob's ``support`` (uint8, 255 on it, its
        top-left corner at ``at``: x, y px), grown by ``hold_margin_px`` as its hold is: what
        a moved object uncovered (:mod:`stereod.vision.uncovered`) is background now, not
        after ``absorb_s``. Does nothing without a frame (after :meth:`learn`) or a T."""
        frame, bg = self._frame, self._background
        if frame is None or bg is None or self.warming_up:
            return
        m = self.params.hold_margin_px
        sh, sw = support.shape[:2]
        h, w = bg.shape[:2]
        x0, y0 = max(at[0] - m, 0), max(at[1] - m, 0)
        x1, y1 = min(at[0] + sw + m, w), min(at[1] + sh + m, h)
        if x1 <= x0 or y1 <= y0:
            return
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        mask[at[1] - y0 : at[1] - y0 + sh, at[0] - x0 : at[0] - x0 + sw] = support
        if self._hold is not None:
            mask = cv2.dilate(mask, self._hold)
        where = (mask != 0)[..., None] if bg.ndim == 3 else mask != 0
        np.copyto(bg[y0:y1, x0:x1], frame[y0:y1, x0:x1], where=where)
        self._coarse = None  # T changed: its first pass's rows are rounded again

    def _rescale(self, bg: np.ndarray, frame: np.ndarray, g: float) -> None:
        """T times the global gain ``g`` in place (the light changed). A channel clipped in
        the frame dims less than ``g`` says, or not at all, while T learned from it is only a
        lower bound: scaled down, T would fall below the frame there and a lit patch by a lamp
        would turn foreground as the light dims. So when ``g`` < 1, where a channel of the
        frame is at :data:`CLIP_LEVEL` or above and T's was at most :data:`CLIP_SLACK` below
        it, T is at least the frame less ``CLIP_SLACK``, and no more than it was: outside the
        last foreground and its hold (an object's lit top passing over the floor is no clip
        of T's). One pixel cannot tell a clipped patch from a near-white object that enters
        over a surface near the clip level while the light drops by a tenth at once: that
        object's first frame is taken into T, and what it leaves is held for ``absorb_s``."""
        gain = np.float32(g)
        if g >= 1.0:
            np.multiply(bg, gain, out=bg)
            return
        near = frame >= CLIP_LEVEL
        if not near.any():
            np.multiply(bg, gain, out=bg)
            return
        held = self._grown if self._grown is not None else self._part
        if self._roi is not None and held is not None and self._shape == bg.shape[:2]:
            x0, y0, x1, y1 = self._roi
            if self._shade is not None:
                held = cv2.bitwise_or(held, self._shade)
            inner = near[y0:y1, x0:x1]
            inner[held != 0] = False  # (every channel of a held pixel)
        idx = np.flatnonzero(near)
        old = np.take(bg, idx)
        clip = old >= CLIP_LEVEL - CLIP_SLACK  # T learned from a clip, or near one
        idx, old = idx[clip], old[clip]
        np.multiply(bg, gain, out=bg)
        least = np.take(frame, idx).astype(np.float32) - np.float32(CLIP_SLACK)
        np.put(bg, idx, np.maximum(old * gain, np.minimum(least, old)))

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

    def _steady(self, grid: np.ndarray, grid8: np.ndarray) -> bool:
        """Whether the mean of the frame on the first pass's rows (``grid``) is that of T there
        (``grid8``, rounded) within ``GAIN_RESCALE``: no change of light the gain would
        rescale T for."""
        if self._coarse_mean[0] != self._coarse_version:
            self._coarse_mean = (self._coarse_version, sum(cv2.mean(grid8)))
        mean = self._coarse_mean[1]
        return abs(sum(cv2.mean(grid)) - mean) <= GAIN_RESCALE * mean

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
        if negligible(g):
            return g  # not applied: nothing to check
        # A gain must explain the change: what is left must look like sensor noise. A light
        # switched on unevenly, or a scene that changed, is not a gain: left alone, it
        # saturates the frame and the background is learned afresh.
        misfit = np.abs(f[use] - g * bs)
        if float(np.sort(misfit)[k]) > _GAIN_MAX_MISFIT * self.params.threshold:
            return 1.0
        return g

    def learn(self, frozen: Sequence[Rect] = (), released: Sequence[Rect] = ()) -> None:
        """Eq. 3 with the frame last given to :meth:`find`: during warm-up the frames are kept
        for the initial background, then T = T (1 - beta) + L beta where allowed: not in the
        ``frozen`` rectangles (objects the tracker freezes), and not on held foreground unless
        in a ``released`` one (an object the tracker knows has stopped for good). Rectangles
        are (x0, y0, x1, y1) px, end exclusive. Eq. 3 runs on every ``learn_stride``-th row, in
        turn, in one call (on one idle frame in ``IDLE_EVERY``, weighted for the frames since
        those rows were last learned); what it must not have changed there (:meth:`_kept`: the
        learned rows under the frozen and held rectangles' union) is copied before and put back
        after. Foreground still for ``absorb_s`` becomes T at once (:meth:`_absorb`)."""
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
        held = self._held(frame) if p.hold_foreground else None
        stale, self._stale = self._stale, None
        tick = self._ticks
        self._ticks += 1
        if self._quiet_frame and not frozen and p.learn_stride > 1:
            self._idle += 1
            if self._idle > IDLE_AFTER and self._idle % IDLE_EVERY:
                return  # idle: its rows are learned with the next one's weight
        else:
            self._idle = 0
        boxes = [r for r in (clipped(b, w, h) for b in frozen) if r is not None]
        phase = self._learned % p.learn_stride
        self._learned += 1
        frames, self._last[phase] = tick - self._last[phase], tick
        beta = self._beta if frames == p.learn_stride else 1.0 - (1.0 - p.beta) ** frames
        rows = slice(phase, None, p.learn_stride)
        kept = self._kept(bg, phase, held, boxes, released)
        cv2.accumulateWeighted(frame[rows], bg[rows], beta)
        if kept is not None:
            region, before, keep = kept
            cv2.copyTo(before, keep, region)  # in place: ``region`` is a view of T
        if stale is not None and self._absorb(frame, bg, stale, boxes):
            self._coarse = None  # T changed off eq. 3's rows: the first pass's are rounded again
        else:
            self._learned_rows(bg, phase)
        roi = self._held_roi if held is not None else None
        self._last_seen = (
            None if roi is None else (roi, frame[roi[1] : roi[3], roi[0] : roi[2]].copy())
        )

    def _absorb(
        self,
        frame: np.ndarray,
        bg: np.ndarray,
        stale: tuple[Rect, np.ndarray],
        boxes: list[Rect],
    ) -> bool:
        """Make T the frame at once where foreground has stayed still ``absorb_s`` seconds
        (``stale``: its rectangle and uint8 mask; :meth:`_held`), outside the ``boxes`` the
        tracker freezes, and hold those pixels ``absorb_s`` anew. Learned by eq. 3 alone, such
        a pixel's difference would fall through t over tens of frames, and its noise would take
        it out of the foreground and back in, each time held ``absorb_s`` anew: a still
        person's legs, learned so, leave speckled foreground for tens of seconds. Gives whether
        anything changed."""
        (x0, y0, x1, y1), mask = stale
        if boxes:
            mask = mask.copy()
            for r in boxes:
                c = clipped(r, x1, y1, x0, y0)
                if c is not None:
                    mask[c[1] - y0 : c[3] - y0, c[0] - x0 : c[2] - x0] = 0
        if not cv2.countNonZero(mask):
            return False
        cv2.copyTo(frame[y0:y1, x0:x1].astype(np.float32), mask, bg[y0:y1, x0:x1])
        assert self._since is not None
        self._since[y0:y1, x0:x1][mask > 0] = self._t_s
        return True

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
                    c = clipped(r, x1, y1, x0, y0)
                    if c is not None:
                        mask[c[1] - y0 : c[3] - y0, c[0] - x0 : c[2] - x0] = 0
            put_rows(keep, mask, x0 - ux0, y0 - uy0, first - uy0, stride)
        for x0, y0, x1, y1 in boxes:
            keep[rows_within(y0 - uy0, y1 - uy0, first - uy0, stride), x0 - ux0 : x1 - ux0] = 255
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

    def _moved(self, frame: np.ndarray, roi: Rect, now: float) -> None:
        """Note ``now`` as the last instant each pixel of ``roi`` moved: where ``frame`` differs
        from the last learned frame by more than t, and where the last frame's rectangle did
        not reach (all background there: what is foreground now came since). What moves in
        place (an object that jitters, an arm that waves over one spot) is not still, however
        long it has been foreground."""
        if self._moved_at is None or self._moved_at.shape != frame.shape[:2]:
            self._moved_at = np.full(frame.shape[:2], now, np.float32)
            return
        x0, y0, x1, y1 = roi
        view = self._moved_at[y0:y1, x0:x1]
        if self._last_seen is None:
            view.fill(now)
            return
        (lx0, ly0, lx1, ly1), last = self._last_seen
        ix0, iy0, ix1, iy1 = max(x0, lx0), max(y0, ly0), min(x1, lx1), min(y1, ly1)
        if ix1 <= ix0 or iy1 <= iy0:
            view.fill(now)
            return
        moved = cv2.absdiff(
            frame[iy0:iy1, ix0:ix1], last[iy0 - ly0 : iy1 - ly0, ix0 - lx0 : ix1 - lx0]
        )
        if moved.ndim == 3:
            moved = cv2.max(cv2.max(moved[..., 0], moved[..., 1]), moved[..., 2])
        inner = view[iy0 - y0 : iy1 - y0, ix0 - x0 : ix1 - x0]
        kept = inner.copy()
        view.fill(now)
        inner[...] = kept
        np.putmask(inner, moved > self.params.threshold, now)

    def _held(self, frame: np.ndarray) -> tuple[Rect, np.ndarray] | None:
        """Inside the rectangle around this frame's foreground, where eq. 3 must not learn
        (uint8 255): the foreground grown by ``hold_margin_px``, less what has stayed
        foreground ``absorb_s`` seconds (eq. 3 learns it; what of it has also been still that
        long, :meth:`_moved`, is left in ``_stale`` for :meth:`_absorb`). Outside it
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
        self._moved(frame, roi, now)
        limit = now - self.params.absorb_s
        if min(held_since, float(old.min()) if old is not None else held_since) >= limit:
            return roi, grown  # no time kept is that old: nothing is still
        if since.size == 1:  # OpenCV takes a one-element array for a scalar: give it two arrays
            stale = cv2.compare(since, np.full(since.shape, limit, np.float32), cv2.CMP_LT)
        else:
            stale = cv2.compare(since, np.float64(limit), cv2.CMP_LT)
        stale = cv2.bitwise_and(grown, stale)
        assert self._moved_at is not None
        still = np.where(self._moved_at[y0:y1, x0:x1] < limit, np.uint8(255), np.uint8(0))
        self._stale = (roi, cv2.bitwise_and(stale, still))
        return roi, cv2.subtract(grown, stale)
