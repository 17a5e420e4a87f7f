"""Accuracy on the paper's Table I scenarios, side by side with the paper's own figures.

Renders the eight Table I motions (fakes/scenarios.py: Minoru-like rig, 0.060 m baseline,
640x480 at 15 Hz, sensor noise, slow lighting drift, right eye half a frame late), replays each
recording through the pipeline three ways and prints one table:

- tracker: Kalman tracker with skew compensation (what the daemon publishes);
- eq. 21: the paper's finite difference over the time base (``raw_velocity_mps``), same run;
- no comp.: the tracker with skew compensation off.

Each figure is the median over the track's valid estimates. Position error is the median
distance of the published position from the truth at the message's instant, beside eq. 12's
one-pixel depth error at that range. Writes the table as Markdown and a PNG figure (top view of
true and measured trajectories; speed against time). Targets with compensation on: heading
error <= 1 deg and speed error <= 3 % in every scenario.

Usage: ``python benchmarks/accuracy.py [--out DIR] [--seed N]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereod.frames import merged
from stereod.messages import ObjectsMessage, objects_message
from stereod.motion import angle_diff_deg, circular_median_deg
from stereod.pipeline import Pipeline, PipelineParams
from stereod.recording import read_manifest
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.scenarios import TABLE_I, TableRow, table_one_scene
from stereod_fakes.synth import Scene, write_scene


def replay_through_pipeline(recording: Path, params: PipelineParams) -> list[ObjectsMessage]:
    """Every objects message the pipeline makes from a recording, in order (no Zenoh)."""
    man = read_manifest(recording)
    with ReplayDriver({"path": recording}).open() as src, Pipeline(params) as pipe:
        results = list(pipe.run(merged(src.left, src.right), int(0.75e9 / (man.fps or 15.0))))
    rig = params.rig
    return [
        objects_message(r, rig="bench", geometry=rig.geometry, calibration_id=None, utc_offset_ns=0)
        for r in results
    ]


HEADING_TARGET_DEG = 1.0
SPEED_TARGET = 0.03


@dataclass
class Run:
    """Summary of one scenario run: medians over valid estimates and the series for plots."""

    heading_deg: float
    speed_mps: float
    raw_heading_deg: float
    raw_speed_mps: float
    position_err_m: float
    eq12_bound_m: float
    t_s: np.ndarray
    positions_m: np.ndarray
    speeds_mps: np.ndarray


def summarise(scene: Scene, messages: list[ObjectsMessage]) -> Run | None:
    """Medians over the valid estimates; ``None`` when no track lived long enough to have one."""
    ball = scene.balls[0]
    states = [(m.t_ns, o) for m in messages for o in m.objects if o.state == "confirmed"]
    valid = [o for _, o in states if o.velocity_valid]
    raw = np.array([o.raw_velocity_mps for o in valid if o.raw_velocity_mps is not None])
    if not valid or raw.size == 0:
        return None
    raw_v = np.median(raw, axis=0)
    t = np.array([(t - scene.t0_ns) / 1e9 for t, _ in states])
    pos = np.array([o.position_m for _, o in states])
    truth = ball.position_m(t)
    return Run(
        heading_deg=circular_median_deg([o.heading_deg for o in valid]),
        speed_mps=float(np.median([o.speed_mps for o in valid])),
        raw_heading_deg=math.degrees(math.atan2(raw_v[0], raw_v[2])) % 360.0,
        raw_speed_mps=float(np.linalg.norm(raw_v)),
        position_err_m=float(np.median(np.linalg.norm(pos - truth, axis=1))),
        eq12_bound_m=float(np.median(scene.rig.depth_error_one_px_m(truth[:, 2]))),
        t_s=t,
        positions_m=pos,
        speeds_mps=np.array([o.speed_mps if o.velocity_valid else np.nan for _, o in states]),
    )


def run_scenario(row: TableRow, workdir: Path, seed: int) -> tuple[Scene, Run, Run | None]:
    scene = table_one_scene(row.heading_deg, row.speed_mps, seed=seed)
    rec = write_scene(scene, workdir / f"h{row.heading_deg:03.0f}")
    params = PipelineParams(scene.rig)
    on = summarise(scene, replay_through_pipeline(rec, params))
    if on is None:
        raise RuntimeError(f"heading {row.heading_deg}: no valid velocity with compensation on")
    off_params = PipelineParams(scene.rig, skew_compensation=False)
    off = summarise(scene, replay_through_pipeline(rec, off_params))
    return scene, on, off


def _deg(h: float) -> str:
    return f"{round(h, 2) % 360:.2f}"


def table(results: list[tuple[TableRow, Scene, Run, Run | None]]) -> tuple[str, bool]:
    head = (
        "| given heading (deg) | given speed (m/s) | paper heading | paper speed "
        "| tracker heading | tracker speed | eq. 21 heading | eq. 21 speed "
        "| no comp. heading | no comp. speed | position error (cm) | eq. 12 bound (cm) |"
    )
    lines = [head, "|" + "---|" * 12]
    ok = True
    for row, _, on, off in results:
        dh = angle_diff_deg(on.heading_deg, row.heading_deg)
        ds = (on.speed_mps - row.speed_mps) / row.speed_mps
        ok &= abs(dh) <= HEADING_TARGET_DEG and abs(ds) <= SPEED_TARGET
        no_comp = (
            f"{_deg(off.heading_deg)} | {off.speed_mps:.3f}" if off else "track lost | track lost"
        )
        lines.append(
            f"| {row.heading_deg:.0f} | {row.speed_mps:.1f} | {row.paper_heading_deg:.0f} "
            f"| {row.paper_speed_mps:.1f} | {_deg(on.heading_deg)} | {on.speed_mps:.3f} "
            f"| {_deg(on.raw_heading_deg)} | {on.raw_speed_mps:.3f} | {no_comp} "
            f"| {on.position_err_m * 100:.2f} | {on.eq12_bound_m * 100:.1f} |"
        )
    errs_h = [abs(angle_diff_deg(on.heading_deg, r.heading_deg)) for r, _, on, _ in results]
    errs_s = [abs(on.speed_mps - r.speed_mps) / r.speed_mps for r, _, on, _ in results]
    paper_h = [abs(angle_diff_deg(r.paper_heading_deg, r.heading_deg)) for r in TABLE_I]
    paper_s = [abs(r.paper_speed_mps - r.speed_mps) / r.speed_mps for r in TABLE_I]
    lines.append("")
    lines.append(
        f"Largest error, tracker with skew compensation: heading {max(errs_h):.2f} deg, speed "
        f"{max(errs_s) * 100:.1f} % (targets {HEADING_TARGET_DEG:g} deg, "
        f"{SPEED_TARGET * 100:g} %); the paper's: {max(paper_h):.0f} deg, "
        f"{max(paper_s) * 100:.0f} %."
    )
    return "\n".join(lines), ok


def figure(results: list[tuple[TableRow, Scene, Run, Run | None]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, spd) = plt.subplots(1, 2, figsize=(13, 6))
    colors = plt.cm.tab10(np.linspace(0, 1, 10))
    for k, (row, scene, on, off) in enumerate(results):
        c = colors[k % 10]
        ball = scene.balls[0]
        tt = np.linspace(ball.t_on_s, ball.t_off_s, 50)
        truth = ball.position_m(tt)
        label = f"{row.heading_deg:.0f} deg, {row.speed_mps} m/s"
        top.plot(truth[:, 0], truth[:, 2], "-", color=c, lw=3, alpha=0.3)
        top.plot(on.positions_m[:, 0], on.positions_m[:, 2], ".", color=c, ms=4, label=label)
        if off is not None:
            top.plot(off.positions_m[:, 0], off.positions_m[:, 2], "x", color=c, ms=3, alpha=0.5)
        spd.plot(on.t_s, on.speeds_mps, "-", color=c, label=label)
        spd.axhline(row.speed_mps, color=c, ls=":", lw=1)
    top.set_xlabel("X (m, right)")
    top.set_ylabel("Z (m, forward)")
    top.set_title("Top view: truth (wide), tracker (dots), no skew compensation (x)")
    top.set_aspect("equal")
    top.legend(fontsize=7, loc="upper right")
    spd.set_xlabel("time (s)")
    spd.set_ylabel("speed (m/s)")
    spd.set_title("Published speed (valid estimates) and truth (dotted)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).parent,
        help="where accuracy.md and accuracy.png go (default: benchmarks/)",
    )
    ap.add_argument("--seed", type=int, default=0, help="noise and texture seed")
    a = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for row in TABLE_I:
            scene, on, off = run_scenario(row, Path(tmp), a.seed)
            results.append((row, scene, on, off))
            print(
                f"heading {row.heading_deg:3.0f} deg, {row.speed_mps} m/s: tracker "
                f"{_deg(on.heading_deg):>6} deg {on.speed_mps:.3f} m/s",
                flush=True,
            )
    text, ok = table(results)
    print()
    print(text)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "accuracy.md").write_text(text + "\n")
    figure(results, a.out / "accuracy.png")
    print(f"\nwrote {a.out / 'accuracy.md'} and {a.out / 'accuracy.png'}")
    if not ok:
        print("TARGETS MISSED", file=sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
