"""One stereo pair in, one objects message out: detect, match, triangulate, track (design sec. 1).

The pipeline is pure computation on arrays: no threads of its own beyond an optional two-worker
pool that detects both eyes at once (OpenCV releases the GIL), no Zenoh, no devices.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .detect import Blobs, Detector, DetectorParams
from .frames import StereoPair
from .geometry.stereo import CanonicalRig, MatchParams, matched_blobs
from .messages import EyeBlob, Latency, ObjectsMessage, ObjectState
from .tracking import Observation, Tracker, TrackerParams, TrackState


@dataclass(frozen=True)
class PipelineParams:
    """Everything the pipeline needs besides the frames."""

    rig_name: str
    rig: CanonicalRig
    detector: DetectorParams = field(default_factory=DetectorParams)
    matching: MatchParams = field(default_factory=MatchParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    centroid_sigma_px: float = 0.5
    detect_workers: int = 1


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
        self._pool = (
            ThreadPoolExecutor(2, thread_name_prefix="detect")
            if params.detect_workers > 1
            else None
        )

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def process(self, pair: StereoPair, queued_ns: int = 0) -> PairResult:
        """Run one pair through eq. 2-5, 9, 12 and 21-23; ``queued_ns`` is the time the pair
        waited for the pipeline (ns), reported in the latency breakdown."""
        t0 = time.perf_counter_ns()
        if self._pool is not None:
            fut = self._pool.submit(self.right.detect, pair.right.image)
            lb = self.left.detect(pair.left.image)
            rb = fut.result()
        else:
            lb = self.left.detect(pair.left.image)
            rb = self.right.detect(pair.right.image)
        t1 = time.perf_counter_ns()
        observations, residuals = self._observe(lb, rb)
        t2 = time.perf_counter_ns()
        t_ns = pair.t_ns
        states, ended = self.tracker.update(t_ns, observations)
        t3 = time.perf_counter_ns()
        latency = Latency(
            detect_ms=(t1 - t0) * 1e-6,
            geometry_ms=(t2 - t1) * 1e-6,
            track_ms=(t3 - t2) * 1e-6,
            pipeline_ms=(time.perf_counter_ns() - t0) * 1e-6,
            queue_ms=queued_ns * 1e-6,
        )
        return PairResult(self._message(pair, states, t_ns, latency), ended, lb, rb, residuals)

    def _observe(self, lb: Blobs, rb: Blobs) -> tuple[list[Observation], np.ndarray]:
        p = self.params
        idx = matched_blobs(lb, rb, p.matching)
        if len(idx) == 0:
            return [], np.zeros(0)
        lpx = lb.centroid_px[idx[:, 0]]
        rpx = rb.centroid_px[idx[:, 1]]
        points, cov = p.rig.triangulate(lpx, rpx, p.centroid_sigma_px)
        f = p.rig.focal_px
        obs = []
        for k, (i, j) in enumerate(idx):
            z = points[k, 2]
            width_px = 0.5 * (lb.bbox_px[i, 2] + rb.bbox_px[j, 2])
            obs.append(
                Observation(
                    position_m=points[k],
                    cov_m2=cov[k],
                    left_px=lpx[k],
                    right_px=rpx[k],
                    left_bbox_px=lb.bbox_px[i],
                    right_bbox_px=rb.bbox_px[j],
                    left_area_px=int(lb.area_px[i]),
                    right_area_px=int(rb.area_px[j]),
                    disparity_px=float(lpx[k, 0] - rpx[k, 0]),
                    size_m=float(width_px * z / f),
                )
            )
        return obs, np.abs(lpx[:, 1] - rpx[:, 1])

    def _message(
        self, pair: StereoPair, states: list[TrackState], t_ns: int, latency: Latency
    ) -> ObjectsMessage:
        stamp = t_ns + self.utc_offset_ns
        skew = pair.skew_ns
        objects = [_object_state(s, stamp, skew) for s in states]
        return ObjectsMessage(
            rig=self.params.rig_name,
            seq=pair.seq,
            t_ns=t_ns,
            stamp_utc_ns=stamp,
            skew_ns=skew,
            left_seq=pair.left.seq,
            right_seq=pair.right.seq,
            geometry="canonical",
            latency=latency,
            objects=objects,
        )


def _vec(a: np.ndarray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _finite(x: float) -> float | None:
    return x if np.isfinite(x) else None


def _object_state(s: TrackState, stamp_utc_ns: int, skew_ns: int) -> ObjectState:
    ob = s.observation
    sigma = np.sqrt(np.diag(ob.cov_m2))
    return ObjectState(
        track_id=s.track_id,
        state=s.lifecycle.value,
        t_ns=s.t_ns,
        stamp_utc_ns=stamp_utc_ns,
        skew_ns=skew_ns,
        position_m=_vec(ob.position_m),
        position_sigma_m=_vec(sigma),
        velocity_mps=_vec(s.velocity_mps),
        velocity_sigma_mps=(
            _vec(s.velocity_sigma_mps) if np.all(np.isfinite(s.velocity_sigma_mps)) else None
        ),
        velocity_valid=s.velocity_valid,
        speed_mps=s.speed_mps,
        speed_sigma_mps=_finite(s.speed_sigma_mps),
        heading_deg=s.heading_deg,
        heading_sigma_deg=_finite(s.heading_sigma_deg),
        raw_velocity_mps=None if s.raw_velocity_mps is None else _vec(s.raw_velocity_mps),
        left=EyeBlob(
            centroid_px=(float(ob.left_px[0]), float(ob.left_px[1])),
            bbox_px=tuple(int(v) for v in ob.left_bbox_px),  # type: ignore[arg-type]
            area_px=ob.left_area_px,
        ),
        right=EyeBlob(
            centroid_px=(float(ob.right_px[0]), float(ob.right_px[1])),
            bbox_px=tuple(int(v) for v in ob.right_bbox_px),  # type: ignore[arg-type]
            area_px=ob.right_area_px,
        ),
        disparity_px=ob.disparity_px,
        size_m=ob.size_m,
        age_s=s.age_s,
    )
