"""Webcam transport of the independent renderer: rolling shutter, flicker, 4:2:2, MJPEG."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from stereod_fakes.world import (
    Box,
    Lighting,
    Photometry,
    Rig,
    Room,
    Scene,
    Trajectory,
    Transport,
    person_sit_walk,
    robot_ball,
    write_scene,
)
from stereod_fakes.world.textures import _remap
from stereod_fakes.world.transport import yuyv_422

BG, FG = 50.0, 250.0
NO_PHOTOMETRY = Photometry(left_gain=1.0, right_gain=1.0, drift_amplitude=0.0, noise_sigma=0.0)
FLAT = Room(floor_height_m=None, texture="flat", flat_wall_bgr=(BG, BG, BG))


def bar_scene(transport: Transport, speed: float, depth: float) -> Scene:
    """A thin vertical plate (taller than the view) sliding along +X at ``depth``."""
    bar = Box(
        name="bar",
        trajectory=Trajectory((-0.05, 0.0, depth), (speed, 0.0, 0.0)),
        half_size_m=(0.03, 2.0, 0.0005),
        colour_bgr=(FG, FG, FG),
    )
    return Scene(
        rig=Rig(80, 60, 60.0),
        objects=(bar,),
        lighting=Lighting(ambient=1.0, diffuse=0.0),
        photometry=NO_PHOTOMETRY,
        room=FLAT,
        transport=transport,
    )


def row_centroids(scene: Scene) -> np.ndarray:
    img = scene.render_radiance("left", scene.t0_ns)[..., 1].astype(np.float64)
    alpha = (img - BG) / (FG - BG)
    cols = np.arange(img.shape[1])
    return np.asarray((alpha * cols).sum(axis=1) / alpha.sum(axis=1))


def test_rolling_shutter_renders_each_row_at_its_own_instant() -> None:
    speed, depth, readout = 6.0, 1.5, 0.030  # 0.14 px per row
    scene = bar_scene(Transport(rolling_shutter=True, readout_s=readout), speed, depth)
    rig = scene.rig
    got = row_centroids(scene)
    rows = np.arange(rig.height_px)
    x = -0.05 + speed * rows * readout / rig.height_px  # bar centre when row r is exposed
    expected = rig.cx + rig.focal_px * (x - rig.camera_centre("left")[0]) / depth
    assert np.abs(got - expected).max() < 0.05  # a third of a row's shift
    slope = np.polyfit(rows, got, 1)[0]
    assert abs(slope - rig.focal_px * speed * readout / (rig.height_px * depth)) < 1e-3
    # Faster: bands of 6 rows, each cast at the instant of its middle row (a staircase).
    banded = replace(scene, quality=replace(scene.quality, rolling_band_rows=6))
    mid_rows = (rows // 6) * 6 + 2.5
    x_band = -0.05 + speed * mid_rows * readout / rig.height_px
    stairs = rig.cx + rig.focal_px * (x_band - rig.camera_centre("left")[0]) / depth
    assert np.abs(row_centroids(banded) - stairs).max() < 0.05
    # A global shutter (the default) sees the whole bar at t: upright.
    upright = row_centroids(bar_scene(Transport(), speed, depth))
    assert np.ptp(upright) < 0.01 and abs(upright[0] - expected[0]) < 0.02
    # Truth stays the nominal instant (row 0), whatever the readout.
    assert np.allclose(scene.truth(scene.t0_ns)["bar"][0], (-0.05, 0.0, depth))


def test_readout_is_written_with_the_truth(tmp_path: Path) -> None:
    scene = replace(
        bar_scene(Transport(rolling_shutter=True, readout_s=0.02), 1.0, 1.5),
        rig=Rig(32, 24, 60.0),
        duration_s=0.1,
    )
    out = write_scene(scene, tmp_path / "rec")
    meta = json.loads((out / "scene.json").read_text())
    assert meta["derived"]["readout_s"] == 0.02
    assert "row 0" in meta["derived"]["timestamp_convention"]
    with (out / "truth.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows and all(float(r["readout_s"]) == 0.02 for r in rows)
    assert {r["kind"] for r in rows} == {"Box"}


def flicker_mean(t0: float, exposure: float, depth: float, hz: float, phase: float) -> float:
    """Mean of 1 - depth (1 + cos(2 pi hz t + phase)) / 2 over [t0, t0 + exposure] (numeric)."""
    n = 4001
    t = t0 + exposure * (np.arange(n) + 0.5) / n
    return float(np.mean(1.0 - 0.5 * depth * (1.0 + np.cos(2.0 * math.pi * hz * t + phase))))


def test_mains_flicker_is_integrated_over_each_rows_exposure() -> None:
    grey = 200.0
    room = Room(floor_height_m=None, texture="flat", flat_wall_bgr=(grey, grey, grey))
    tr = Transport(rolling_shutter=True, readout_s=0.030, flicker_depth=0.4, flicker_phase_rad=0.3)
    scene = Scene(
        rig=Rig(40, 60, 60.0), photometry=NO_PHOTOMETRY, room=room, transport=tr, exposure_s=0.004
    )
    t_ns = scene.frame_times("left")[2]
    img = scene.render("left", t_ns).astype(np.float64)
    assert np.ptp(img, axis=(1, 2)).max() == 0.0  # uniform along each row
    t0 = scene.time_s(t_ns)
    h = scene.rig.height_px
    expected = [grey * flicker_mean(t0 + r * 0.030 / h, 0.004, 0.4, 100.0, 0.3) for r in range(h)]
    assert np.abs(img[:, 0, 0] - np.asarray(expected)).max() <= 0.5 + 1e-6
    # 30 ms of readout spans three 10 ms flicker periods: three dark bands down the image.
    dark = img[:, 0, 0] < grey * (1.0 - 0.3)
    assert np.count_nonzero(np.diff(dark.astype(int)) == 1) + int(dark[0]) == 3
    # A global shutter: every row alike, and the frame brightness follows the mains phase.
    glob = replace(scene, transport=replace(tr, rolling_shutter=False))
    means = []
    for t in glob.frame_times("left")[:6]:
        frame = glob.render("left", t).astype(np.float64)
        assert np.ptp(frame) == 0.0
        want = grey * flicker_mean(glob.time_s(t), 0.004, 0.4, 100.0, 0.3)
        assert abs(frame[0, 0, 0] - want) <= 0.5 + 1e-6
        means.append(frame[0, 0, 0])
    assert np.ptp(means) > 10.0


def test_yuyv_422_averages_chroma_over_pixel_pairs_and_keeps_luma() -> None:
    rng = np.random.default_rng(5)
    img = rng.integers(20, 236, size=(6, 10, 3), dtype=np.uint8)
    img[:, 0::2] = (40, 40, 220)  # red even columns, blue odd ones: the worst case
    img[:, 1::2] = (220, 40, 40)
    img[3:] = rng.integers(20, 236, size=(3, 10, 3), dtype=np.uint8)
    out = yuyv_422(img)
    ycc_in = cv2.cvtColor(img, cv2.COLOR_BGR2YCrCb).astype(np.float64)
    ycc_out = cv2.cvtColor(out, cv2.COLOR_BGR2YCrCb).astype(np.float64)
    assert np.abs(ycc_out[..., 0] - ycc_in[..., 0]).max() <= 2.0  # luma kept per pixel
    pair_in = ycc_in[..., 1:].reshape(6, 5, 2, 2)
    pair_out = ycc_out[..., 1:].reshape(6, 5, 2, 2)
    assert np.abs(pair_out[:, :, 0] - pair_out[:, :, 1]).max() <= 2.0  # one chroma per pair
    assert np.abs(pair_out.mean(axis=2) - pair_in.mean(axis=2)).max() <= 2.0
    assert np.abs(pair_in[:3, :, 0] - pair_in[:3, :, 1]).min() > 100.0  # it was not so before
    # In a scene it is applied to the final 8-bit frame, deterministically.
    scene = robot_ball(90, mode=(64, 48, 30.0))
    t = scene.frame_times("left")[40]
    yuyv = replace(scene, transport=Transport(yuyv_422=True))
    assert np.array_equal(yuyv.render("left", t), yuyv_422(scene.render("left", t)))


def test_mjpeg_round_trip() -> None:
    scene = robot_ball(90, mode=(96, 72, 30.0))
    t = scene.frame_times("left")[40]
    raw = scene.render("left", t)
    mj = replace(scene, transport=Transport(mjpeg_quality=75))
    got = mj.render("left", t)
    ok, buf = cv2.imencode(".jpg", raw, [cv2.IMWRITE_JPEG_QUALITY, 75])
    assert ok
    assert np.array_equal(got, cv2.imdecode(buf, cv2.IMREAD_COLOR))
    assert np.array_equal(got, mj.render("left", t))  # deterministic
    mse = float(np.mean((got.astype(np.float64) - raw) ** 2))
    assert mse > 0.0 and 10.0 * math.log10(255.0**2 / mse) > 28.0
    low = replace(scene, transport=Transport(mjpeg_quality=20)).render("left", t)
    assert np.mean((low.astype(np.float64) - raw) ** 2) > mse


def test_a_lookup_of_no_texels_is_empty() -> None:
    atlas = np.ones((4, 4, 3), np.float32)
    none = np.zeros((0, 5), np.float32)
    assert _remap(atlas, none, none).shape == (0, 5, 3)


def test_rolling_shutter_renders_a_band_with_no_background_in_it() -> None:
    # Frame 468 of this scene once failed in OpenCV's remap: one of its rolling shutter's
    # bands needed no background ray (found by rendering the whole scene from the CLI).
    scene = replace(
        person_sit_walk(8.0, lit=True),
        transport=Transport(rolling_shutter=True, readout_s=0.03, mjpeg_quality=80),
    )
    img = scene.render("left", scene.frame_times("left")[468])
    assert img.shape == (scene.rig.height_px, scene.rig.width_px, 3)
    assert 20 < float(img.mean()) < 235
