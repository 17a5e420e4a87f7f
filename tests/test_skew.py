"""Skew compensation: closed forms, and depth error on a rendered sideways motion."""

from __future__ import annotations

import numpy as np
import pytest

from stereod import skew
from stereod.pipeline import PipelineParams
from stereod_fakes.synth import Ball, Scene
from tests.scenes import run_scene, states


def test_image_velocity_and_shift() -> None:
    hist = [(k * 50_000_000, np.array([100.0 + 3 * k, 50.0 - k])) for k in range(6)]
    v = skew.image_velocity(hist, max_age_ns=10**9)
    assert v is not None
    np.testing.assert_allclose(v, [60.0, -20.0])
    np.testing.assert_allclose(skew.shift_to(np.array([10.0, 10.0]), 0, v, 25_000_000), [11.5, 9.5])
    assert skew.image_velocity(hist[:1], 10**9) is None
    # Samples older than the window: the newest two still give the velocity.
    np.testing.assert_allclose(skew.image_velocity(hist, max_age_ns=10_000_000), [60.0, -20.0])
    assert skew.common_instant(5, 9) == 5


def depth_errors(compensate: bool, skew_s: float) -> np.ndarray:
    scene = Scene(
        skew_s=skew_s,
        fps=15,
        balls=[
            Ball(
                heading_deg=90,
                speed_mps=1.0,
                centre_m=(0.0, 0.0, 2.0),
                t_on_s=1.0,
                t_off_s=2.6,
                t_mid_s=1.8,
            )
        ],
    )
    ball = scene.balls[0]
    errs = []
    results = run_scene(scene, PipelineParams(scene.rig, skew_compensation=compensate))
    for o in states(results, confirmed=True):
        truth = ball.position_m((o.t_ns - scene.t0_ns) / 1e9)
        errs.append(abs(o.position_m[2] - truth[2]))
    return np.array(errs)


def test_compensation_cuts_depth_error_by_five_on_33ms_skew() -> None:
    """1 m/s sideways at 2 m with the right eye 33 ms late (half a frame at 15 Hz)."""
    off = depth_errors(False, 0.033)
    on = depth_errors(True, 0.033)
    assert len(on) > 15 and len(off) > 15
    assert np.median(off) > 0.2, f"uncompensated depth error only {np.median(off):.3f} m"
    ratio = np.median(on) / np.median(off)
    assert ratio <= 0.2, f"compensated {np.median(on):.4f} m vs {np.median(off):.4f} m"


def test_compensation_is_harmless_without_skew() -> None:
    assert np.median(depth_errors(True, 0.0)) == pytest.approx(
        np.median(depth_errors(False, 0.0)), abs=2e-3
    )


def test_the_later_eye_is_interpolated_between_its_two_frames() -> None:
    """The later eye's previous frame and this one bracket the earlier eye's instant: the
    centroid there is interpolated, exact for any motion that is linear between frames, and
    free of the lag a velocity fitted over older frames has when the image motion speeds up."""
    hist = [(0, np.array([100.0, 50.0])), (33_000_000, np.array([110.0, 50.0]))]
    now = np.array([130.0, 50.0])  # accelerating: 10 px, then 20 px per frame
    got = skew.at_instant(hist, 66_000_000, now, 50_000_000, 150_000_000)
    assert got is not None
    np.testing.assert_allclose(got, [110.0 + 20.0 * 17 / 33, 50.0])
    # Nothing before the target: the image velocity moves it instead; nothing at all: None.
    moved = skew.at_instant(hist[1:], 66_000_000, now, 20_000_000, 10**9)
    assert moved is not None
    np.testing.assert_allclose(moved, [130.0 - 20.0 * 46 / 33, 50.0])
    assert skew.at_instant([], 33_000_000, now, 20_000_000, 10**9) is None
