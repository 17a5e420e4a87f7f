"""A pair where nothing moves: the stages after detection are skipped, and what comes out is
what the full path gives, to the byte on the wire."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereod.bus.messages import dump_objects, objects_message
from stereod.pipeline import PairResult, Pipeline, PipelineParams
from stereod.sources.frames import StereoPair
from stereod_fakes.synth import Ball, Renderer, Scene


def wire(result: PairResult) -> tuple[bytes, list[tuple[int, bytes]]]:
    """The ``objects`` payload and per-track payloads the daemon would publish for a result."""
    msg = objects_message(
        result, rig="rig", geometry="canonical", calibration_id=None, utc_offset_ns=7
    )
    return dump_objects(msg)


def test_a_pair_where_nothing_moves_skips_the_stages_after_detection_and_says_the_same(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Still frames, then a ball crossing, then still frames again, through two pipelines: one
    as it is, one whose tracker always claims a live track, so that every stage runs on
    every pair. Each pair's messages agree to the byte (the latency fields, wall-clock
    measurements, taken from the full path), and so do the backgrounds at the end; the
    pairs with no blob in either eye and no live track before them spent nothing after
    detection."""
    ball = Ball(heading_deg=60, speed_mps=0.7, t_on_s=1.0, t_off_s=1.8)
    scene = Scene(width_px=320, height_px=240, duration_s=3.5, balls=[ball])
    params = PipelineParams(scene.rig)
    pairs = [StereoPair(k, left, right) for k, (left, right) in enumerate(Renderer(scene).frames())]
    skipped = tracked = 0
    with Pipeline(params) as pipe, Pipeline(params) as full:
        monkeypatch.setattr(full.tracker, "live_ids", lambda: [0])
        for pair in pairs:
            alive = bool(pipe.tracker.live_ids())
            got, want = pipe.process(pair), full.process(pair)
            assert wire(dataclasses.replace(got, timings=want.timings)) == wire(want), pair.seq
            assert got.ended == want.ended and got.t_ns == want.t_ns
            assert len(got.left) == len(want.left) and len(got.right) == len(want.right)
            if not (alive or len(got.left) or len(got.right)):
                skipped += 1
                assert got.timings.geometry_ms == 0.0 and got.timings.track_ms == 0.0, pair.seq
            tracked += bool(got.tracks)
        for a, b in ((pipe.left, full.left), (pipe.right, full.right)):
            assert a.background is not None and b.background is not None
            assert np.array_equal(a.background, b.background)
    assert tracked > 5, "the ball was never tracked: the scene tests nothing"
    assert skipped > len(pairs) / 2, (skipped, len(pairs))
