"""A frame where nothing moves (:data:`stereod.vision.background.QUIET_LEVELS`) costs the
difference pass and eq. 3 on one such frame in two (:data:`stereod.vision.background.IDLE_EVERY`):
the background still follows light that drifts, as eq. 3 on every frame would, and finds an
object that comes after a long empty stretch."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereod.vision.background import IDLE_EVERY
from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams

H, W = 120, 160
FRAMES = 900
"""The empty stretch: 30 s at 30 Hz."""


def _wall(rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float: a smooth colour texture, grey levels about 90 +- 20."""
    coarse = rng.normal(90.0, 20.0, (H // 8 + 1, W // 8 + 1, 3))
    return cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC)


def _light(wall: np.ndarray, t: int, drift: str) -> np.ndarray:
    """The wall at frame ``t`` of the stretch: 0.01 grey levels brighter a frame (+9 over
    the stretch), or 0.01 % a frame brighter (x 1.09 over the stretch), a light that
    drifts."""
    return wall + 0.01 * t if drift == "offset" else wall * 1.0001**t


def _u8(a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return np.clip(a + rng.normal(0.0, 1.0, a.shape), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("drift", ["offset", "gain"])
def test_an_empty_stretch_learns_on_one_frame_in_two_and_follows_a_drifting_light(
    drift: str,
) -> None:
    """Over 900 empty frames of a light that drifts, nothing is detected, T is written on one
    frame in ``IDLE_EVERY`` (and where the gain rescales it) only, and ends as close to the
    light (mean over the image, grey levels) as eq. 3 on every row of every frame at the
    same beta (computed here), within one level; a ball that then comes in is found in its
    first frame, centred within 0.3 px."""
    rng = np.random.default_rng(3)
    wall = _wall(rng)
    params = DetectorParams()
    det = Detector(params)
    reference: np.ndarray | None = None
    for _ in range(params.warmup_frames):
        det.detect(_u8(wall, rng))
    written = 0
    for t in range(FRAMES):
        frame = _u8(_light(wall, t, drift), rng)
        before = det.background
        assert before is not None
        before = before.copy()
        assert len(det.detect(frame)) == 0, f"frame {t}: something found in an empty scene"
        after = det.background
        assert after is not None
        written += int(not np.array_equal(before, after))
        if reference is None:
            reference = before.copy()
        cv2.accumulateWeighted(frame, reference, params.beta)
    assert reference is not None and det.background is not None
    assert FRAMES / IDLE_EVERY <= written <= 0.6 * FRAMES  # (and where a frame is not idle)
    now = _light(wall, FRAMES, drift)
    lag = float(np.mean(np.abs(det.background - now)))
    eq3 = float(np.mean(np.abs(reference - now)))
    assert lag < eq3 + 1.0, f"T lags the light by {lag:.2f} grey levels, eq. 3 by {eq3:.2f}"
    u, v, r = 83.3, 57.6, 6.0
    yy, xx = np.mgrid[0:H, 0:W]
    disc = ((xx - u) ** 2 + (yy - v) ** 2 <= r * r)[..., None]
    blobs = det.detect(_u8(np.where(disc, np.array([40.0, 200.0, 230.0]), now), rng))
    assert len(blobs) == 1
    assert float(np.hypot(*(blobs.centroid_px[0] - (u, v)))) < 0.3


def test_eq3_on_every_frame_is_kept_where_the_stride_is_one() -> None:
    """With ``learn_stride = 1`` (eq. 3 as the paper writes it) every empty frame is learned."""
    rng = np.random.default_rng(4)
    wall = _wall(rng)
    det = Detector(DetectorParams(learn_stride=1))
    for _ in range(DetectorParams().warmup_frames):
        det.detect(_u8(wall, rng))
    for _ in range(20):
        bg = det.background
        assert bg is not None
        before = bg.copy()
        det.detect(_u8(wall, rng))
        assert not np.array_equal(before, det.background)
