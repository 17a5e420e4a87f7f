"""The paper's Table I scenarios as synthetic scenes, and a replay of a recording through the
pipeline without the daemon around it (for benchmarks and accuracy tests).

Table I: a robot moves at constant speed on the floor in front of a Minoru (0.060 m baseline),
in eight directions. Here it is a 0.08 m sphere 0.25 m below the optical axes, crossing about
1.8 m in front of the rig, seen at 640x480 and 15 Hz with sensor noise, a slow lighting drift
and the right eye half a frame late (the worst case of two free-running eyes).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from stereod.frames import Frame, merged
from stereod.messages import ObjectsMessage
from stereod.pairing import Pairer
from stereod.pipeline import PairResult, Pipeline, PipelineParams
from stereod.recording import read_manifest

from .replay import ReplayDriver
from .synth import Ball, Renderer, Scene


@dataclass(frozen=True)
class TableRow:
    """One row of the paper's Table I: given and measured direction (deg) and speed (m/s)."""

    heading_deg: float
    speed_mps: float
    paper_heading_deg: float
    paper_speed_mps: float


TABLE_I = (
    TableRow(0, 0.9, 5, 0.7),
    TableRow(30, 0.7, 27, 0.6),
    TableRow(60, 0.7, 58, 0.6),
    TableRow(90, 0.4, 91, 0.4),
    TableRow(180, 0.9, 176, 0.8),
    TableRow(210, 0.7, 208, 0.6),
    TableRow(240, 0.7, 242, 0.7),
    TableRow(270, 0.4, 271, 0.4),
)


def table_one_scene(
    heading_deg: float,
    speed_mps: float,
    *,
    fps: float = 15.0,
    skew_frames: float = 0.5,
    noise_sigma: float = 2.0,
    drift: float = 0.05,
    seed: int = 0,
) -> Scene:
    """The scene of one Table I row: the sphere travels at most 1.4 m (at most 2 s) through
    (0, 0.25, 1.8) m, after a 1 s empty lead-in for the background."""
    travel_s = min(2.0, 1.4 / speed_mps)
    lead_in = 1.0
    ball = Ball(
        centre_m=(0.0, 0.25, 1.8),
        heading_deg=heading_deg,
        speed_mps=speed_mps,
        radius_m=0.08,
        t_on_s=lead_in,
        t_off_s=lead_in + travel_s,
        t_mid_s=lead_in + travel_s / 2,
    )
    return Scene(
        fps=fps,
        duration_s=lead_in + travel_s + 0.3,
        skew_s=skew_frames / fps,
        noise_sigma=noise_sigma,
        drift=drift,
        drift_period_s=8.0,
        seed=seed,
        balls=[ball],
    )


def run_pipeline(
    frames: Iterable[Frame], params: PipelineParams, tolerance_ns: int
) -> list[PairResult]:
    """Pair ``frames`` (both eyes, each eye in order) and run every pair through a fresh
    pipeline, as the daemon does minus threads and Zenoh."""
    pipe = Pipeline(params, utc_offset_ns=0)
    pairer = Pairer(tolerance_ns=tolerance_ns)
    out: list[PairResult] = []
    for frame in frames:
        out.extend(pipe.process(p) for p in pairer.push(frame))
    out.extend(pipe.process(p) for p in pairer.flush())
    pipe.close()
    return out


def process_scene(scene: Scene, params: PipelineParams) -> list[PairResult]:
    """Render ``scene`` in memory and run it through the pipeline."""
    frames = (f for pair in Renderer(scene).frames() for f in pair)
    return run_pipeline(frames, params, int(0.75e9 / scene.fps))


def replay_through_pipeline(recording: Path, params: PipelineParams) -> list[ObjectsMessage]:
    """Every objects message the pipeline makes from a recording, in order (no Zenoh)."""
    man = read_manifest(recording)
    if (man.width, man.height) != (params.rig.width_px, params.rig.height_px):
        raise ValueError("the rig's image size must match the recording")
    with ReplayDriver({"path": recording}).open() as src:
        results = run_pipeline(merged(src.left, src.right), params, int(0.75e9 / (man.fps or 15.0)))
    return [r.message for r in results]
