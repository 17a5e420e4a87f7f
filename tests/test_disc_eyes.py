"""Both eyes' round blobs centred by one batched disc fit, as each eye's alone would be."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from stereod.pipeline import Pipeline, PipelineParams
from stereod.sources.frames import StereoPair
from stereod.vision import detect
from stereod.vision.detect import Detector, fit_round_blobs
from stereod.vision.detect_params import DetectorParams
from stereod.vision.geometry.stereo import CanonicalRig
from stereod_fakes.synth import Ball, Renderer, Scene
from tests.shaded_balls import shaded_balls

TOLERANCE_PX = 1e-9
"""How far a centre fitted with the other eye's blobs may be from the one fitted alone: the
batch sums the same products and solves the same systems, blob by blob."""


def _eye(rng: np.random.Generator, h: int, w: int) -> tuple[np.ndarray, np.ndarray, list]:
    """A textured wall, a frame of it with four shaded balls 5-16 px across (each pixel the
    share a ball covers, sampled 8 x 8, of its colour, plus sensor noise), both uint8
    (h, w, 3), and the balls' true centres (x, y px)."""
    wall, frame, truth = shaded_balls(rng, h, w, (2.5, 4.0, 6.0, 8.0), 30.0, 45.0)
    return wall.astype(np.uint8), frame.astype(np.uint8), truth


def _counted(monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> list[int]:
    """Wrap ``module.name`` so that each call appends its first argument's length."""
    calls: list[int] = []
    real: Callable[..., object] = getattr(module, name)

    def counting(*args: object) -> object:
        calls.append(len(args[0]))  # type: ignore[arg-type]
        return real(*args)

    monkeypatch.setattr(module, name, counting)
    return calls


def test_both_eyes_round_blobs_are_fitted_in_one_batch_as_each_eye_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two eyes' frames of four balls each, found with ``fit_later`` and centred by one
    :func:`fit_round_blobs`: each centre is what the eye's own detector fits alone (within
    ``TOLERANCE_PX``) and within 0.15 px of the ball's true centre; until then a blob keeps
    its matte centre; the whole batch is one fit of the eight blobs."""
    rng = np.random.default_rng(32)
    eyes = [_eye(rng, 70, 200) for _ in range(2)]
    params = DetectorParams(warmup_frames=1)
    alone, later = [], []
    for wall, frame, _ in eyes:
        det = Detector(params)
        det.detect(wall)
        alone.append(det.find(frame))
        det = Detector(params)
        det.detect(wall)
        later.append((det, det.find(frame, fit_later=True)))
    matte = [blobs.centroid_px.copy() for _, blobs in later]
    fits = _counted(monkeypatch, detect, "disc_centres")
    fit_round_blobs(later)
    assert fits == [8], fits
    for (_, _, truth), one, (_, both), before in zip(eyes, alone, later, matte, strict=True):
        assert len(both) == len(truth) == 4
        np.testing.assert_allclose(both.centroid_px, one.centroid_px, atol=TOLERANCE_PX, rtol=0)
        assert not np.allclose(before, both.centroid_px, atol=1e-3)  # the fit moved them
        for centre in both.centroid_px:
            assert min(math.hypot(centre[0] - u, centre[1] - v) for u, v in truth) < 0.15


def test_the_pipeline_fits_a_pairs_two_eyes_in_one_batch(monkeypatch: pytest.MonkeyPatch) -> None:
    """A ball crossing a 320x240 view (under ``disc_max_px`` across): where a pair's two
    eyes are detected together, their round blobs are fitted in one call; where one eye was
    detected ahead (:meth:`Pipeline.run`), each eye's alone. Both give the same centroids."""
    ball = Ball(heading_deg=90.0, speed_mps=1.5, centre_m=(0.0, 0.1, 1.8), t_on_s=0.3, t_mid_s=0.6)
    scene = Scene(
        width_px=320, height_px=240, fps=30.0, duration_s=1.0, skew_s=0.5 / 30.0, color=True,
        balls=[ball],
    )  # fmt: skip
    pairs = list(Renderer(scene).frames())
    rig = CanonicalRig(0.06, 60.0, 320, 240)
    fits = _counted(monkeypatch, detect, "disc_centres")
    with Pipeline(PipelineParams(rig)) as pipe:
        together = [
            pipe.process(StereoPair(k, left, right)) for k, (left, right) in enumerate(pairs)
        ]
    per_pair = list(fits)
    del fits[:]
    with Pipeline(PipelineParams(rig)) as pipe:
        ahead = list(pipe.run([frame for pair in pairs for frame in pair]))
    assert pipe.detected_ahead > 0
    assert sum(n == 2 for n in per_pair) >= 10, per_pair  # both eyes' balls in one call
    assert max(per_pair) == 2 and max(fits) == 1
    assert len(together) == len(ahead)
    for a, b in zip(together, ahead, strict=True):
        for x, y in ((a.left, b.left), (a.right, b.right)):
            np.testing.assert_allclose(x.centroid_px, y.centroid_px, atol=TOLERANCE_PX, rtol=0)
