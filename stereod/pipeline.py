"""One stereo pair in, the state of every track out (design sec. 1).

The stages of :meth:`Pipeline.process`: detect both eyes (eq. 2-5) -> match blobs by row,
disparity and size, pieces of one object grouped -> associate with tracks -> skew (each eye's
centroid moved to one instant along its 2D track) -> triangulate (eq. 9, 12) -> track (Kalman
update, eq. 21-23) -> learn the background (eq. 3), frozen under tracked objects, which runs
with the next pair's detection, in each eye's worker.

Pure computation on arrays: no threads beyond an optional pool detecting both eyes at once
(OpenCV releases the GIL), no Zenoh, no devices, no wire format (``bus.messages`` makes that).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from stereod.sources.frames import Eye, Frame, StereoPair
from stereod.sources.pairing import (
    DEFAULT_TOLERANCE_NS,
    DROP_NON_MONOTONIC,
    DROP_OVERFLOW,
    Pairer,
    PairerStats,
)
from stereod.tracking import measure, skew
from stereod.tracking.tracker import Tracker
from stereod.tracking.types import Detection, Observation, TrackerParams, TrackState
from stereod.vision.agreement import eye_agreement
from stereod.vision.blobs import Blobs
from stereod.vision.detect import Detector, fit_round_blobs
from stereod.vision.detect_params import DetectorParams
from stereod.vision.geometry import Geometry
from stereod.vision.geometry.matching import MatchParams, match_blobs, side_cut_edges
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.refine import RefineParams
from stereod.vision.geometry.stereo import CanonicalRig
from stereod.vision.geometry.triangulate import (
    Matched,
    blob_instants,
    in_range,
    refine_rights,
    triangulate_object,
)
from stereod.vision.grouping import GroupParams, group_objects
from stereod.vision.rects import Rect, box_rect
from stereod.vision.row_disparity import rows_median
from stereod.vision.uncovered import left_behind

log = logging.getLogger(__name__)

FREEZE_MARGIN_PX = 4
"""Margin (px) around a tracked blob's box where the background is not learned either."""
PARALLEL_MIN_PX = 500_000
"""The smallest frame (px) whose two eyes are worth detecting on two threads. Handing an eye
to another thread and back costs about 60 us a pair on two cores, and the threads contend for
the interpreter lock between OpenCV calls; by ``benchmarks/throughput.py``, that costs more
than the overlap saves at 640x480 (0.31 Mpx) and gains 14-17 % at 1280x720 (0.92 Mpx)."""

_DISORDER = (DROP_OVERFLOW, DROP_NON_MONOTONIC)
"""Pairing drops that mean :meth:`Pipeline.run` was given frames out of capture order."""

MIN_FRAME_INTERVAL_NS = 100_000
"""The shortest time (ns) between one eye's frames in two pairs that the pipeline takes: 0.1
ms, ten thousand frames a second. Closer frames are capture times in another unit (ms or us
read as ns), which would make every speed a thousand times or more too fast."""


