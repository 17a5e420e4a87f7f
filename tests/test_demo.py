"""The demo end to end (as fast as possible): it must report the truth it rendered."""

from __future__ import annotations

import pytest

from stereod.demo import run_demo
from stereod.motion import angle_diff_deg


def test_angle_difference_wraps() -> None:
    assert angle_diff_deg(359.0, 1.0) == pytest.approx(-2.0)
    assert angle_diff_deg(1.0, 359.0) == pytest.approx(2.0)
    assert angle_diff_deg(180.0, 0.0) == pytest.approx(180.0)


@pytest.mark.slow
def test_demo_measures_heading_and_speed(capsys: pytest.CaptureFixture[str]) -> None:
    assert run_demo(rate=0.0, heading_deg=210.0, speed_mps=0.7) == 0
    out = capsys.readouterr().out
    assert "within the paper's errors" in out
    error_line = next(line for line in out.splitlines() if line.startswith("error"))
    dh, ds = (float(v) for v in error_line.split()[1:])
    assert abs(dh) < 1.0 and abs(ds) < 0.02, error_line
