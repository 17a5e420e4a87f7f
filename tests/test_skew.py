"""Skew compensation: closed forms, and depth error on a rendered sideways motion."""

from __future__ import annotations

import numpy as np
import pytest

from stereod.pipeline import PipelineParams
from stereod.tracking import skew
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


def _projected(t_s: float) -> np.ndarray:
    """Pixel (2,) of a point at constant 3D velocity, thrown at a 500 px camera from 3 m at
    10 m/s with a sideways drift: x = f X / Z + c, closed form."""
    x, y, z = 0.1 + 1.0 * t_s, -0.2 + 0.5 * t_s, 3.0 - 10.0 * t_s
    return np.array([500.0 * x / z + 320.0, 500.0 * y / z + 240.0])


def test_moebius_is_exact_for_constant_velocity_where_a_line_is_not() -> None:
    """Three frames 66.7 ms apart (15 Hz) and an instant 16 ms before the newest: the
    fractional-linear curve through them is the projection itself; a straight line through
    the newest two errs by over a pixel."""
    times = (0, 66_666_667, 133_333_333)
    target = 117_000_000
    cs = tuple(_projected(t * 1e-9) for t in times)
    truth = _projected(target * 1e-9)
    got = skew.moebius(times, cs, target)
    np.testing.assert_allclose(got, truth, atol=1e-9)
    w = (target - times[1]) / (times[2] - times[1])
    line = cs[1] + (cs[2] - cs[1]) * w
    assert np.abs(line - truth).max() > 1.0
    # at_instant uses it once the eye has two earlier frames within the window
    hist = [(times[0], cs[0]), (times[1], cs[1])]
    np.testing.assert_allclose(skew.at_instant(hist, times[2], cs[2], target, 10**9), truth)


def test_two_frames_and_the_depth_change_follow_the_projection() -> None:
    """With only the eye's previous frame, the centroid at an instant between the two is the
    samples' mix weighted by their depths (homogeneous coordinates): given how much the depth
    changed, exact for the ball thrown at the camera, where the line errs by a pixel. The
    depth change comes from the blob's areas (a disc of radius 0.1 m seen by the 500 px
    camera), which scale as 1 / Z^2."""
    t0, t1, target = 0, 66_666_667, 50_000_000
    c0, c1 = _projected(t0 * 1e-9), _projected(t1 * 1e-9)
    truth = _projected(target * 1e-9)
    z0, z1 = 3.0 - 10.0 * t0 * 1e-9, 3.0 - 10.0 * t1 * 1e-9
    area0, area1 = (np.pi * (500.0 * 0.1 / z) ** 2 for z in (z0, z1))
    ratio = skew.size_depth_ratio(area0, area1)
    assert ratio == pytest.approx(z1 / z0)
    got = skew.at_instant([(t0, c0)], t1, c1, target, 10**9, ratio)
    assert got is not None
    np.testing.assert_allclose(got, truth, atol=1e-9)
    line = skew.at_instant([(t0, c0)], t1, c1, target, 10**9)
    assert line is not None and np.abs(line - truth).max() > 0.9
    # through compensate, per eye
    histories = ([(t0 - t1 + target, c0)], [(t0, c0)])
    lc, rc, exact = skew.compensate(
        histories, truth, c1, (target, t1), target, 10**9, (None, ratio)
    )
    assert exact
    np.testing.assert_allclose(rc, truth, atol=1e-9)
    np.testing.assert_array_equal(lc, truth)
    # A depth that changed by less than a blob's size wobbles, or is unknown, keeps the line:
    # 56 px against 62 px is 5 % in size, within a 56 px blob's noise (1.0 / sqrt(56) = 13 %),
    # and so is a ball crossing at one depth whose support read 54 px at 25 deg off the axis
    # and 62 px at 13 deg (10.9 % once the angle is out: at 0.75 it was taken as 10 % closer).
    assert skew.size_depth_ratio(56.0, 62.0) is None
    assert skew.size_depth_ratio(54.0, 62.0, 0.90, 0.974) is None
    assert skew.size_depth_ratio(151.0, 273.0) == pytest.approx((151.0 / 273.0) ** 0.5)
    assert skew.size_depth_ratio(0.0, 10.0) is None
    assert skew.projective_weight(0.75, None) == 0.75
    assert skew.projective_weight(0.5, 2.0) == pytest.approx(2.0 / 3.0)


