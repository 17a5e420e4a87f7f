"""``stereod plot``: the data it draws against closed forms, and a real run drawn to a PNG."""

from __future__ import annotations

import json
import math
import os
import stat
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stereod.view.plot import (
    DPI,
    FIGSIZE_IN,
    Run,
    TrackSeries,
    band,
    display_deg,
    draw,
    eq21,
    read_run,
    read_truth,
    speed_heading,
    truth_from_scene,
    unwrap_deg,
)
from stereod_fakes.synth import Ball, Scene
from tests.conftest import ROOT, stereod


def _track(raw: np.ndarray, speed: np.ndarray, sigma: np.ndarray) -> TrackSeries:
    n = len(speed)
    return TrackSeries(
        track_id=1,
        t_s=np.arange(n) * 0.1,
        position_m=np.zeros((n, 3)),
        valid=np.ones(n, bool),
        heading_valid=np.ones(n, bool),
        speed_mps=speed,
        speed_sigma_mps=sigma,
        heading_deg=np.zeros(n),
        heading_sigma_deg=sigma,
        raw_velocity_mps=raw,
    )


def test_eq21_series_is_speed_and_heading_of_the_raw_velocity() -> None:
    """Eq. 21's velocity v = s (sin a, 0, cos a) gives back speed s (eq. 22) and heading a
    (eq. 23); the states before the track spans the time base have none."""
    speeds = np.array([0.5, 0.7, 1.2, 0.3])
    headings = np.array([0.0, 60.0, 181.5, 300.0])
    raw = np.stack(
        [
            speeds * np.sin(np.radians(headings)),
            speeds * 0.0,
            speeds * np.cos(np.radians(headings)),
        ],
        axis=1,
    )
    raw = np.vstack([np.full((2, 3), np.nan), raw])
    t, s, h = eq21(_track(raw, np.ones(6), np.ones(6)))
    assert np.allclose(t, np.arange(2, 6) * 0.1)
    assert np.allclose(s, speeds)
    assert np.allclose(h, headings)
    # vy counts in the speed (3D), not in the heading.
    s3, h3 = speed_heading(np.array([[3.0, 4.0, 0.0]]))
    assert s3[0] == pytest.approx(5.0) and h3[0] == pytest.approx(90.0)


def test_sigma_band_is_value_plus_minus_sigma() -> None:
    value = np.array([0.7, 0.71, 0.69])
    sigma = np.array([0.05, 0.02, np.nan])
    lo, hi = band(value, sigma)
    assert np.allclose(lo[:2], [0.65, 0.69]) and np.allclose(hi[:2], [0.75, 0.73])
    assert math.isnan(lo[2]) and math.isnan(hi[2])


def test_headings_unwrap_near_the_truth() -> None:
    h = np.array([350.0, 355.0, 2.0, 8.0])
    assert np.allclose(unwrap_deg(h), [350, 355, 362, 368])
    assert np.allclose(unwrap_deg(h, near_deg=0.0), [-10, -5, 2, 8])
    # Drawn around their circular mean in [0, 360): a track heading 250 stays at 250.
    assert np.allclose(display_deg(np.array([-110.0, -108.0])), [250, 252])
    assert np.allclose(display_deg(np.array([2.0, 8.0, 350.0])), [2, 8, -10])


def test_truth_csv_straight_line(tmp_path: Path) -> None:
    """A straight line at 0.8 m/s, heading 210 deg: the truth's speed and heading come out
    exactly, from its positions alone or from its velocity columns."""
    t0 = 5_000_000_000
    a = math.radians(210.0)
    v = 0.8 * np.array([math.sin(a), 0.0, math.cos(a)])
    rows = ["object,t_ns,x_m,y_m,z_m,extra"]
    rows_v = ["object,t_ns,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps"]
    for k in range(20):
        t_s = 1.0 + k / 15
        p = np.array([0.5, 0.1, 2.5]) + v * t_s
        rows.append(f"ball,{t0 + round(t_s * 1e9)},{p[0]},{p[1]},{p[2]},zzz")
        rows_v.append(f"ball,{t0 + round(t_s * 1e9)},{p[0]},{p[1]},{p[2]},{v[0]},{v[1]},{v[2]}")
    for name, lines in (("truth.csv", rows), ("truth_v.csv", rows_v)):
        (tmp_path / name).write_text("\n".join(lines) + "\n")
        (truth,) = read_truth(tmp_path / name, t0)
        assert truth.name == "ball"
        assert truth.t_s[0] == pytest.approx(1.0) and len(truth.t_s) == 20
        s, h = speed_heading(truth.velocity_mps)
        assert np.allclose(s, 0.8, atol=1e-6) and np.allclose(h, 210.0, atol=1e-4)
    (tmp_path / "bad.csv").write_text("object,t_ns,x_m\nball,1,2\n")
    with pytest.raises(Exception, match=r"lacks column\(s\) y_m, z_m"):
        read_truth(tmp_path / "bad.csv", t0)


