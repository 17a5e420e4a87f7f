"""Kalman tracker: lifecycle, gating and global assignment, ids, motion against known truth."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.tracking import Observation, Tracker, TrackerParams, TrackLifecycle, TrackState

DT_NS = 66_666_667


def obs(p: np.ndarray, sigma: float = 0.01) -> Observation:
    z2 = np.zeros(2)
    return Observation(
        position_m=np.asarray(p, float),
        cov_m2=np.eye(3) * sigma**2,
        left_px=z2,
        right_px=z2,
        left_image_px=z2,
        right_image_px=z2,
        left_bbox_px=np.zeros(4, np.int32),
        right_bbox_px=np.zeros(4, np.int32),
        left_area_px=1,
        right_area_px=1,
        disparity_px=1.0,
        size_m=0.1,
    )


def step(
    tracker: Tracker, t_ns: int, observations: list[Observation]
) -> tuple[list[TrackState], list[int]]:
    assignment = tracker.associate(t_ns, observations)
    return tracker.update(t_ns, observations, assignment, (t_ns, t_ns))


def test_constant_velocity_track_reports_truth() -> None:
    tracker = Tracker(TrackerParams(time_base_s=0.5, confirm_hits=3))
    v = np.array([0.35, 0.0, -0.6])
    p0 = np.array([-0.2, 0.1, 2.0])
    rng = np.random.default_rng(1)
    states = []
    for k in range(40):
        t = k * DT_NS
        st, ended = step(tracker, t, [obs(p0 + v * t * 1e-9 + rng.normal(0, 0.005, 3), 0.005)])
        assert ended == []
        states += st
    assert {s.track_id for s in states} == {1}
    assert [s.lifecycle for s in states[:3]] == [TrackLifecycle.TENTATIVE] * 2 + [
        TrackLifecycle.CONFIRMED
    ]
    assert not states[6].velocity_valid  # 0.4 s < time base
    assert states[8].velocity_valid
    last = states[-1]
    np.testing.assert_allclose(last.velocity_mps, v, atol=0.05)
    sig = np.sqrt(np.diag(last.velocity_cov))
    assert np.all(np.abs(last.velocity_mps - v) < 4 * sig + 1e-3)
    assert last.raw_velocity_mps is not None
    np.testing.assert_allclose(last.raw_velocity_mps, v, atol=0.05)
    assert abs(last.speed_mps - np.linalg.norm(v)) < 4 * last.speed_sigma_mps
    true_heading = np.degrees(np.arctan2(0.35, -0.6)) % 360
    assert abs(last.heading_deg - true_heading) < 4 * last.heading_sigma_deg
    assert last.age_s == pytest.approx(39 * DT_NS * 1e-9, abs=1e-6)


def test_coasting_then_ended_and_ids_never_reused() -> None:
    tracker = Tracker(TrackerParams(max_coast_s=0.3))
    a0, va = np.array([-0.5, 0, 2.0]), np.array([0.5, 0, 0])
    for k in range(10):
        step(tracker, k * DT_NS, [obs(a0 + va * k * DT_NS * 1e-9)])
    lifecycles = []
    for k in range(10, 20):
        st, ended = step(tracker, k * DT_NS, [])
        if ended:
            assert ended == [1]
            break
        lifecycles.append(st[0].lifecycle)
        # A coasting track's position is predicted along its velocity.
        np.testing.assert_allclose(st[0].position_m, a0 + va * k * DT_NS * 1e-9, atol=0.01)
    assert lifecycles == [TrackLifecycle.COASTING] * 4  # 0.27 s <= 0.3 s < 0.33 s
    st, _ = step(tracker, 30 * DT_NS, [obs(a0)])
    assert st[0].track_id == 2


def test_tentative_track_ends_at_first_miss() -> None:
    tracker = Tracker(TrackerParams(confirm_hits=3))
    step(tracker, 0, [obs(np.array([0, 0, 2.0]))])
    _, ended = step(tracker, DT_NS, [])
    assert ended == [1]


def test_global_assignment_beats_greedy() -> None:
    """Greedy nearest-first would give track 1 the observation at 0.10 and leave the other far
    outside track 2's gate; the global assignment keeps both."""
    tracker = Tracker(TrackerParams(confirm_hits=1, init_velocity_sigma_mps=0.01))
    step(tracker, 0, [obs(np.array([0.0, 0, 2.0]), 0.05), obs(np.array([0.16, 0, 2.0]), 0.05)])
    a = tracker.associate(
        DT_NS, [obs(np.array([0.10, 0, 2.0]), 0.05), obs(np.array([-0.06, 0, 2.0]), 0.05)]
    )
    assert a == [2, 1]


def test_mahalanobis_gate_uses_depth_uncertainty() -> None:
    """The same 0.3 m jump is accepted along a noisy depth axis and refused across it."""
    tracker = Tracker(TrackerParams(confirm_hits=1, init_velocity_sigma_mps=0.01))
    far = np.diag([0.01, 0.01, 0.2]) ** 2
    ob = obs(np.array([0, 0, 4.0]))
    step(
        tracker,
        0,
        [Observation(**{**{f: getattr(ob, f) for f in Observation.__slots__}, "cov_m2": far})],
    )
    along = Observation(
        **{
            **{f: getattr(ob, f) for f in Observation.__slots__},
            "position_m": np.array([0, 0, 4.3]),
            "cov_m2": far,
        }
    )
    across = Observation(
        **{
            **{f: getattr(ob, f) for f in Observation.__slots__},
            "position_m": np.array([0.3, 0, 4.0]),
            "cov_m2": far,
        }
    )
    assert tracker.associate(DT_NS, [along]) == [1]
    assert tracker.associate(DT_NS, [across]) == [None]


def test_inexact_observations_do_not_reach_the_filter() -> None:
    """Observations flagged inexact (skew not compensated yet) are replaced by the first exact
    one: the filter starts afresh there."""
    tracker = Tracker(TrackerParams(confirm_hits=1))
    biased = obs(np.array([0, 0, 2.5]))
    tracker.update(0, [biased], [None], (0, 0), [False])
    st, _ = tracker.update(DT_NS, [obs(np.array([0, 0, 2.0]))], [1], (DT_NS, DT_NS), [True])
    np.testing.assert_allclose(st[0].position_m, [0, 0, 2.0])
    np.testing.assert_allclose(st[0].velocity_mps, 0.0)


def test_stopped_object_freezes_background_for_freeze_s() -> None:
    tracker = Tracker(TrackerParams(confirm_hits=1, freeze_s=1.0))
    flags = []
    for k in range(60):
        x = min(k, 15) * 0.03  # 0.45 m/s for 1 s, then still
        st, _ = step(tracker, k * DT_NS, [obs(np.array([x, 0, 2.0]), 0.001)])
        flags.append(st[0].freeze_background)
    assert any(flags[:15]), "a moving tracked object freezes the background under it"
    last = max(i for i, f in enumerate(flags) if f)
    assert 14 + 13 <= last <= 15 + 15 + 10, f"freeze ended at frame {last}"
    assert not any(flags[last + 1 :])


def test_object_never_seen_moving_does_not_freeze() -> None:
    tracker = Tracker(TrackerParams(confirm_hits=1))
    for k in range(30):
        st, _ = step(tracker, k * DT_NS, [obs(np.array([0, 0, 2.0]), 0.001)])
        assert not st[0].freeze_background
