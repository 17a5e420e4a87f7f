"""Nearest-neighbour tracking with eq. 21-23 motion, on trajectories with known velocity."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.tracking import Observation, Tracker, TrackerParams, TrackLifecycle


def obs(p: np.ndarray, sigma: float = 0.01) -> Observation:
    z2 = np.zeros(2)
    return Observation(
        position_m=np.asarray(p, float),
        cov_m2=np.eye(3) * sigma**2,
        left_px=z2,
        right_px=z2,
        left_bbox_px=np.zeros(4, np.int32),
        right_bbox_px=np.zeros(4, np.int32),
        left_area_px=1,
        right_area_px=1,
        disparity_px=1.0,
        size_m=0.1,
    )


def test_constant_velocity_track_reports_truth() -> None:
    tracker = Tracker(TrackerParams(time_base_s=0.5, confirm_hits=3))
    v = np.array([0.35, 0.0, -0.6])
    p0 = np.array([-0.2, 0.1, 2.0])
    states = []
    for k in range(20):
        t_ns = 10**9 + k * 66_666_667
        st, ended = tracker.update(t_ns, [obs(p0 + v * (t_ns - 10**9) * 1e-9)])
        assert ended == []
        states += st
    assert {s.track_id for s in states} == {1}
    assert states[0].lifecycle is TrackLifecycle.TENTATIVE
    assert states[2].lifecycle is TrackLifecycle.CONFIRMED
    assert not states[6].velocity_valid  # 0.4 s < time base
    last = states[-1]
    assert last.velocity_valid
    np.testing.assert_allclose(last.velocity_mps, v, atol=1e-9)
    np.testing.assert_allclose(last.raw_velocity_mps, v, atol=1e-9)
    assert last.speed_mps == pytest.approx(np.linalg.norm(v))
    assert last.heading_deg == pytest.approx(np.degrees(np.arctan2(0.35, -0.6)) % 360)
    assert last.age_s == pytest.approx(19 * 0.066666667, abs=1e-6)


def test_two_objects_keep_ids_and_ended_track_is_reported() -> None:
    tracker = Tracker(TrackerParams(max_coast_s=0.3))
    a0, b0 = np.array([-0.5, 0, 2.0]), np.array([0.5, 0, 2.5])
    va, vb = np.array([0.5, 0, 0]), np.array([-0.5, 0, 0])
    ids = []
    for k in range(10):
        t = k * 0.1
        st, _ = tracker.update(int(t * 1e9), [obs(b0 + vb * t), obs(a0 + va * t)])
        ids.append([s.track_id for s in st])
    assert ids == [[1, 2]] * 10
    ended_at = None
    for k in range(10, 16):
        _, ended = tracker.update(int(k * 0.1 * 1e9), [obs(a0 + va * k * 0.1)])
        if ended:
            ended_at = (k, ended)
            break
    assert ended_at == (13, [1]), "track 1 ends once unseen for more than max_coast_s"
    assert tracker.live_ids() == [2]
    st, _ = tracker.update(int(1.7e9), [obs(b0 + vb * 1.7)])
    assert st[0].track_id == 3, "a returning object gets a new id"


def test_far_observation_starts_a_new_track() -> None:
    tracker = Tracker(TrackerParams(gate_m=0.2))
    tracker.update(0, [obs(np.array([0, 0, 2.0]))])
    st, _ = tracker.update(66_000_000, [obs(np.array([0.5, 0, 2.0]))])
    assert st[0].track_id == 2