def test_truth_json_is_the_scene_balls_at_frame_times(tmp_path: Path) -> None:
    ball = Ball(heading_deg=100.0, speed_mps=0.5, t_on_s=1.0, t_off_s=2.0, t_mid_s=1.5)
    scene = Scene(duration_s=3.0, fps=10.0, balls=[ball], t0_ns=7_000_000_000)
    path = tmp_path / "truth.json"
    path.write_text(scene.model_dump_json())
    (truth,) = truth_from_scene(path, t0_ns=scene.t0_ns)
    assert np.allclose(truth.t_s, np.arange(10, 21) / 10.0)
    assert np.allclose(truth.position_m, ball.position_m(truth.t_s))
    s, h = speed_heading(truth.velocity_mps)
    assert np.allclose(s, 0.5) and np.allclose(h, 100.0)


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", "not a PNG"
    w, h = struct.unpack(">II", data[16:24])
    return w, h


@pytest.mark.slow
def test_plot_of_a_real_run(tmp_path: Path) -> None:
    """synth -> replay --jsonl -> plot: a PNG of the figure's size, and the run's track at the
    scene's heading and speed in the summary."""
    rec = tmp_path / "rec"
    r = stereod("synth", str(rec), "--ball", "heading=60,speed=0.7,z=1.8", "--size", "320x240")
    assert r.returncode == 0, r.stderr
    run = tmp_path / "run.jsonl"
    r = stereod("replay", str(rec), "--rate", "0", "--jsonl", str(run), "-q")
    assert r.returncode == 0, r.stderr
    fig = tmp_path / "fig.png"
    r = stereod("plot", str(run), "--truth", str(rec / "truth.json"), "-o", str(fig))
    assert r.returncode == 0, r.stderr
    assert _png_size(fig) == (int(FIGSIZE_IN[0] * DPI), int(FIGSIZE_IN[1] * DPI))
    line = next(x for x in r.stdout.splitlines() if "valid states" in x)
    speed = float(line.split("speed ")[1].split()[0])
    heading = float(line.split("heading ")[1].split()[0])
    assert abs(speed - 0.7) < 0.05 and abs(heading - 60.0) < 3.0, line