@dataclass(frozen=True)
class PipelineParams:
    """Everything the pipeline needs besides the frames.

    ``rig``: the geometry (:class:`CanonicalRig` from a baseline and a field of view, or
    :class:`CalibratedRig` from a calibration file); its image size must be the frames'.
    ``centroid_sigma_px``: assumed centroid error per axis (px), the source of every covariance
    (0.15: the matte centroid errs by 0.01 to 0.2 px on the independent renderer; each track
    learns a scale of it from its own positions). An observation whose two centroids lie on
    different rectified rows, or whose areas say one eye lost part of the object, has it
    widened by that evidence (:mod:`stereod.vision.geometry.errors`) once the track has an
    earlier observation to compare with.
    ``detect_workers``: 2 detects the two eyes on two threads (OpenCV releases the GIL) when
    a frame has at least ``PARALLEL_MIN_PX`` pixels; smaller frames are detected on the
    calling thread alone, which is faster for them.
    ``silhouette_depth``: place each object's depth at its centre, not at the depth its
    silhouettes' centroids triangulate to, which is r^2 / Z nearer for a sphere (see
    ``silhouette_depth_factor`` (``vision/geometry/stereo.py``); other convex objects are taken to
    be as deep as they are wide).
    ``skew_compensation``: move both eyes' centroids to one instant before triangulating.
    ``skew_window_s``: how much of an eye's 2D track (s) its image velocity is fitted over, and
    how old its oldest of three frames may be for the projective interpolation.
    ``freeze_background``: do not learn the background under tracked objects.
    ``refine``: how the disparity is refined by matching appearance between the eyes.
    ``max_image_speed_wps``: the fastest image motion to expect, in image widths per second
    (a 20 m/s ball 2.5 m away crosses a 42 deg view in a tenth of a second): with the skew, it
    bounds how far an object moves between the eyes' instants, and with no depth known yet,
    between frames.
    ``grouping``: which matched blob pairs are one object (:mod:`stereod.vision.grouping`).
    ``readout_s``: a rolling shutter's readout time (s), from the first image row to the row
    below the last: each blob is taken at its frame's instant plus its centroid's row times
    ``readout_s / height_px``, wherever an eye's instant is used (association, skew
    compensation, the filter); 0 for a global shutter.
    """

    rig: CanonicalRig | CalibratedRig
    detector: DetectorParams = field(default_factory=DetectorParams)
    matching: MatchParams = field(default_factory=MatchParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    centroid_sigma_px: float = 0.15
    detect_workers: int = 1
    silhouette_depth: bool = True
    skew_compensation: bool = True
    skew_window_s: float = 0.2
    freeze_background: bool = True
    max_image_speed_wps: float = 10.0
    refine: RefineParams = field(default_factory=RefineParams)
    grouping: GroupParams = field(default_factory=GroupParams)
    readout_s: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.rig, (CanonicalRig, CalibratedRig)):
            raise TypeError(
                "rig must be a CanonicalRig (baseline, field of view, image size) or a "
                f"CalibratedRig (a calibration file), got {type(self.rig).__name__}"
            )
        for name in ("centroid_sigma_px", "skew_window_s", "max_image_speed_wps"):
            value = getattr(self, name)
            if not 0 < value < math.inf:
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        if not 0.0 <= self.readout_s <= 1.0:
            raise ValueError(f"readout_s must be within 0 and 1 s, got {self.readout_s}")
        if self.detect_workers not in (1, 2):
            raise ValueError(f"detect_workers must be 1 or 2, got {self.detect_workers}")


@dataclass(frozen=True, slots=True)
class Timings:
    """Where the time of one pair went inside the pipeline (ms, wall clock). ``detect_ms``
    includes eq. 3 with the previous pair's frames (deferred to run in the eyes' workers); an
    eye detected ahead (:meth:`Pipeline.detect_ahead`) adds nothing to it. A pair with no blob
    in either eye and no live track skips the later stages: 0 for them."""

    detect_ms: float
    geometry_ms: float
    track_ms: float
    pipeline_ms: float


@dataclass(frozen=True)
class PairResult:
    """What one stereo pair produced.

    ``t_ns`` is the instant the measurements refer to (the earlier eye's capture when skew is
    compensated, else the pair's midpoint), on the frames' clock; ``tracks`` the state of every
    live track at that instant (seen in this pair, or coasting); ``ended`` the ids of the tracks
    that ended with this pair; ``left``/``right`` each eye's blobs (image px);
    ``row_residuals_px`` the rectified |y_L - y_R| of every matched blob.
    """

    seq: int
    t_ns: int
    skew_ns: int
    left_seq: int
    right_seq: int
    tracks: list[TrackState]
    ended: list[int]
    left: Blobs
    right: Blobs
    timings: Timings
    row_residuals_px: np.ndarray = field(default_factory=lambda: np.zeros(0))


