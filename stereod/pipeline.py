"""One stereo pair in, one objects message out (design sec. 1).

detect both eyes (eq. 2-5) -> match blobs by row, disparity and size -> triangulate (eq. 9) ->
associate with tracks -> skew compensation (each eye's centroid moved to one instant along its
2D track) and triangulate again -> Kalman update -> background learning (eq. 3), frozen under
tracked objects -> message.

The pipeline is pure computation on arrays: no threads of its own beyond an optional two-worker
pool that detects both eyes at once (OpenCV releases the GIL), no Zenoh, no devices.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from . import skew
from .detect import Blobs, Detector, DetectorParams
from .frames import StereoPair
from .geometry.rectified import CalibratedRig
from .geometry.stereo import CanonicalRig, MatchParams, matched_blobs
from .messages import EyeBlob, Latency, ObjectsMessage, ObjectState
from .tracking import Observation, Track, Tracker, TrackerParams, TrackState

FREEZE_MARGIN_PX = 4
"""Margin (px) around a tracked blob's box where the background is not learned either."""


@dataclass(frozen=True)
class PipelineParams:
    """Everything the pipeline needs besides the frames.

    ``centroid_sigma_px``: assumed centroid error per axis (px), the source of every covariance.
    ``skew_compensation``: move both eyes' centroids to one instant before triangulating.
    ``skew_window_s``: how much of an eye's 2D track (s) its image velocity is fitted over.
    ``freeze_background``: do not learn the background under tracked objects.
    """

    rig_name: str
    rig: CanonicalRig | CalibratedRig
    detector: DetectorParams = field(default_factory=DetectorParams)
    matching: MatchParams = field(default_factory=MatchParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    centroid_sigma_px: float = 0.5
    detect_workers: int = 1
    skew_compensation: bool = True
    skew_window_s: float = 0.15
    freeze_background: bool = True


@dataclass
class PairResult:
    """What one pair produced: the message, the tracks that ended, and the raw blobs."""

    message: ObjectsMessage
    ended: list[int]
    left: Blobs
    right: Blobs
    row_residuals_px: np.ndarray = field(default_factory=lambda: np.zeros(0))


class Pipeline:
    """Stateful per-rig processing: background models, tracker, clock offset."""

    def __init__(self, params: PipelineParams, utc_offset_ns: int) -> None:
        self.params = params
        self.utc_offset_ns = utc_offset_ns
        self.left = Detector(params.detector)
        self.right = Detector(params.detector)
        self.tracker = Tracker(params.tracker)
        self.ended_by_reconfiguration: list[int] = []
        """Tracks this pipeline ended when it was replaced by :meth:`reconfigured`."""
        self._pool = (
            ThreadPoolExecutor(2, thread_name_prefix="detect")
            if params.detect_workers > 1
            else None
        )

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def reconfigured(self, params: PipelineParams) -> Pipeline:
        """A pipeline with new parameters that carries over what still holds: the background
        models (always, so there is no new warm-up), and the tracks while neither the tracker
        settings nor the geometry changed. Otherwise the old tracks end (their ids are listed
        in ``ended_by_reconfiguration`` of this pipeline) and new ids continue after them."""
        new = Pipeline(params, self.utc_offset_ns)
        new.left.adopt(self.left)
        new.right.adopt(self.right)
        same_geometry = type(params.rig) is type(self.params.rig) and (
            params.rig.calibration_id == self.params.rig.calibration_id
            and (params.rig == self.params.rig or params.rig.calibration_id is not None)
        )
        if params.tracker == self.params.tracker and same_geometry:
            new.tracker = self.tracker
            self.ended_by_reconfiguration = []
        else:
            self.ended_by_reconfiguration = self.tracker.end_all()
            new.tracker.continue_after(self.tracker)
        self.close()
        return new

    def process(self, pair: StereoPair, queued_ns: int = 0) -> PairResult:
        """Run one pair through eq. 2-5, 9, 12 and 21-23; ``queued_ns`` is the time the pair
        waited for the pipeline (ns), reported in the latency breakdown."""
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
        latency = Latency(
            detect_ms=(t1 - t0) * 1e-6,
            geometry_ms=(t2 - t1) * 1e-6,
            track_ms=(t3 - t2) * 1e-6,
            pipeline_ms=(time.perf_counter_ns() - t0) * 1e-6,
            queue_ms=queued_ns * 1e-6,
        )
        residuals = np.abs(lpx[:, 1] - rpx[:, 1])
        return PairResult(self._message(pair, states, t_ns, latency), ended, lb, rb, residuals)

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

    def _message(
        self, pair: StereoPair, states: list[TrackState], t_ns: int, latency: Latency
    ) -> ObjectsMessage:
        stamp = t_ns + self.utc_offset_ns
        skew_ns = pair.skew_ns
        return ObjectsMessage(
            rig=self.params.rig_name,
            seq=pair.seq,
            t_ns=t_ns,
            stamp_utc_ns=stamp,
            skew_ns=skew_ns,
            left_seq=pair.left.seq,
            right_seq=pair.right.seq,
            geometry=self.params.rig.geometry,  # type: ignore[arg-type]
            calibration_id=self.params.rig.calibration_id,
            latency=latency,
            objects=[object_state(s, stamp, skew_ns) for s in states],
        )


def _vec(a: np.ndarray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _finite(x: float) -> float | None:
    return x if np.isfinite(x) else None


def _blob(centroid: np.ndarray, bbox: np.ndarray, area: int) -> EyeBlob:
    return EyeBlob(
        centroid_px=(float(centroid[0]), float(centroid[1])),
        bbox_px=(int(bbox[0]), int(bbox[1]), int(bbox[2]), int(bbox[3])),
        area_px=area,
    )


def object_state(s: TrackState, stamp_utc_ns: int, skew_ns: int) -> ObjectState:
    """The wire form of one track's state."""
    ob = s.observation
    vsig = np.sqrt(np.diag(s.velocity_cov))
    return ObjectState(
        track_id=s.track_id,
        state=s.lifecycle.value,
        t_ns=s.t_ns,
        stamp_utc_ns=stamp_utc_ns,
        skew_ns=skew_ns,
        position_m=_vec(s.position_m),
        position_sigma_m=_vec(np.sqrt(np.diag(s.position_cov_m2))),
        velocity_mps=_vec(s.velocity_mps),
        velocity_sigma_mps=_vec(vsig) if np.all(np.isfinite(vsig)) else None,
        velocity_valid=s.velocity_valid,
        speed_mps=s.speed_mps,
        speed_sigma_mps=_finite(s.speed_sigma_mps),
        heading_deg=s.heading_deg,
        heading_sigma_deg=_finite(s.heading_sigma_deg),
        raw_velocity_mps=None if s.raw_velocity_mps is None else _vec(s.raw_velocity_mps),
        left=_blob(ob.left_image_px, ob.left_bbox_px, ob.left_area_px),
        right=_blob(ob.right_image_px, ob.right_bbox_px, ob.right_area_px),
        disparity_px=ob.disparity_px,
        size_m=ob.size_m,
        age_s=s.age_s,
    )