def test_plot_without_matplotlib_says_how_to_install_it(tmp_path: Path) -> None:
    run = tmp_path / "run.jsonl"
    run.write_text(
        (ROOT / "tests" / "golden" / "objects_example.json").read_text().replace("\n", "")
    )
    code = (
        "import sys; sys.modules['matplotlib'] = None; sys.modules['matplotlib.figure'] = None; "
        "from stereod.cli import main; sys.exit(main(sys.argv[1:]))"
    )
    r = subprocess.run(
        [sys.executable, "-c", code, "plot", str(run), "-o", str(tmp_path / "f.png")],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert r.returncode == 69
    assert r.stderr == "stereod: stereod plot needs matplotlib: pip install 'stereod[plot]'\n"
    assert not (tmp_path / "f.png").exists()


def test_a_truth_that_does_not_meet_the_run_in_time_is_refused(tmp_path: Path) -> None:
    """A truth from another run lies far off on this run's clock: one line naming the file and
    both spans, exit 65, and no figure; the same truth moved onto the run's clock is drawn."""
    run = _golden_run(tmp_path)
    t0 = read_run(run).t0_ns
    fig = tmp_path / "fig.png"
    for offset_s, code in ((1000.0, 65), (0.0, 0)):
        truth = tmp_path / f"truth_{int(offset_s)}.csv"
        rows = ["object,t_ns,x_m,y_m,z_m"]
        rows += [
            f"ball,{t0 + round((offset_s + k / 15) * 1e9)},0.1,0.0,{1.5 + k / 30}" for k in range(5)
        ]
        truth.write_text("\n".join(rows) + "\n")
        r = stereod("plot", str(run), "--truth", str(truth), "-o", str(fig))
        assert r.returncode == code, r.stderr
        if code:
            assert r.stderr.count("\n") == 1 and "do not overlap the run's" in r.stderr
            assert f"{truth}: its times (1000.0 to 1000.3 s" in r.stderr, r.stderr
            assert not fig.exists()
    assert fig.exists()


def test_a_run_whose_values_no_axis_can_hold_is_one_line_and_exit_65(tmp_path: Path) -> None:
    """A position of 1e308 m is no position: a run of them overflowed the axes' arithmetic
    inside matplotlib (an internal error, exit 70), and one alone draws a figure of nothing.
    The file, line, track and field are named, and no figure is made; 1e6 m, the bound, is
    still drawn."""
    import json

    msg = json.loads((ROOT / "tests" / "golden" / "objects_example.json").read_text())
    fig = tmp_path / "fig.png"
    for value, code in ((1e308, 65), (-1e6, 0)):
        msg["objects"][0]["position_m"] = [value] * 3
        run = tmp_path / "run.jsonl"
        run.write_text("\n" + json.dumps(msg) + "\n")
        r = stereod("plot", str(run), "-o", str(fig))
        assert r.returncode == code, r.stderr
        if code:
            track = msg["objects"][0]["track_id"]
            assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
            assert f"{run}:2: track {track}'s position_m holds 1e+308, out of range" in r.stderr
            assert not fig.exists()
    assert fig.exists()


def _golden_run(tmp_path: Path) -> Path:
    run = tmp_path / "run.jsonl"
    line = (ROOT / "tests" / "golden" / "objects_example.json").read_text().replace("\n", "")
    run.write_text(line + "\n")
    return run


def test_a_figure_format_matplotlib_cannot_write_is_refused_up_front(tmp_path: Path) -> None:
    """-o out.xyz or x.jsonl: one line listing the suffixes that work, exit 64, nothing written
    (it used to end in an internal error after the work)."""
    run = _golden_run(tmp_path)
    for name in ("out.xyz", "x.jsonl"):
        r = stereod("plot", str(run), "-o", str(tmp_path / name))
        assert r.returncode == 64, r.stderr
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
        suffix = name.rsplit(".", 1)[1]
        assert f"{tmp_path / name}: .{suffix} is not a figure format" in r.stderr, r.stderr
        assert ".pdf, " in r.stderr and ".png, " in r.stderr and ".svg, " in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.jsonl"]


def test_a_figure_without_suffix_is_a_png_and_said_by_its_name(tmp_path: Path) -> None:
    """-o pout writes pout.png, and says so (it used to say 'wrote pout')."""
    run = _golden_run(tmp_path)
    r = stereod("plot", str(run), "-o", str(tmp_path / "pout"))
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == f"wrote {tmp_path / 'pout.png'}"
    assert _png_size(tmp_path / "pout.png") == (int(FIGSIZE_IN[0] * DPI), int(FIGSIZE_IN[1] * DPI))
    assert not (tmp_path / "pout").exists()


def test_a_figure_follows_the_rule_of_every_output(tmp_path: Path) -> None:
    """Through a symbolic link to the file it names (the link kept); into /dev/null as it is
    (no /dev/null.png, no regular file in its place); an earlier figure stays until the new
    one is whole."""
    run = _golden_run(tmp_path)
    target = tmp_path / "figs" / "run.png"
    target.parent.mkdir()
    target.write_bytes(b"earlier")
    link = tmp_path / "latest.png"
    link.symlink_to(target)
    r = stereod("plot", str(run), "-o", str(link))
    assert r.returncode == 0, r.stderr
    assert link.is_symlink() and _png_size(target)[0] == int(FIGSIZE_IN[0] * DPI)
    r = stereod("plot", str(run), "-o", "/dev/null")
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-1] == "wrote /dev/null"
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert sorted(p.name for p in target.parent.iterdir()) == ["run.png"]


def test_a_truth_or_run_that_cannot_be_read_is_one_line_and_exit_66(tmp_path: Path) -> None:
    """A folder where the truth.json of a recording, or the run, is expected stands for any
    file the OS will not read: one line naming it and the OS's reason (the truth.json case
    used to be an internal error)."""
    run = _golden_run(tmp_path)
    folder = tmp_path / "truth.json"
    folder.mkdir()
    for args in (["--truth", str(folder)], []):
        given = str(run) if args else str(folder)
        r = stereod("plot", given, *args, "-o", str(tmp_path / "fig.png"))
        assert r.returncode == 66, r.stderr
        what = "truth" if args else "run"
        assert r.stderr == f"stereod: {folder}: cannot read the {what} file: Is a directory\n"
    assert not (tmp_path / "fig.png").exists()


def test_a_title_is_drawn_as_written_not_as_a_formula(tmp_path: Path) -> None:
    """``--title '$x^{2$'`` (a dollar sign, unbalanced braces) is drawn literally: it was
    parsed as mathtext and failed with an internal error (70)."""
    run = _golden_run(tmp_path)
    fig = tmp_path / "fig.png"
    r = stereod("plot", str(run), "-o", str(fig), "--title", "$x^{2$ costs $5")
    assert r.returncode == 0, r.stderr
    assert _png_size(fig) == (int(FIGSIZE_IN[0] * DPI), int(FIGSIZE_IN[1] * DPI))


