"""Scenes through the public pipeline API, shared by the tests (not a test module itself)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from stereod import Frame, PairResult, Pipeline, PipelineParams
from stereod.sources.frames import merged
from stereod.sources.recording import read_manifest
from stereod.tracking.types import TrackLifecycle, TrackState
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.synth import Renderer, Scene


def scene_frames(scene: Scene) -> Iterator[Frame]:
    """Both eyes' frames of a rendered scene, in memory."""
    for left, right in Renderer(scene).frames():
        yield left
        yield right


def run_scene(scene: Scene, params: PipelineParams) -> list[PairResult]:
    """Every pair's result for a scene rendered in memory."""
    with Pipeline(params) as pipe:
        return list(pipe.run(scene_frames(scene), int(0.75e9 / scene.fps)))


def run_recording(recording: Path, params: PipelineParams) -> list[PairResult]:
    """Every pair's result for a recording, read by the replay driver."""
    man = read_manifest(recording)
    with ReplayDriver({"path": recording}).open() as src, Pipeline(params) as pipe:
        frames = merged(src.left, src.right)
        return list(pipe.run(frames, int(0.75e9 / (man.fps or 15.0))))


def states(
    results: list[PairResult], *, confirmed: bool = False, valid: bool = False
) -> list[TrackState]:
    """Every track state of the results, optionally only confirmed or with a valid velocity."""
    return [
        s
        for r in results
        for s in r.tracks
        if (not confirmed or s.lifecycle in (TrackLifecycle.CONFIRMED, TrackLifecycle.STATIONARY))
        and (not valid or s.velocity_valid)
    ]


def sigma(s: TrackState) -> np.ndarray:
    """(3,) one-sigma position error (m)."""
    return np.sqrt(np.diag(s.position_cov_m2))
