"""One stereo pair in, the state of every track out (design sec. 1).

detect both eyes (eq. 2-5) -> match blobs by row, disparity and size -> triangulate (eq. 9) ->
associate with tracks -> skew compensation (each eye's centroid moved to one instant along its
2D track) and triangulate again -> Kalman update -> background learning (eq. 3), frozen under
tracked objects, which runs with the next pair's detection, in each eye's worker.

The pipeline is pure computation on arrays: no threads of its own beyond an optional two-worker
pool that detects both eyes at once (OpenCV releases the GIL), no Zenoh, no devices, no wire
format (:func:`stereod.bus.messages.objects_message` turns a result into the wire message).
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
from stereod.tracking import kalman, skew
from stereod.tracking.tracker import Tracker
from stereod.tracking.types import Detection, Observation, TrackerParams, TrackState
from stereod.vision.blobs import Blobs
from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams
from stereod.vision.geometry import Geometry
from stereod.vision.geometry.rectified import CalibratedRig
from stereod.vision.geometry.refine import RefineParams, refine_match
from stereod.vision.geometry.stereo import (
    CanonicalRig,
    MatchParams,
    centre_depth,
    match_blobs,
    sym3,
)
from stereod.vision.grouping import (
    EDGE_SIGMA_PX,
    GroupParams,
    edge_disparity_px,
    extent_m,
    group_objects,
)
from stereod.vision.rects import Rect

log = logging.getLogger(__name__)

FREEZE_MARGIN_PX = 4
"""Margin (px) around a tracked blob's box where the background is not learned either."""
PARALLEL_MIN_PX = 500_000
"""The smallest frame (px) whose two eyes are worth detecting on two threads. Handing an eye
to another thread and back costs about 60 us a pair on two cores, and the two threads then
contend for the interpreter lock between OpenCV calls; measured with
``benchmarks/throughput.py``, that costs more than the overlap saves at 640x480 (0.31 Mpx) and
gains 14-17 % at 1280x720 (0.92 Mpx)."""


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
    widened by that evidence (:func:`_row_error_px`, :func:`_segmentation_error_px`) once
    the track has an earlier observation to compare with.
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
    eye detected ahead (:meth:`Pipeline.detect_ahead`) adds nothing to it."""

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


def _grown_box(bbox: np.ndarray) -> Rect:
    """A blob's box (x, y, w, h px) grown by ``FREEZE_MARGIN_PX`` as (x0, y0, x1, y1)."""
    x, y, w, h = (int(v) for v in bbox)
    m = FREEZE_MARGIN_PX
    return (x - m, y - m, x + w + m + 1, y + h + m + 1)


def _cos_off_axis(point_px: np.ndarray, centre_px: tuple[float, float], focal_px: float) -> float:
    """Cosine of the angle between an eye's optical axis and the ray through a point (px)."""
    dx, dy = float(point_px[0]) - centre_px[0], float(point_px[1]) - centre_px[1]
    return focal_px / math.sqrt(focal_px * focal_px + dx * dx + dy * dy)


def _touches_side(bbox: np.ndarray, rig: CanonicalRig | CalibratedRig) -> bool:
    """Whether a blob's box (x, y, w, h px) reaches the image's left or right edge: part of
    the object may be cut off there, differently in each eye, so its disparity is off."""
    x, _, w, _ = (int(v) for v in bbox)
    return x <= 0 or x + w >= rig.width_px