def _moving(track_id: int, states: list[str], heading_deg: float) -> TrackSeries:
    n = len(states)
    t = np.arange(n) * 0.1
    h = math.radians(heading_deg)
    pos = np.stack([np.sin(h) * t, np.zeros(n), 1.0 + np.cos(h) * t], axis=1)
    pos[0] += (0.3, 0.0, -0.2)  # a tentative first guess off the path: the "hook"
    raw = np.tile([math.sin(h), 0.0, math.cos(h)], (n, 1))
    return TrackSeries(
        track_id=track_id,
        t_s=t,
        position_m=pos,
        valid=np.ones(n, bool),
        heading_valid=np.ones(n, bool),
        speed_mps=np.ones(n),
        speed_sigma_mps=np.full(n, 0.1),
        heading_deg=np.full(n, heading_deg),
        heading_sigma_deg=np.full(n, 2.0),
        raw_velocity_mps=raw,
        state=np.array(states),
    )


def test_coasting_states_have_no_eq21_point_and_tentative_ones_no_path() -> None:
    """A coasting state repeats the last eq. 21 value without a measurement: not drawn as one;
    a tentative state (the track's unconfirmed start) is not drawn into its path."""
    states = ["tentative", "confirmed", "confirmed", "coasting", "coasting", "confirmed"]
    tr = _moving(1, states, 30.0)
    t, _, _ = eq21(tr)
    assert np.allclose(t, [0.0, 0.1, 0.2, 0.5])
    path = tr.trajectory_m()
    assert len(path) == 5 and np.allclose(path, tr.position_m[1:])


def test_read_run_keeps_each_states_lifecycle(tmp_path: Path) -> None:
    run = read_run(_golden_run(tmp_path))
    (tr,) = run.tracks
    assert tr.state is not None and list(tr.state) == ["tentative"]
    assert len(tr.trajectory_m()) == 0


def test_legends_never_cover_the_data() -> None:
    """Every legend stands outside every panel's plotting area."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    states = ["tentative"] + ["confirmed"] * 30
    run = Run(0, [_moving(k, states, 40.0 * k) for k in range(1, 6)])
    fig = draw(run, [], title="legends")
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    assert len(legends) == 3
    for legend in legends:
        box = legend.get_window_extent(renderer)
        for ax in fig.axes:
            assert not box.overlaps(ax.get_window_extent(renderer)), ax.get_title()


def test_a_folder_as_the_figure_is_refused_like_every_output(tmp_path: Path) -> None:
    """``-o DIR`` (an existing folder, with or without a slash) is one line and exit 73, and
    nothing is written: it wrote DIR.png beside the folder (``-o /tmp`` wrote /tmp.png)."""
    run = _golden_run(tmp_path)
    folder = tmp_path / "figs"
    folder.mkdir()
    for given in (str(folder), f"{folder}/"):
        r = stereod("plot", str(run), "-o", given)
        assert r.returncode == 73, r.stderr
        assert r.stderr == f"stereod: {folder}: is a directory; give the name of a file in it\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figs", "run.jsonl"]
    assert list(folder.iterdir()) == []


def test_a_binary_file_as_the_run_or_truth_says_what_to_give(tmp_path: Path) -> None:
    """A PNG given as the run (or the truth) is one line and exit 65 naming it and what to give
    instead (it was Python's own 'utf-8' codec message)."""
    run = _golden_run(tmp_path)
    png = tmp_path / "fig.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    for args, what in (([str(png)], "--jsonl"), ([str(run), "--truth", str(png)], "truth")):
        r = stereod("plot", *args, "-o", str(tmp_path / "out.png"))
        assert r.returncode == 65, r.stderr
        assert r.stderr.count("\n") == 1 and "codec" not in r.stderr, r.stderr
        assert r.stderr.startswith(f"stereod: {png}: not a text file (byte 0 is not UTF-8)")
        assert what in r.stderr
    assert not (tmp_path / "out.png").exists()


@pytest.mark.parametrize(
    ("field", "value"),
    [("speed_sigma_mps", 1e308), ("position_sigma_m", [1e300, 0.01, 0.01])],
)
def test_a_sigma_beyond_the_axes_is_refused_naming_it(
    tmp_path: Path, field: str, value: object
) -> None:
    """A sigma of 1e308 made the band's axis limits overflow in matplotlib (an internal error,
    70); it is refused as an out-of-range position is: one line naming the field, exit 65."""
    msg = json.loads((ROOT / "tests" / "golden" / "objects_example.json").read_text())
    msg["objects"][0][field] = value
    run = tmp_path / "run.jsonl"
    run.write_text(json.dumps(msg) + "\n")
    r = stereod("plot", str(run), "-o", str(tmp_path / "fig.png"))
    assert r.returncode == 65, r.stderr
    assert r.stderr.count("\n") == 1 and f"'s {field} holds 1e+30" in r.stderr, r.stderr
    assert not (tmp_path / "fig.png").exists()
