"""Recording what a source delivers, and replaying it back exactly."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np

from stereod.calibration import canonical, save
from stereod.frames import merged
from stereod.record import record
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.synth import Renderer, Scene, SyntheticDriver

from .conftest import stereod


def test_replay_reproduces_recorded_frames_and_timestamps(tmp_path: Path) -> None:
    scene = {"duration_s": 1.0, "fps": 10, "skew_s": 0.013, "width_px": 160, "height_px": 120}
    cal = tmp_path / "cal.json"
    save(canonical(0.06, 60.0, 160, 120), cal)
    counts = record(SyntheticDriver(scene), tmp_path / "rec", calibration=cal)
    assert counts == {"left": 10, "right": 10}
    truth = [f for pair in Renderer(Scene(**scene)).frames() for f in pair]
    with ReplayDriver({"path": tmp_path / "rec"}).open() as src:
        got = list(merged(src.left, src.right))
    assert len(got) == len(truth)
    for g in got:
        want = next(t for t in truth if t.eye is g.eye and t.seq == g.seq)
        assert g.t_ns == want.t_ns
        assert np.array_equal(g.image, want.image), f"{g.eye} frame {g.seq} differs"
    man = json.loads((tmp_path / "rec" / "recording.json").read_text())
    assert man["calibration"] == json.loads(cal.read_text())


def test_live_record_stops_after_seconds(tmp_path: Path) -> None:
    driver = SyntheticDriver(
        {"duration_s": 10.0, "fps": 20, "live": True, "width_px": 80, "height_px": 60}
    )
    counts = record(driver, tmp_path / "rec", seconds=0.5)
    assert 8 <= counts["left"] <= 11 and 8 <= counts["right"] <= 11
    rows = (tmp_path / "rec" / "left.csv").read_text().splitlines()[1:]
    t = [int(r.split(",")[0]) for r in rows]
    assert all(b > a for a, b in itertools.pairwise(t))


def test_record_and_devices_commands(tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        '[driver]\nname = "synthetic"\n[driver.options]\nduration_s = 0.5\nfps = 10\n'
        "width_px = 80\nheight_px = 60\n"
    )
    res = stereod("record", str(tmp_path / "rec"), "--config", str(cfg))
    assert res.returncode == 0, res.stderr
    assert "recorded 5 left and 5 right frames" in res.stdout
    res = stereod("devices", "--brief")
    assert res.returncode == 0 and res.stdout.strip(), res.stderr
