"""Table I scenarios (worst case: half a frame of skew) against the accuracy targets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereod import PipelineParams
from stereod.tracking.motion import angle_diff_deg, circular_median_deg
from stereod_fakes.scenarios import TABLE_I, table_one_scene
from stereod_fakes.synth import write_scene
from tests.scenes import run_recording, states

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("row", [TABLE_I[1], TABLE_I[7]], ids=["30deg", "270deg"])
def test_table_one_motion_within_targets(row, tmp_path: Path) -> None:
    scene = table_one_scene(row.heading_deg, row.speed_mps)
    rec = write_scene(scene, tmp_path / "rec")
    valid = states(run_recording(rec, PipelineParams(scene.rig)), confirmed=True, valid=True)
    assert len(valid) >= 8
    heading = circular_median_deg([o.heading_deg for o in valid])
    speed = float(np.median([o.speed_mps for o in valid]))
    assert abs(angle_diff_deg(heading, row.heading_deg)) <= 1.0, f"heading {heading:.2f} deg"
    assert abs(speed - row.speed_mps) <= 0.03 * row.speed_mps, f"speed {speed:.3f} m/s"


def test_without_compensation_half_frame_skew_biases_depth(tmp_path: Path) -> None:
    """The same 30 deg motion with compensation off: half a frame of skew shifts the later eye's
    blob along the motion, a disparity error that biases depth by many times what is left
    with compensation on."""
    row = TABLE_I[1]
    scene = table_one_scene(row.heading_deg, row.speed_mps)
    rec = write_scene(scene, tmp_path / "rec")
    ball = scene.balls[0]

    def depth_error(compensate: bool) -> float:
        results = run_recording(rec, PipelineParams(scene.rig, skew_compensation=compensate))
        errs = [
            abs(s.position_m[2] - ball.position_m((s.t_ns - scene.t0_ns) / 1e9)[2])
            for s in states(results, confirmed=True)
        ]
        return float(np.median(errs))

    on, off = depth_error(True), depth_error(False)
    assert off > 0.05 and off > 5 * on, f"depth error {off:.3f} m off, {on:.3f} m on"
