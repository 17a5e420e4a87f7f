"""A ball's disc fit started from its fit in the eye's previous frame: the same centres in
fewer steps."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest

from stereod.pipeline import Pipeline, PipelineParams
from stereod.sources.frames import StereoPair
from stereod.vision import detect, disc
from stereod.vision.disc import Candidate, disc_fits, warm_start
from stereod.vision.geometry.stereo import CanonicalRig
from stereod_fakes.synth import Ball, Renderer, Scene

Start = tuple[float, float, float] | None


def test_warm_start_moves_the_last_fit_with_its_blob() -> None:
    """The start is the blob's centre plus the nearest previous blob's fit offset, at the
    previous fit's radius ratio; no start without a previous blob within the gate, where
    the previous fit sat more than half a pixel off its blob, or where the blob's size
    changed by more than 5 %."""
    r = math.sqrt(100 / math.pi)
    last = [(10.0, 10.0, 10.1, 9.8, 1.2 * r, r), (40.0, 10.0, 40.2, 10.0, r, r)]
    start = warm_start((13.0, 11.0), 100, last, 8.0)
    assert start == pytest.approx((13.1, 10.8, r * 1.2))
    assert warm_start((25.0, 10.0), 100, last, 8.0) is None
    far = [(10.0, 10.0, 10.6, 10.0, r, r)]
    assert warm_start((10.0, 10.0), 100, far, 8.0) is None
    assert warm_start((13.0, 11.0), 112, last, 8.0) is None  # 5.8 % larger a radius


def test_a_followed_ball_is_fitted_as_from_cold_in_fewer_steps(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A ball crossing a 320x240 view, both eyes: every fit after the ball's first frame
    starts from its last one, lands within 0.04 px of where the fit started from the blob's
    matte centre lands (and is refused where that one is), and the fits take at most half
    the Gauss-Newton steps that those take."""
    ball = Ball(heading_deg=60.0, speed_mps=0.7, centre_m=(0.0, 0.1, 1.8), t_on_s=0.2, t_mid_s=0.8)
    scene = Scene(width_px=320, height_px=240, fps=30.0, duration_s=1.4, color=True, balls=[ball])
    batches: list[tuple[list[Candidate], list[Start]]] = []
    real = detect.disc_centres

    def recorded(
        blobs: Sequence[Candidate], starts: Sequence[Start] | None = None, *rest: object
    ) -> object:
        batches.append((list(blobs), list(starts or [None] * len(blobs))))
        return real(blobs, starts, *rest)  # type: ignore[arg-type]

    monkeypatch.setattr(detect, "disc_centres", recorded)
    rig = CanonicalRig(0.06, 60.0, 320, 240)
    with Pipeline(PipelineParams(rig)) as pipe:
        for k, (left, right) in enumerate(Renderer(scene).frames()):
            pipe.process(StereoPair(k, left, right))
    monkeypatch.undo()
    steps = [0]
    real_coverage = disc.coverage

    def counted(*args: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        steps[0] += 1
        return real_coverage(*args)

    monkeypatch.setattr(disc, "coverage", counted)
    warm_steps = cold_steps = fitted = started = 0
    for blobs, starts in batches:
        for blob, start in zip(blobs, starts, strict=True):
            steps[0] = 0
            (cold,) = disc_fits([blob])
            cold_steps += steps[0]
            steps[0] = 0
            (warm,) = disc_fits([blob], [start])
            warm_steps += steps[0]
            started += start is not None
            assert (warm is None) == (cold is None)
            if warm is not None and cold is not None:
                assert math.hypot(warm[0] - cold[0], warm[1] - cold[1]) < 0.04
                fitted += 1
    assert fitted >= 30 and started >= fitted - 4, (fitted, started)
    assert warm_steps <= cold_steps / 2, (warm_steps, cold_steps)