Learning = tuple[list[Rect], list[Rect]]
"""One eye's (frozen, released) rectangles of :meth:`stereod.vision.detect.Detector.learn`."""


class Pipeline:
    """Stateful processing of one rig's stereo pairs: background models and tracker.

    Feed it pairs in capture order with :meth:`process`, or any frames with :meth:`run`; it
    needs no thread, bus or device, so it works on arrays from anywhere::

        from stereod import CanonicalRig, Pipeline, PipelineParams, StereoPair

        pipe = Pipeline(PipelineParams(CanonicalRig(0.060, 60.0, 640, 480)))
        for k, (left, right, t_left_ns, t_right_ns) in enumerate(my_frames):
            result = pipe.process(StereoPair.of(left, right, t_left_ns, t_right_ns, seq=k))
            for track in result.tracks:
                if track.velocity_valid:
                    print(track.track_id, track.position_m, track.speed_mps, track.heading_deg)
        pipe.close()
    """

    def __init__(self, params: PipelineParams) -> None:
        if not isinstance(params, PipelineParams):
            raise TypeError(
                f"Pipeline takes a PipelineParams, e.g. PipelineParams(CanonicalRig(...)), "
                f"got {type(params).__name__}"
            )
        self.params = params
        self.left = Detector(params.detector)
        self.right = Detector(params.detector)
        rig = params.rig
        self.tracker = Tracker(params.tracker, rig.rectified.project, (rig.width_px, rig.height_px))
        self.tracker.line_ns = self._line_ns = params.readout_s * 1e9 / rig.height_px
        self._pending: list[Learning | None] = [None, None]
        """Each eye's eq. 3 rectangles (frozen, released) from the last pair, for the next;
        ``None`` once that eye has learned (or before the first pair)."""
        self._ahead: list[tuple[int, int, Blobs] | None] = [None, None]
        """Per eye, (seq, t_ns, blobs) of a frame detected before its pair was formed."""
        self._last: list[tuple[int, int, int] | None] = [None, None]
        """Per eye, (seq, t_ns, image ndim) of its frame in the last pair processed."""
        self.pairing: PairerStats | None = None
        """The pairer's counts of the last :meth:`run` (None before one)."""
        self.detected_ahead = 0
        """Frames detected before their pair formed (:meth:`detect_ahead`) and then used."""
        parallel = params.rig.width_px * params.rig.height_px >= PARALLEL_MIN_PX
        self._pool = (
            ThreadPoolExecutor(1, thread_name_prefix="detect")
            if params.detect_workers > 1 and parallel
            else None
        )

    def close(self) -> None:
        """Stop the detection workers (idempotent). A pipeline used again afterwards detects
        both eyes on the calling thread."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reconfigured(self, params: PipelineParams) -> tuple[Pipeline, list[int]]:
        """A pipeline with new parameters that carries over what still holds, and the ids of
        the tracks that ended. The background models always carry over (no new warm-up); the
        tracks carry over while neither the tracker settings nor the geometry changed, and
        otherwise end, new ids continuing after theirs. This pipeline is closed. Call it
        from the thread that calls :meth:`process`, between pairs."""
        new = Pipeline(params)
        self._flush()
        new.left.adopt(self.left)
        new.right.adopt(self.right)
        same_geometry = type(params.rig) is type(self.params.rig) and (
            params.rig.calibration_id == self.params.rig.calibration_id
            and (params.rig == self.params.rig or params.rig.calibration_id is not None)
        )
        ended: list[int] = []
        if params.tracker == self.params.tracker and same_geometry:
            new.tracker, self.tracker.line_ns = self.tracker, new.tracker.line_ns
        else:
            ended = self.tracker.end_all()
            new.tracker.continue_after(self.tracker)
        self.close()
        return new, ended

    def finish(self) -> list[int]:
        """End every live track (end of input); return their ids."""
        return self.tracker.end_all()

    def run(
        self, frames: Iterable[Frame], tolerance_ns: int = DEFAULT_TOLERANCE_NS
    ) -> Iterator[PairResult]:
        """Pair ``frames`` (both eyes, in the order they were captured, as a camera delivers them: a
        frame waits for the other eye's nearest one within ``tolerance_ns`` among at most 8 of its
        eye's, so frames given long before their partners, such as one eye's whole sequence before
        the other's, are dropped; see :class:`stereod.sources.pairing.Pairer`) and yield each pair's
        result as soon as the pair is formed (a frame that waits for its partner is detected
        meanwhile, as the daemon does: :meth:`detect_ahead`). Tracks still live at the end stay
        live: :meth:`finish` ends them. The pairer's counts (frames in, pairs out, drops by reason)
        are :attr:`pairing` meanwhile and after; frames dropped because they came out of order
        (``overflow``, ``non_monotonic``) are also logged as a warning at the end."""
        pairer = Pairer(tolerance_ns)
        self.pairing = pairer.stats
        for k, frame in enumerate(frames):
            if not isinstance(frame, Frame):
                raise TypeError(
                    f"Pipeline.run: item {k} is a {type(frame).__name__}, not a Frame "
                    "(Frame(eye, image, t_ns, seq), both eyes' frames in one sequence)"
                )
            pairs = pairer.push(frame)
            if not pairs:
                self.detect_ahead(frame)
            for pair in pairs:
                yield self.process(pair)
        for pair in pairer.flush():
            yield self.process(pair)
        seen = pairer.stats.frames
        for eye, other in ((Eye.LEFT, Eye.RIGHT), (Eye.RIGHT, Eye.LEFT)):
            if seen[other] and not seen[eye]:
                log.warning(
                    "Pipeline.run got %d %s frames and no %s one: nothing can be paired; give "
                    "both eyes' frames in one sequence",
                    seen[other],
                    other.value,
                    eye.value,
                )
        disorder = {k: n for k, n in pairer.stats.drops.items() if k in _DISORDER and n}
        if disorder:
            counts = ", ".join(f"{k} {n}" for k, n in sorted(disorder.items()))
            log.warning(
                "Pipeline.run dropped %d frames while pairing (%s): give the frames in the "
                "order they were captured",
                sum(disorder.values()),
                counts,
            )

    def detect_ahead(self, frame: Frame) -> bool:
        """Detect one eye's frame before its pair is formed (eq. 2-5, after eq. 3 with that
        eye's last frame), so that when the pair comes only the other eye is left to detect:
        the eyes free-run up to half a frame apart, and the earlier one's detection is done
        in that wait instead of after it. Only the frame that follows the eye's frame in the
        last pair processed, in number, time and format, is taken (the detectors see each eye's
        frames in order; a new format is left to its pair), once; returns whether it was. Call
        it from the thread that calls :meth:`process`. The result is the same, to the bit, as
        detecting the frame with its pair, unless its pair never comes (the pairer dropped the
        frame): its detection still leaves what it saw of the light and foreground to the next."""
        if not isinstance(frame, Frame):
            raise TypeError(f"detect_ahead takes a Frame, got {type(frame).__name__}")
        e = 0 if frame.eye is Eye.LEFT else 1
        last = self._last[e]
        if (
            self._ahead[e] is not None
            or last is None
            or frame.seq != last[0] + 1
            or frame.image.ndim != last[2]
            or self._refusal(frame, frame.eye) is not None  # left to its pair to report
        ):
            return False
        self._ahead[e] = (frame.seq, frame.t_ns, self._eye(e, frame.image, frame.t_ns))
        return True

    def _refusal(self, frame: Frame, eye: Eye) -> str | None:
        """Why ``frame``, as ``eye``'s frame of a pair, cannot be used (see :meth:`process`),
        or None when it can."""
        if frame.eye is not eye:
            return f"its {eye.value} frame is the {frame.eye.value} eye's"
        w, h = self.params.rig.width_px, self.params.rig.height_px
        fh, fw = frame.image.shape[:2]
        if (fw, fh) != (w, h):
            return (
                f"the {eye.value} frame is {fw}x{fh} px but the rig is {w}x{h}: give "
                "PipelineParams a rig of the frames' size"
            )
        last = self._last[0 if eye is Eye.LEFT else 1]
        if last is not None and frame.t_ns <= last[1]:
            return (
                f"the {eye.value} frame's capture time {frame.t_ns} ns is not after that of "
                f"the last pair's ({last[1]} ns): capture times must increase, in ns on one "
                "monotonic clock"
            )
        if last is not None and frame.t_ns - last[1] < MIN_FRAME_INTERVAL_NS:
            return (
                f"the {eye.value} frame was captured {frame.t_ns - last[1]} ns after the last "
                "pair's: capture times must be in ns (a 30 Hz camera's frames are 33333333 ns "
                "apart)"
            )
        return None

    def _check(self, pair: StereoPair) -> None:
        """Refuse a pair whose frames do not fit the rig or the eyes' time lines."""
        if not isinstance(pair, StereoPair):
            got = type(pair).__name__
            raise TypeError(f"process takes a StereoPair(seq, left, right) of Frames, got {got}")
        for frame, eye in ((pair.left, Eye.LEFT), (pair.right, Eye.RIGHT)):
            why = self._refusal(frame, eye)
            if why is None and pair.left.image.ndim != frame.image.ndim:
                why = "one eye's frame is grey and the other's BGR: give both in one format"
            if why is not None:
                raise ValueError(f"pair {pair.seq}: {why}")

    def _detected(self, e: int, frame: Frame) -> Blobs | None:
        """This eye's blobs for ``frame`` if it was detected ahead, else ``None`` (a frame
        detected ahead that did not make it into this pair is dropped)."""
        ahead, self._ahead[e] = self._ahead[e], None
        if ahead is None or ahead[0] != frame.seq or ahead[1] != frame.t_ns:
            return None
        self.detected_ahead += 1
        return ahead[2]

    def process(self, pair: StereoPair) -> PairResult:
        """Run one pair through eq. 2-5, 9, 12 and 21-23: :meth:`_detect`, :meth:`_match`,
        :meth:`_associate`, then per detection :meth:`_skew` (skew compensated) and
        :meth:`_triangulate`, the tracker's update (filters, tracks started and ended, speed and
        heading) and :meth:`_learn`; with no blob and no live track, all after detection is
        skipped. A pair the pipeline cannot use (a frame not the rig's size, the eyes' formats
        unlike, a frame not ``MIN_FRAME_INTERVAL_NS`` after that eye's in the last pair)
        raises ValueError before anything is changed."""
        p = self.params
        self._check(pair)
        t0 = time.perf_counter_ns()
        lb, rb = self._detect(pair)
        t1 = time.perf_counter_ns()
        t_left, t_right = pair.left.t_ns, pair.right.t_ns
        eye_times = (t_left, t_right)
        compensate = p.skew_compensation and (t_left != t_right or self._line_ns > 0.0)
        t_ns = skew.common_instant(t_left, t_right) if compensate else pair.t_ns
        if not (len(lb) or len(rb) or self.tracker.live_ids()):  # nothing moves, none tracked:
            self._learn([])  # the later stages would find nothing, so they are skipped
            ms = (t1 - t0) * 1e-6, (time.perf_counter_ns() - t0) * 1e-6
            seqs = pair.seq, t_ns, pair.skew_ns, pair.left.seq, pair.right.seq
            return PairResult(*seqs, [], [], lb, rb, Timings(ms[0], 0.0, 0.0, ms[1]))
        m = self._match(pair, lb, rb, eye_times)
        gone = left_behind(m.left, m.right, m.matches, (self.left, self.right))  # relearned now
        detections, assignment, may_start = self._associate(m, eye_times, gone)
        blob_times = blob_instants(m.left, m.right, m.matches, eye_times, self._line_ns)
        observations: list[Observation | None] = []
        for k, tid in enumerate(assignment):
            if tid is None and not may_start[k]:
                observations.append(None)
                continue
            det, times = detections[k], blob_times[k]
            if compensate:
                lc, rc, exact = self._skew(m, k, tid, det, times, t_ns)
            else:
                lc, rc, exact = m.left_px[k], m.right_px[k], True
            at_once = exact and (compensate or times[0] == times[1])
            observations.append(self._triangulate(m, k, tid, det, times, (lc, rc, exact), at_once))
        t2 = time.perf_counter_ns()
        boxes = (m.left.bbox_px, m.right.bbox_px)
        states, ended = self.tracker.update(  # the track stage (eq. 21-23)
            t_ns, observations, assignment, eye_times, detections, blob_times, boxes
        )
        self._learn(states)
        t3 = time.perf_counter_ns()
        timings = Timings(
            detect_ms=(t1 - t0) * 1e-6,
            geometry_ms=(t2 - t1) * 1e-6,
            track_ms=(t3 - t2) * 1e-6,
            pipeline_ms=(time.perf_counter_ns() - t0) * 1e-6,
        )
        return PairResult(
            seq=pair.seq,
            t_ns=t_ns,
            skew_ns=pair.skew_ns,
            left_seq=pair.left.seq,
            right_seq=pair.right.seq,
            tracks=states,
            ended=ended,
            left=m.left,
            right=m.right,
            timings=timings,
            row_residuals_px=np.abs(m.left_px[:, 1] - m.right_px[:, 1]),
        )

    def _detect(self, pair: StereoPair) -> tuple[Blobs, Blobs]:
        """The detect stage: each eye's blobs (image px; eq. 2-5, after eq. 3 with that eye's
        last frame), from :meth:`detect_ahead` where that eye's frame was detected before its
        pair formed, else detected now, the two eyes on two threads with two workers."""
        lb, rb = self._detected(0, pair.left), self._detected(1, pair.right)
        if lb is None and rb is None and self._pool is not None:
            fut = self._pool.submit(self._eye, 1, pair.right.image, pair.right.t_ns)
            try:
                lb = self._eye(0, pair.left.image, pair.left.t_ns)
            finally:  # never leave the right eye's detector running into the next pair
                rb = fut.result()
        both = lb is None and rb is None  # on this thread: both eyes' disc fits in one batch
        lb = lb if lb is not None else self._eye(0, pair.left.image, pair.left.t_ns, both)
        rb = rb if rb is not None else self._eye(1, pair.right.image, pair.right.t_ns, both)
        if both:
            fit_round_blobs(((self.left, lb), (self.right, rb)))
        self._last = [(f.seq, f.t_ns, f.image.ndim) for f in (pair.left, pair.right)]
        return lb, rb

    def _match(self, pair: StereoPair, lb: Blobs, rb: Blobs, eye_times: tuple[int, int]) -> Matched:
        """The match stage: both eyes' centroids rectified, blobs paired on one rectified row
        (within a tolerance that grows with their heights) with a disparity in range (widened by how
        far ``max_image_speed_wps`` moves an object between the eyes' instants ``eye_times``, ns)
        and a similar area, pieces of one object grouped into one (:mod:`stereod.vision.grouping`,
        after asking the tracker which track each piece is), and the right centroids placed by
        appearance (``refine``) or the rows' median disparity where it disagrees
        (:func:`rows_median`). Gives the (grouped) blobs, pairs' indices and rectified centroids."""
        p = self.params
        # Matching, association, compensation and triangulation work in rectified coordinates
        # (identical to image coordinates for the canonical rig); messages report the image ones.
        lrect, rrect = p.rig.rectify_left(lb.centroid_px), p.rig.rectify_right(rb.centroid_px)
        slack = abs(eye_times[1] - eye_times[0]) * 1e-9 * p.max_image_speed_wps * p.rig.width_px
        images = pair.left.image, pair.right.image
        agree = lambda i, j: eye_agreement(*images, lb.bbox_px[i], rb.bbox_px[j])  # noqa: E731
        edges = side_cut_edges(p.rig, lb.bbox_px, rb.bbox_px, p.matching, (lrect, rrect))
        hs = lb.bbox_px[:, 3], rb.bbox_px[:, 3]
        idx = match_blobs(lrect, lb.area_px, rrect, rb.area_px, p.matching, slack, agree, edges, hs)
        lpx, rpx = lrect[idx[:, 0]], rrect[idx[:, 1]]
        if p.grouping.enabled and len(lb) + len(rb) > 2 * min(len(idx), 1):  # or unmatched
            m0 = Matched(lb, rb, idx, lpx, rpx)  # which live object each pair is, before merging
            owners = self.tracker.objects(self._associate(m0, eye_times)[1])
            grouped = group_objects(
                lb, rb, idx, lpx, rpx, lrect, rrect, p.rig.focal_px, p.rig.baseline_m,
                p.grouping, owners, p.rig.width_px,
            )  # fmt: skip
            if grouped is not None:  # pieces of one object, one detection
                lb, rb, idx = grouped.left, grouped.right, grouped.index
                lpx, rpx = grouped.left_px, grouped.right_px
        if p.refine.enabled:
            refine_rights(p.rig, (pair.left.image, pair.right.image), lb, idx, lpx, rpx, p.refine)
        else:
            rig, size = p.rig, (p.rig.width_px, p.rig.height_px)
            level = rig.geometry is Geometry.CANONICAL  # image rows are rectified rows
            eyes = None if level else (rig.rectify_left, rig.rectify_right)
            rows_median(lb, rb, idx, lpx, rpx, p.centroid_sigma_px, size, eyes)
        return Matched(lb, rb, idx, lpx, rpx)

    def _associate(
        self, m: Matched, eye_times: tuple[int, int], gone: list[bool] | None = None
    ) -> tuple[list[Detection], list[int | None], list[bool]]:
        """The associate stage: the matched pairs as detections (:func:`measure.detections`;
        ``gone``: uncovered background, which no track takes), each given to a track in the
        images, each eye at its own instant (``eye_times``, ns, plus the rolling shutter's
        delay): the detections, their track ids (None: none), whether each may start one."""
        detections = measure.detections(
            m.left, m.right, m.matches, m.left_px, m.right_px, self.params.rig,
            self.params.tracker.max_speed_mps, self.params.max_image_speed_wps, gone,
        )  # fmt: skip
        assignment, may_start = self.tracker.associate(detections, eye_times)
        return detections, assignment, may_start

    def _skew(
        self, m: Matched, k: int, tid: int | None, det: Detection, times: tuple[int, int], t_ns: int
    ) -> tuple[np.ndarray, np.ndarray, bool]:
        """The skew stage, for matched pair ``k`` (detection ``det`` of track ``tid``, None for
        none, its blobs seen at ``times``, ns): both rectified centroids (px) moved to the
        instant ``t_ns`` along the projection of a steady 3D motion, from each eye's 2D track
        over ``skew_window_s`` and the depth change its blobs' areas say
        (:func:`stereod.tracking.measure.depth_ratios`, :func:`stereod.tracking.skew.compensate`).
        Gives the two centroids and whether they are now at one instant."""
        p = self.params
        histories = self.tracker.histories(tid)
        areas = (int(m.left.area_px[m.matches[k, 0]]), int(m.right.area_px[m.matches[k, 1]]))
        track = self.tracker.track(tid) if tid is not None else None
        ratios = measure.depth_ratios(track, det, times, areas, p.rig, p.tracker.max_speed_mps)
        window = int(p.skew_window_s * 1e9)
        return skew.compensate(histories, m.left_px[k], m.right_px[k], times, t_ns, window, ratios)

    def _triangulate(
        self, m: Matched, k: int, tid: int | None, det: Detection, times: tuple[int, int],
        centroids: tuple[np.ndarray, np.ndarray, bool], one_instant: bool,
    ) -> Observation | None:  # fmt: skip
        """The triangulate stage, for matched pair ``k`` (detection ``det`` of track ``tid``,
        its blobs seen at ``times``, ns): its ``centroids`` (left, right, rectified px, and
        whether both were brought to one instant; ``one_instant``: they are at one) to a
        position by eq. 9, its covariance from the centroid error (eq. 12) widened as
        :func:`~stereod.vision.geometry.triangulate.triangulate_object` and, for a first sight
        of eyes apart in time, :func:`~stereod.tracking.measure.apart_in_time` say."""
        p = self.params
        lb, rb, (tri_left, tri_right, exact) = m.left, m.right, centroids
        i, j, clipped = int(m.matches[k, 0]), int(m.matches[k, 1]), det.clipped
        track = self.tracker.track(tid) if tid is not None else None
        before, growth = track.last if track else None, measure.expected_growth(track, times)
        t = triangulate_object(
            p.rig, lb, rb, i, j, tri_left, tri_right, p.centroid_sigma_px, clipped, before,
            growth, one_instant, silhouette_depth=p.silhouette_depth, refined=p.refine.enabled,
            size_noise=skew.SIZE_NOISE,
        )  # fmt: skip
        ob = measure.observation(t, lb, rb, i, j, m.left_px[k], m.right_px[k], exact, clipped)
        if not exact and times[0] != times[1] and not (track and track.started):
            dt, v = (times[1] - times[0]) * 1e-9, p.tracker.manoeuvre_sigma_mps
            ob = measure.apart_in_time(ob, dt, v, p.rig.focal_px)
        usable = in_range(t.position_m, t.cov_m2, exact, p.rig, p.matching.min_disparity_px)
        return ob if usable else None

    def _learn(self, states: list[TrackState]) -> None:
        """Where eq. 3 may learn in each eye, applied when the next pair is detected: not under
        objects seen moving (so one that stops stays seen, for ``hold_still_s``), and at once under
        one that has been still longer than that (the detector would otherwise hold it as
        foreground for its own ``absorb_s``)."""
        frozen: tuple[list[Rect], list[Rect]] = ([], [])
        released: tuple[list[Rect], list[Rect]] = ([], [])
        if self.params.freeze_background:
            for s in states:
                if s.freeze_background or s.release_background:
                    ob = s.observation
                    into = frozen if s.freeze_background else released
                    into[0].append(box_rect(ob.left_bbox_px, FREEZE_MARGIN_PX))
                    into[1].append(box_rect(ob.right_bbox_px, FREEZE_MARGIN_PX))
        self._pending = [(frozen[0], released[0]), (frozen[1], released[1])]

    def _eye(self, e: int, image: np.ndarray, t_ns: int, fit_later: bool = False) -> Blobs:
        """One eye's detector: first eq. 3 with its last frame (deferred from the last pair to
        run in the eye's worker, or ahead, in the order as if done at once), then this frame's
        blobs (round ones fitted later with ``fit_later``: :func:`fit_round_blobs`)."""
        det = self.right if e else self.left
        pending, self._pending[e] = self._pending[e], None
        if pending is not None:
            det.learn(*pending)
        return det.find(image, t_ns, fit_later)

    def _flush(self) -> None:
        """Apply the deferred eq. 3 now (before the backgrounds are handed over)."""
        for e, det in enumerate((self.left, self.right)):
            pending, self._pending[e] = self._pending[e], None
            if pending is not None:
                det.learn(*pending)