def _ball_area_px(centre_m: np.ndarray, radius_m: float, f_px: float = 500.0) -> tuple[int, float]:
    """Pixels of a 640x480, ``f_px`` camera whose ray passes within ``radius_m`` of a ball's
    centre (its silhouette, ray-cast), and the cosine of the centre's angle off the axis."""
    u, v = np.meshgrid(np.arange(640) - 319.5, np.arange(480) - 239.5)
    rays = np.stack([u, v, np.full(u.shape, f_px)], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    along = rays @ centre_m
    miss2 = centre_m @ centre_m - along**2
    area = int(np.count_nonzero((miss2 <= radius_m**2) & (along > 0)))
    return area, float(centre_m[2] / np.linalg.norm(centre_m))


def test_a_ball_crossing_off_the_axis_keeps_its_depth() -> None:
    """A ball's image grows as it moves off the axis at one depth (it stretches along the
    ray): 28 deg off at 1.5 m it covers 13 % more pixels. Corrected for the angle, the
    areas say the depth did not change, so the line is kept; towards the camera they still
    give the ratio."""
    a0, c0 = _ball_area_px(np.array([0.0, 0.0, 1.5]), 0.035)
    a1, c1 = _ball_area_px(np.array([1.5 * np.tan(np.radians(28.0)), 0.0, 1.5]), 0.035)
    assert a1 > 1.1 * a0
    assert skew.size_depth_ratio(a0, a1) is not None  # taken for a 6 % approach
    assert skew.size_depth_ratio(a0, a1, c0, c1) is None
    a2, c2 = _ball_area_px(np.array([0.3, 0.0, 1.08]), 0.035)
    ratio = skew.size_depth_ratio(a0, a2, c0, c2)
    assert ratio == pytest.approx(1.08 / 1.5, rel=0.02)
    # no faster in depth than allowed: 0.42 m in 1/30 s is beyond 10 m/s from 1.5 m
    assert skew.size_depth_ratio(a0, a2, c0, c2, max_change=10.0 / 30 / 1.5) is None


def test_a_ball_thrown_at_the_rig_from_afar_is_already_on_the_curve() -> None:
    """A ball coming at 20 m/s from 5 m, 0.3 m off the axis, seen at 30 Hz by a 277 px
    camera (320x240, 60 deg): its image moves 2.6 then 3.5 px a frame, a change of 0.9 px that
    is well above a fitted centroid's noise, so the instant half a frame before the newest
    is taken on the curve, exact, where the line is 0.1 px off."""

    def seen(t_s: float) -> np.ndarray:
        return np.array([277.0 * 0.3 / (5.0 - 20.0 * t_s) + 160.0, 120.0])

    times = (0, 33_333_333, 66_666_667)
    target = 50_000_000
    cs = tuple(seen(t * 1e-9) for t in times)
    truth = seen(target * 1e-9)
    np.testing.assert_allclose(skew.moebius(times, cs, target), truth, atol=1e-9)
    assert abs((cs[1][0] + cs[2][0]) / 2 - truth[0]) > 0.08


def test_moebius_stays_between_the_bracketing_samples() -> None:
    """A coordinate whose samples go back and forth (noise on a still object) is interpolated
    linearly; a monotone one lands between the two samples that bracket the instant."""
    a, b, c = np.array([10.0, 5.0]), np.array([10.4, 5.2]), np.array([10.2, 9.0])
    got = skew.moebius((0, 10, 20), (a, b, c), 15)
    assert got[0] == pytest.approx(10.3)  # x went up then down: the line
    assert 5.2 < got[1] < 9.0  # y rose ever faster: between the last two, nearer the start
    assert got[1] < 7.1
    # motion that barely changes (0.5 then 0.9 px per frame): the line, not the curve
    a, b, c = np.array([10.0, 0.0]), np.array([10.5, 0.0]), np.array([11.4, 0.0])
    assert skew.moebius((0, 10, 20), (a, b, c), 15)[0] == pytest.approx(10.95)


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
    """The later eye's previous frame and this one bracket the earlier eye's instant: with no
    older frame the centroid there is on the line between them, exact for any motion linear
    between frames, and free of the lag a velocity fitted over older frames has when the
    image motion speeds up."""
    hist = [(0, np.array([100.0, 50.0])), (33_000_000, np.array([110.0, 50.0]))]
    now = np.array([130.0, 50.0])  # accelerating: 10 px, then 20 px per frame
    got = skew.at_instant(hist[1:], 66_000_000, now, 50_000_000, 150_000_000)
    assert got is not None
    np.testing.assert_allclose(got, [110.0 + 20.0 * 17 / 33, 50.0])
    # the first frame is outside the window: still the line
    got = skew.at_instant(hist, 66_000_000, now, 50_000_000, 40_000_000)
    np.testing.assert_allclose(got, [110.0 + 20.0 * 17 / 33, 50.0])
    # Nothing before the target: the image velocity moves it instead; nothing at all: None.
    moved = skew.at_instant(hist[1:], 66_000_000, now, 20_000_000, 10**9)
    assert moved is not None
    np.testing.assert_allclose(moved, [130.0 - 20.0 * 46 / 33, 50.0])
    assert skew.at_instant([], 33_000_000, now, 20_000_000, 10**9) is None
