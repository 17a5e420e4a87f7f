"""One stereo pair in, the state of every track out (design sec. 1).

detect both eyes (eq. 2-5) -> match blobs by row, disparity and size -> triangulate (eq. 9) ->
associate with tracks -> skew compensation (each eye's centroid moved to one instant along its
2D track) and triangulate again -> Kalman update -> background learning (eq. 3), frozen under
tracked objects.

The pipeline is pure computation on arrays: no threads of its own beyond an optional two-worker
pool that detects both eyes at once (OpenCV releases the GIL), no Zenoh, no devices, no wire
format (:func:`stereod.messages.objects_message` turns a result into the wire message).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from . import skew
from .detect import Blobs, Detector, DetectorParams
from .frames import Frame, StereoPair
from .geometry.rectified import CalibratedRig
from .geometry.stereo import CanonicalRig, MatchParams, matched_blobs
from .pairing import DEFAULT_TOLERANCE_NS, Pairer
from .tracking import Observation, Track, Tracker, TrackerParams, TrackState

FREEZE_MARGIN_PX = 4
"""Margin (px) around a tracked blob's box where the background is not learned either."""


@dataclass(frozen=True)
class PipelineParams:
    """Everything the pipeline needs besides the frames.

    ``rig``: the geometry (:class:`CanonicalRig` from a baseline and a field of view, or
    :class:`CalibratedRig` from a calibration file); its image size must be the frames'.
    ``centroid_sigma_px``: assumed centroid error per axis (px), the source of every covariance.
    ``detect_workers``: 2 detects the two eyes on two threads (OpenCV releases the GIL).
    ``skew_compensation``: move both eyes' centroids to one instant before triangulating.
    ``skew_window_s``: how much of an eye's 2D track (s) its image velocity is fitted over.
    ``freeze_background``: do not learn the background under tracked objects.
    """

    rig: CanonicalRig | CalibratedRig
    detector: DetectorParams = field(default_factory=DetectorParams)
    matching: MatchParams = field(default_factory=MatchParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    centroid_sigma_px: float = 0.5
    detect_workers: int = 1
    skew_compensation: bool = True
    skew_window_s: float = 0.15
    freeze_background: bool = True


@dataclass(frozen=True, slots=True)
class Timings:
    """Where the time of one pair went inside the pipeline (ms, wall clock)."""

    detect_ms: float
    geometry_ms: float
    track_ms: float
    pipeline_ms: float


@dataclass(frozen=True)
class PairResult:
    """What one stereo pair produced.

    ``t_ns`` is the instant the measurements refer to (the later eye's capture when skew is
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
        self.params = params
        self.left = Detector(params.detector)
        self.right = Detector(params.detector)
        self.tracker = Tracker(params.tracker)
        self._pool = (
            ThreadPoolExecutor(2, thread_name_prefix="detect")
            if params.detect_workers > 1
            else None
        )

    def close(self) -> None:
        """Stop the detection workers (idempotent); the pipeline cannot process afterwards."""
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
        """Pair ``frames`` (both eyes, each eye in capture order, interleaved in any way) by
        nearest capture time within ``tolerance_ns`` and yield each pair's result as soon as
        the pair is formed. Tracks still live at the end stay live: :meth:`finish` ends them."""
        pairer = Pairer(tolerance_ns)
        for frame in frames:
            for pair in pairer.push(frame):
                yield self.process(pair)
        for pair in pairer.flush():
            yield self.process(pair)

    def process(self, pair: StereoPair) -> PairResult:
        """Run one pair through eq. 2-5, 9, 12 and 21-23."""
        p = self.params
        t0 = time.perf_counter_ns()
        if self._pool is not None:
            fut = self._pool.submit(self.right.find, pair.right.image)
            lb = self.left.find(pair.left.image)
            rb = fut.result()
        else:
            lb = self.left.find(pair.left.image)
            rb = self.right.find(pair.right.image)
        t1 = time.perf_counter_ns()
        t_left, t_right = pair.left.t_ns, pair.right.t_ns
        compensate = p.skew_compensation and t_left != t_right
        t_ns = skew.common_instant(t_left, t_right) if compensate else pair.t_ns
        # Matching, compensation and triangulation work in rectified coordinates (identical to
        # image coordinates for the canonical rig); messages report the image ones.
        lrect = replace(lb, centroid_px=p.rig.rectify_left(lb.centroid_px))
        rrect = replace(rb, centroid_px=p.rig.rectify_right(rb.centroid_px))
        idx = matched_blobs(lrect, rrect, p.matching)
        lpx = lrect.centroid_px[idx[:, 0]]
        rpx = rrect.centroid_px[idx[:, 1]]
        observations = self._observe(lb, rb, idx, lpx, rpx)
        exact = [not compensate] * len(observations)
        if compensate:
            cache: dict[int, tuple[list[Observation], list[bool]]] = {}

            raw = observations

            def candidates(track: Track) -> list[Observation]:
                if track.track_id not in cache:
                    cache[track.track_id] = self._compensated(
                        track, lb, rb, idx, lpx, rpx, (t_left, t_right), t_ns
                    )
                return cache[track.track_id][0]

            assignment = self.tracker.associate(t_ns, observations, candidates, (t_left, t_right))
            observations = list(raw)
            for i, tid in enumerate(assignment):
                if tid is not None:
                    if tid not in cache:
                        candidates(self.tracker.track(tid))
                    shifted, flags = cache[tid]
                    observations[i], exact[i] = shifted[i], flags[i]
        else:
            assignment = self.tracker.associate(t_ns, observations)
        t2 = time.perf_counter_ns()
        states, ended = self.tracker.update(
            t_ns, observations, assignment, (t_left, t_right), exact
        )
        self._learn(states, pair.left.image.shape[:2])
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

    def _observe(
        self,
        lb: Blobs,
        rb: Blobs,
        idx: np.ndarray,
        lpx: np.ndarray,
        rpx: np.ndarray,
        tri_left: np.ndarray | None = None,
        tri_right: np.ndarray | None = None,
    ) -> list[Observation]:
        """Observations from matched blobs; ``tri_*`` are the centroids to triangulate when they
        differ from the measured ones (skew compensation)."""
        if len(idx) == 0:
            return []
        p = self.params
        tl = lpx if tri_left is None else tri_left
        tr = rpx if tri_right is None else tri_right
        points, cov = p.rig.triangulate(tl, tr, p.centroid_sigma_px)
        f = p.rig.focal_px
        obs = []
        for k, (i, j) in enumerate(idx):
            width_px = 0.5 * (lb.bbox_px[i, 2] + rb.bbox_px[j, 2])
            obs.append(
                Observation(
                    position_m=points[k],
                    cov_m2=cov[k],
                    left_px=lpx[k],
                    right_px=rpx[k],
                    left_image_px=lb.centroid_px[i],
                    right_image_px=rb.centroid_px[j],
                    left_bbox_px=lb.bbox_px[i],
                    right_bbox_px=rb.bbox_px[j],
                    left_area_px=int(lb.area_px[i]),
                    right_area_px=int(rb.area_px[j]),
                    disparity_px=float(tl[k, 0] - tr[k, 0]),
                    size_m=float(width_px * points[k, 2] / f),
                )
            )
        return obs

    def _compensated(
        self,
        track: Track,
        lb: Blobs,
        rb: Blobs,
        idx: np.ndarray,
        lpx: np.ndarray,
        rpx: np.ndarray,
        eye_times: tuple[int, int],
        t_ns: int,
    ) -> tuple[list[Observation], list[bool]]:
        """Every observation as if it belonged to ``track``: each eye's centroid moved to
        ``t_ns`` along that eye's image velocity, fitted to the track's recent centroids in that
        eye plus this one, then triangulated again. The flags say which observations could be
        moved (the earlier eye had a past centroid): those are exact."""
        window = int(self.params.skew_window_s * 1e9)
        t_left, t_right = eye_times
        tl, tr = lpx.copy(), rpx.copy()
        early_history = track.left_history if t_left < t_right else track.right_history
        exact = [len(early_history) > 0] * len(lpx)
        for k in range(len(lpx)):
            vl = skew.image_velocity([*track.left_history, (t_left, lpx[k])], window)
            vr = skew.image_velocity([*track.right_history, (t_right, rpx[k])], window)
            tl[k] = skew.shift_to(lpx[k], t_left, vl, t_ns)
            tr[k] = skew.shift_to(rpx[k], t_right, vr, t_ns)
        return self._observe(lb, rb, idx, lpx, rpx, tl, tr), exact

    def _learn(self, states: list[TrackState], shape: tuple[int, ...]) -> None:
        """Eq. 3 on both eyes, not under objects being tracked (so a stopped one stays seen)."""
        masks: list[np.ndarray | None] = [None, None]
        if self.params.freeze_background:
            frozen = [s for s in states if s.freeze_background]
            if frozen:
                h, w = shape[0], shape[1]
                m = FREEZE_MARGIN_PX
                for e in range(2):
                    mask = np.full((h, w), 255, np.uint8)
                    for s in frozen:
                        ob = s.observation
                        x, y, bw, bh = (ob.left_bbox_px, ob.right_bbox_px)[e]
                        cv2.rectangle(
                            mask,
                            (int(x) - m, int(y) - m),
                            (int(x + bw) + m, int(y + bh) + m),
                            0,
                            -1,
                        )
                    masks[e] = mask
        self.left.learn(masks[0])
        self.right.learn(masks[1])