def _cut_rows(bbox: np.ndarray, rig: CanonicalRig | CalibratedRig) -> bool:
    """Whether a blob's box (x, y, w, h px) reaches the image's top or bottom edge: a person
    close to the camera, head or feet out of view. Both eyes lose the same rectified rows, so
    its disparity holds; only its height is unknown."""
    _, y, _, h = (int(v) for v in bbox)
    return y <= 0 or y + h >= rig.height_px


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
        self.tracker = Tracker(params.tracker, params.rig.rectified.project)
        self._line_ns = params.readout_s * 1e9 / params.rig.height_px
        self.tracker.line_ns = self._line_ns
        self._pending: list[Learning | None] = [None, None]
        """Each eye's eq. 3 rectangles (frozen, released) from the last pair, for the next;
        ``None`` once that eye has learned (or before the first pair)."""
        self._ahead: list[tuple[int, int, Blobs] | None] = [None, None]
        """Per eye, (seq, t_ns, blobs) of a frame detected before its pair was formed."""
        self._last: list[tuple[int, int] | None] = [None, None]
        """Per eye, (seq, t_ns) of its frame in the last pair processed."""
        self.pairing: PairerStats | None = None
        """The pairer's counts of the last :meth:`run` (None before one)."""
        self.detected_ahead = 0
        """Frames whose detection was done before their pair formed (:meth:`detect_ahead`)
        and then used."""
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
            new.tracker = self.tracker
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
        """Pair ``frames`` (both eyes, in the order they were captured, as a camera delivers
        them: a frame waits for the other eye's nearest one within ``tolerance_ns`` among at
        most 8 of its eye's, so frames given long before their partners, such as one eye's
        whole sequence before the other's, are dropped; see :class:`stereod.sources.pairing.Pairer`)
        and yield each pair's result as soon as
        the pair is formed (a frame that waits for its partner is detected meanwhile, as the
        daemon does: :meth:`detect_ahead`). Tracks still live at the end stay live:
        :meth:`finish` ends them. The pairer's counts (frames in, pairs out, drops by reason)
        are :attr:`pairing` meanwhile and after; frames dropped because they came out of
        order (``overflow``, ``non_monotonic``) are also logged as a warning at the end."""
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
        last pair processed, in number and in time, is taken (the detectors see each eye's
        frames in order), once; returns whether it was. Call it from the thread that calls
        :meth:`process`. The result is the same, to the bit, as detecting the frame with its
        pair, unless its pair never comes (the pairer dropped the frame): its detection then
        still leaves what it saw of the light (the gain) and of the foreground to the next."""
        if not isinstance(frame, Frame):
            raise TypeError(f"detect_ahead takes a Frame, got {type(frame).__name__}")
        e = 0 if frame.eye is Eye.LEFT else 1
        last = self._last[e]
        if (
            self._ahead[e] is not None
            or last is None
            or frame.seq != last[0] + 1
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
            raise TypeError(
                f"process takes a StereoPair(seq, left, right) of two Frames, got "
                f"{type(pair).__name__}"
            )
        for frame, eye in ((pair.left, Eye.LEFT), (pair.right, Eye.RIGHT)):
            why = self._refusal(frame, eye)
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
        """Run one pair through eq. 2-5, 9, 12 and 21-23. A pair the pipeline cannot use (an
        eye's frame not the rig's size, or not at least ``MIN_FRAME_INTERVAL_NS`` later than
        that eye's frame in the last pair) raises ValueError before anything is changed."""
        p = self.params
        self._check(pair)
        t0 = time.perf_counter_ns()
        lb, rb = self._detected(0, pair.left), self._detected(1, pair.right)
        if lb is None and rb is None and self._pool is not None:
            fut = self._pool.submit(self._eye, 1, pair.right.image, pair.right.t_ns)
            try:
                lb = self._eye(0, pair.left.image, pair.left.t_ns)
            finally:  # never leave the right eye's detector running into the next pair
                rb = fut.result()
        if lb is None:
            lb = self._eye(0, pair.left.image, pair.left.t_ns)
        if rb is None:
            rb = self._eye(1, pair.right.image, pair.right.t_ns)
        self._last = [(pair.left.seq, pair.left.t_ns), (pair.right.seq, pair.right.t_ns)]
        t1 = time.perf_counter_ns()
        t_left, t_right = pair.left.t_ns, pair.right.t_ns
        eye_times = (t_left, t_right)
        compensate = p.skew_compensation and (t_left != t_right or self._line_ns > 0.0)
        t_ns = skew.common_instant(t_left, t_right) if compensate else pair.t_ns
        # Matching, association, compensation and triangulation work in rectified coordinates
        # (identical to image coordinates for the canonical rig); messages report the image ones.
        lrect = p.rig.rectify_left(lb.centroid_px)
        rrect = p.rig.rectify_right(rb.centroid_px)
        image_speed = p.max_image_speed_wps * p.rig.width_px
        slack = abs(t_right - t_left) * 1e-9 * image_speed
        idx = match_blobs(lrect, lb.area_px, rrect, rb.area_px, p.matching, slack)
        lpx = lrect[idx[:, 0]]
        rpx = rrect[idx[:, 1]]
        if p.grouping.enabled and len(lb) + len(rb) > 2:
            owners = None
            if len(idx) > 1:  # which live track each pair is, before they are merged
                pieces = self._detections(lb, rb, idx, lpx, rpx)
                owners = self.tracker.associate(pieces, eye_times)[0]
            grouped = group_objects(
                lb, rb, idx, lpx, rpx, lrect, rrect, p.rig.focal_px, p.rig.baseline_m,
                p.grouping, owners,
            )  # fmt: skip
            if grouped is not None:  # pieces of one object, one detection
                lb, rb, idx = grouped.left, grouped.right, grouped.index
                lpx, rpx = grouped.left_px, grouped.right_px
        if p.refine.enabled:
            self._refine(pair, lb, idx, lpx, rpx)
        detections = self._detections(lb, rb, idx, lpx, rpx)
        assignment, may_start = self.tracker.associate(detections, eye_times)
        blob_times = self._blob_times(lb, rb, idx, eye_times)
        window = int(p.skew_window_s * 1e9)
        observations: list[Observation | None] = []
        for k, tid in enumerate(assignment):
            if tid is None and not may_start[k]:
                observations.append(None)
                continue
            histories = self.tracker.histories(tid)
            times = blob_times[k]
            if compensate:
                areas = (int(lb.area_px[idx[k, 0]]), int(rb.area_px[idx[k, 1]]))
                ratios = self._depth_ratios(tid, detections[k], times, areas)
                lc, rc, exact = skew.compensate(
                    histories, lpx[k], rpx[k], times, t_ns, window, ratios
                )
            else:
                lc, rc, exact = lpx[k], rpx[k], True
            clipped = detections[k].clipped
            before = self.tracker.track(tid).last if tid is not None else None
            growth = self._expected_growth(tid, times)
            at_once = exact and (compensate or times[0] == times[1])
            ob = self._observe(
                lb, rb, idx[k], lpx[k], rpx[k], lc, rc, exact, clipped, before, growth, at_once
            )
            observations.append(ob if self._in_range(ob) else None)
        t2 = time.perf_counter_ns()
        states, ended = self.tracker.update(
            t_ns, observations, assignment, eye_times, detections, blob_times
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
            left=lb,
            right=rb,
            timings=timings,
            row_residuals_px=np.abs(lpx[:, 1] - rpx[:, 1]),
        )

    def _blob_times(
        self, lb: Blobs, rb: Blobs, idx: np.ndarray, eye_times_ns: tuple[int, int]
    ) -> list[tuple[int, int]]:
        """Each matched pair's capture instants (ns), left and right: its frame's instant plus
        its centroid's image row times the rolling shutter's time per row (``readout_s``)."""
        if self._line_ns <= 0.0:
            return [eye_times_ns] * len(idx)
        t_left, t_right = eye_times_ns
        line = self._line_ns
        return [
            (
                t_left + round(max(float(lb.centroid_px[i, 1]), 0.0) * line),
                t_right + round(max(float(rb.centroid_px[j, 1]), 0.0) * line),
            )
            for i, j in idx.tolist()
        ]

    def _expected_growth(
        self, tid: int | None, eye_times_ns: tuple[int, int]
    ) -> tuple[float, float] | None:
        """How much a track's blob should have grown in each eye since that eye last saw it,
        as the log of the area ratio: 2 log(Z then / Z now), with Z at that eye's two instants
        from the track's filter (so the eyes' skew is allowed for exactly, whatever it is);
        ``None`` before the filter runs (a track's first two observations)."""
        if tid is None:
            return None
        tr = self.tracker.track(tid)
        if not tr.started:
            return None
        out: list[float] = []
        for history, t_now in (
            (tr.left_history, eye_times_ns[0]),
            (tr.right_history, eye_times_ns[1]),
        ):
            z_then = float(kalman.position_at(tr.kf, history[-1][0])[2])
            z_now = float(kalman.position_at(tr.kf, t_now)[2])
            if z_then <= 0 or z_now <= 0:
                return None
            out.append(2.0 * math.log(z_then / z_now))
        return out[0], out[1]

    def _depth_ratios(
        self,
        tid: int | None,
        det: Detection,
        eye_times_ns: tuple[int, int],
        areas_px: tuple[int, int],
    ) -> tuple[float | None, float | None]:
        """How much a track's depth changed since each eye last saw it (Z now over Z then),
        from its blob's areas in that eye (``areas_px`` now, left and right), each seen at
        its angle off that eye's axis, and no faster than ``max_speed_mps`` from its last
        depth (:func:`stereod.tracking.skew.size_depth_ratio`); unknown for a new track, or when
        either blob is cut by the image's edge, now or then."""
        if tid is None:
            return None, None
        tr = self.tracker.track(tid)
        last = tr.last
        if last.clipped or det.clipped or last.cut or det.cut:
            return None, None
        rig, max_speed = self.params.rig, self.params.tracker.max_speed_mps
        z_then = float(last.position_m[2])
        out: list[float | None] = []
        for e, (then_px, now_px, area_then) in enumerate(
            ((last.left_px, det.left_px, last.left_area_px),
             (last.right_px, det.right_px, last.right_area_px))
        ):  # fmt: skip
            history = tr.right_history if e else tr.left_history
            dt_s = (eye_times_ns[e] - history[-1][0]) * 1e-9
            centre = rig.principal_point_px(e == 0)
            out.append(
                skew.size_depth_ratio(
                    area_then,
                    areas_px[e],
                    _cos_off_axis(then_px, centre, rig.focal_px),
                    _cos_off_axis(now_px, centre, rig.focal_px),
                    max_speed * dt_s / z_then if z_then > 0 else math.inf,
                )
            )
        return out[0], out[1]

    def _refine(
        self, pair: StereoPair, lb: Blobs, idx: np.ndarray, lpx: np.ndarray, rpx: np.ndarray
    ) -> None:
        """Replace each right centroid in ``rpx`` by where the left blob's appearance is found
        in the right image (:mod:`stereod.vision.geometry.refine`), when it is found confidently."""
        rig = self.params.rig
        size = (rig.width_px, rig.height_px)
        limg, rimg = pair.left.image, pair.right.image

        def left(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
            return rig.rectified_patch(limg, True, x0, y0, x1, y1)

        def right(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
            return rig.rectified_patch(rimg, False, x0, y0, x1, y1)

        for k, i in enumerate(idx[:, 0]):
            if not lb.support:
                return
            box, support = rig.rectified_support(True, lb.bbox_px[i], lb.support[i])
            rpx[k], _ = refine_match(
                left, right, size, box, support, lpx[k], rpx[k], self.params.refine
            )

    def _detections(
        self, lb: Blobs, rb: Blobs, idx: np.ndarray, lpx: np.ndarray, rpx: np.ndarray
    ) -> list[Detection]:
        """Matched blob pairs as the tracker's detections (rectified px), each with the fastest
        image motion it can have: ``max_speed_mps`` at its depth (f / Z = disparity / B pixels
        per metre), or the fastest image motion at all when its disparity is too small to say
        (a skewed first sight of a fast object)."""
        p = self.params
        ceiling = p.max_image_speed_wps * p.rig.width_px
        out = []
        for k, (i, j) in enumerate(idx):
            d = float(lpx[k, 0] - rpx[k, 0])
            limit = (
                min(p.tracker.max_speed_mps * d / p.rig.baseline_m, ceiling) if d >= 2 else ceiling
            )
            out.append(
                Detection(
                    left_px=lpx[k],
                    right_px=rpx[k],
                    left_bbox_px=lb.bbox_px[i],
                    right_bbox_px=rb.bbox_px[j],
                    area_px=int(min(lb.area_px[i], rb.area_px[j])),
                    image_speed_pxps=limit,
                    clipped=_touches_side(lb.bbox_px[i], p.rig)
                    or _touches_side(rb.bbox_px[j], p.rig),
                    cut=_cut_rows(lb.bbox_px[i], p.rig) or _cut_rows(rb.bbox_px[j], p.rig),
                )
            )
        return out

    def _observe(
        self,
        lb: Blobs,
        rb: Blobs,
        ij: np.ndarray,
        lpx: np.ndarray,
        rpx: np.ndarray,
        tri_left: np.ndarray,
        tri_right: np.ndarray,
        exact: bool,
        clipped: bool,
        before: Observation | None = None,
        growth: tuple[float, float] | None = None,
        one_instant: bool = True,
    ) -> Observation:
        """The observation of one matched pair of blobs; ``tri_*`` are the centroids to
        triangulate (moved to one instant when skew is compensated; ``one_instant`` whether
        they are at one), ``before`` the track's last observation and ``growth`` how much its
        blob should have grown in each eye since (see :func:`_segmentation_error_px`)."""
        p = self.params
        i, j = int(ij[0]), int(ij[1])
        width_px = 0.5 * (int(lb.bbox_px[i, 2]) + int(rb.bbox_px[j, 2]))
        area_l, area_r = float(lb.area_px[i]), float(rb.area_px[j])
        if p.rig.geometry is Geometry.CALIBRATED and lb.support and rb.support:
            # Outlines in rectified px: a distorted image's blob is stretched and bent.
            area_l, width_l, shift_l = p.rig.rectified_silhouette(
                True, lb.bbox_px[i], lb.support[i]
            )
            area_r, width_r, shift_r = p.rig.rectified_silhouette(
                False, rb.bbox_px[j], rb.support[j]
            )
            tri_left, tri_right = tri_left + shift_l, tri_right + shift_r
            width_px = 0.5 * (width_l + width_r)
        area = 0.5 * (area_l + area_r)
        sigma = p.centroid_sigma_px
        cut = _cut_rows(lb.bbox_px[i], p.rig) or _cut_rows(rb.bbox_px[j], p.rig)
        whole = not clipped and not cut
        if before is not None and whole and not before.clipped and not before.cut:
            seg = _segmentation_error_px(lb, rb, i, j, before, width_px, (area_l, area_r), growth)
            sigma = math.hypot(sigma, seg)
        xl, yl = tri_left.tolist()
        xr, yr = tri_right.tolist()
        edge = None
        if clipped:  # cut by one side of the image: the depth from its other side's edges
            edge = edge_disparity_px(
                lb.bbox_px[i], rb.bbox_px[j], xl - float(lb.centroid_px[i, 0]),
                xr - float(rb.centroid_px[j, 0]), p.rig.width_px,
            )  # fmt: skip
            if edge is not None:
                mid = 0.5 * (xl + xr)
                xl, xr = mid + 0.5 * edge, mid - 0.5 * edge
                sigma = math.hypot(sigma, EDGE_SIGMA_PX)
        # The rows' gap says how the two segmentations disagree only where both centroids
        # are at one instant and segmented (not placed on one row by appearance matching).
        # An outline cut by the image's edge counts too: its gap is as much a sign that its
        # centroids are off, and the smaller of the gap and its change bounds what it adds.
        row_gap = yl - yr if one_instant and not p.refine.enabled else None
        if row_gap is not None and before is not None and before.row_gap_px is not None:
            sigma = math.hypot(sigma, _row_error_px(row_gap, before.row_gap_px))
        point, cov = p.rig.rectified.triangulate(xl, yl, xr, yr, sigma)
        factor = 1.0
        if p.silhouette_depth and not cut and edge is None:
            point, cov, factor = centre_depth(point, cov, area, p.rig.focal_px, width_px)
        centre = np.array(point)
        cov_m2 = sym3(cov)
        if cut:  # its centre's height is anywhere within its cut box: half its height as sigma
            h_px = max(int(lb.bbox_px[i, 3]), int(rb.bbox_px[j, 3]))
            cov_m2[1, 1] += (0.5 * h_px * float(point[2]) / p.rig.focal_px) ** 2
        if edge is not None:  # its centre lies anywhere across what is seen of it
            cov_m2[0, 0] += (0.5 * width_px * float(point[2]) / p.rig.focal_px) ** 2
        extent = None
        if np.all(np.isfinite(centre)):  # (one that is not is refused by _in_range)
            lo, hi = extent_m(
                centre, lb.bbox_px[i], rb.bbox_px[j], lb.centroid_px[i], p.rig.focal_px
            )
            extent = (lo - centre, hi - centre)
        return Observation(
            position_m=centre,
            cov_m2=cov_m2,
            left_px=lpx,
            right_px=rpx,
            left_image_px=lb.centroid_px[i],
            right_image_px=rb.centroid_px[j],
            left_bbox_px=lb.bbox_px[i],
            right_bbox_px=rb.bbox_px[j],
            left_area_px=int(lb.area_px[i]),
            right_area_px=int(rb.area_px[j]),
            disparity_px=float(tri_left[0] - tri_right[0]),
            size_m=float(width_px * point[2] / p.rig.focal_px),
            exact=exact,
            clipped=clipped,
            cut=cut,
            depth_factor=factor,
            edge_depth=edge is not None,
            row_gap_px=row_gap,
            extent_m=extent,
        )

    def _in_range(self, ob: Observation) -> bool:
        """Whether a triangulated position can be used: finite, and, once both eyes are
        brought to one instant, in front of the rig and no further than the matcher's
        smallest disparity allows. Blobs are matched with room for the eyes' skew, so two
        views of one object at the same image position in both eyes (no parallax: far away,
        or not a stereo view at all) can be matched, and at one instant their disparity is
        nil or negative: such a position is at infinity or behind the rig, and would poison a
        track. (A track's first sight, not brought to one instant, only places it, and a fast
        object's may well lie behind the rig.) With skew compensation off every observation is
        taken as at one instant, so a fast object whose skewed disparity falls out of range
        is dropped for that pair rather than placed far off or behind the rig."""
        p = self.params
        if not (np.all(np.isfinite(ob.position_m)) and np.all(np.isfinite(ob.cov_m2))):
            return False
        if not ob.exact:
            return True
        far = p.rig.baseline_m * p.rig.focal_px / max(p.matching.min_disparity_px, 1e-3)
        return 0.0 < float(ob.position_m[2]) <= far

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
                    into[0].append(_grown_box(ob.left_bbox_px))
                    into[1].append(_grown_box(ob.right_bbox_px))
        self._pending = [(frozen[0], released[0]), (frozen[1], released[1])]

    def _eye(self, e: int, image: np.ndarray, t_ns: int) -> Blobs:
        """One eye's detector: first eq. 3 with its last frame (deferred from the last pair so
        that it runs in the eye's worker, or ahead, in the same order as if done at once),
        then this frame's blobs."""
        det = self.right if e else self.left
        pending, self._pending[e] = self._pending[e], None
        if pending is not None:
            det.learn(*pending)
        return det.find(image, t_ns)

    def _flush(self) -> None:
        """Apply the deferred eq. 3 now (before the backgrounds are handed over)."""
        for e, det in enumerate((self.left, self.right)):
            pending, self._pending[e] = self._pending[e], None
            if pending is not None:
                det.learn(*pending)


_SQRT_HALF = math.sqrt(0.5)


def _row_error_px(gap: float, gap_before: float) -> float:
    """How far (px, one sigma, per centroid) the two eyes' centroids of one object may be
    off across the rows, from how far apart their rows are now and were at the track's last
    observation (``gap``, ``gap_before``: y_L - y_R in rectified px, each at one instant). A
    rectified pair sees a point on one row in both eyes, so a gap is the two segmentations
    disagreeing: one eye took in or lost a part of the object that the other did not (the
    colour of the background behind it in that eye only), which moves its centroid across as
    much as along, and the disparity (eq. 9) is then as likely off by as much as the rows
    are apart: each centroid's error is that over sqrt(2). What counts is the smaller of the
    gap and its change since the last observation: a gap that stays (a calibration's row
    error, or the skew interpolation's on an object whose image motion speeds up) is no
    segmentation's doing. A robot cylinder at 1.6 m, 640x480 and 42 deg (eq. 12: 5 cm of
    depth a px of disparity), has its rows 0.5 to 1 px apart on about one frame in eight,
    and its depth 1.5 to 3 cm off there (0.3 to 0.6 px of disparity)."""
    return min(abs(gap), abs(gap - gap_before)) * _SQRT_HALF


SEGMENTATION_SLACK = 0.03
"""How far (as a share) an object's two blob areas may differ, or their ratio change from
one observation to the next, before its centroids are trusted less: noise, the object's own
turning and the side of a box that one eye sees more of than the other change it by a few
percent."""


def _segmentation_error_px(
    lb: Blobs,
    rb: Blobs,
    i: int,
    j: int,
    before: Observation,
    width_px: float,
    areas: tuple[float, float] | None = None,
    growth: tuple[float, float] | None = None,
) -> float:
    """How far (px, one sigma) the centroids may have moved because the two eyes segmented
    the object differently. Where part of an object is the colour of what is behind it, each
    eye loses or regains that part on its own frame (each sees another patch of background),
    and the eye that lost a share ``s`` of the object's area has its centroid moved by up to
    ``s`` times half the object's width: the disparity, so the depth, is off for as long as
    the loss lasts. Two signs tell it apart: the two eyes' area changes since ``before``
    (logs) differ by ``s`` on the frame it happens, and the two areas themselves differ by
    ``s`` for every frame it lasts (the eyes of a canonical rig see the same outline to a
    few percent). An object coming closer or going away grows in both, and differently
    through the eyes' skew alone. With the track's filter running, ``growth`` gives what
    each eye's change should be (:meth:`Pipeline._expected_growth`), and the two changes
    count by how far their difference is from the expected one: a loss in one eye counts in
    full on its first frame, and a thrown ball's skewed growth not at all. Before that, what
    counts is the excess over the mean growth (by at most half a frame's growth apart
    through the skew); the mean holds half of a loss in one eye alone, so such a loss then
    counts from twice the slack (6 %), at half its size. The two areas apart count beyond
    the mean growth. Either counts beyond ``SEGMENTATION_SLACK`` and the areas' own noise,
    2 ``SIZE_NOISE`` / sqrt(A) of the smallest of the four areas A (a difference of two log
    area ratios, each twice the half-log that :func:`stereod.tracking.skew.size_depth_ratio` bounds
    by ``SIZE_NOISE`` / sqrt(A): a ball 5 px across wobbles by a fifth); the larger, times
    half the blob's width ``width_px``, is added to the centroid error of this observation,
    so the filter leans on its prediction across the loss instead of following it. The two
    areas are compared as ``areas`` (left, right) gives them, in rectified px where lens
    distortion scales the two eyes' images differently (the images' areas when None)."""
    area_l, area_r = max(int(lb.area_px[i]), 1), max(int(rb.area_px[j]), 1)
    then_l, then_r = max(before.left_area_px, 1), max(before.right_area_px, 1)
    left = math.log(area_l / then_l)
    right = math.log(area_r / then_r)
    grew = abs(left + right) / 2.0
    rect_l, rect_r = areas if areas is not None else (area_l, area_r)
    apart = abs(math.log(max(rect_l, 1.0) / max(rect_r, 1.0))) - grew
    if growth is None:
        changed = abs(left - right) - grew
    else:
        changed = abs((left - right) - (growth[0] - growth[1]))
    noise = 2.0 * skew.SIZE_NOISE / math.sqrt(min(area_l, area_r, then_l, then_r))
    return max(max(changed, apart) - SEGMENTATION_SLACK - noise, 0.0) * 0.5 * width_px
