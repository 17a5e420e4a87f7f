"""Accuracy on scenes from two renderers written apart, in the Minoru's real modes.

Every combination of:

- renderer: the project's own (``synth``: the paper's Table I motions, discs seen by the
  canonical rig, the right eye half a frame late) and the independent ray-caster (``world``:
  shaded balls, a cylinder and a box on a textured floor before a textured wall, free-running
  clocks whose skew wanders from -1/2 to +1/2 frame, per-eye gain, lighting drift, noise);
- mode: 320x240 at 30 Hz and 640x480 at 15 Hz (what a Minoru streams from both eyes), each at a
  42 deg and a 60 deg field of view;
- seed: 0, 1, 2;

for the eight Table I motions, plus (independent renderer) two balls crossing with occlusion, a
cylinder and a box robot, and thrown balls at 10 and 20 m/s across the view and towards the rig. A
room table (seed 0 unless ``--room-seeds``, every mode): a ball rolling across a floor under an
overhead and a low side lamp (cast shadows), each also through a webcam's transport (30 ms rolling
shutter, 4:2:2, MJPEG q75, 100 Hz flicker), with the same targets; and the people rows (a robot
that stops and goes, one that pushes a box away, a person who sits, walks and stands, one who walks
up to 0.8 m from the rig, two people crossing): ids per person while in view (target 1), ghost
tracks (target none), the share of frames in view with a confirmed track within 0.5 m of the truth,
and the closest range at which the person walking up was still tracked (target 0.8 m). Fused rooms,
one row per object of each room scene rendered from several rig poses
(``stereod_fakes.world.rooms``): every rig's views through the pipeline, its tracks fused as
``stereod fuse`` does; room ids per object, id switches (at a handover), and the position, heading
and speed errors of the room's tracks and of each rig alone, also where two rigs see the object at
once. Rendered people take minutes per scene: set ``STEREOD_WORLD_CACHE`` to a directory to keep
the frames. Each scene goes through the pipeline with default settings and is scored against its
truth (``tests/accuracy.py``). Targets, in every cell: heading within 1 deg and speed within 3 %;
median position error at most 1/4 of eq. 12's one-pixel depth error; exactly one track per object
(no ghosts, no id switch at the crossing); a fast object tracked from its second frame in view.
Beside the median heading error each cell reports the 90th percentile of its estimates' |heading
error| (not a target): what single frames show, which the median hides.

Writes ``docs/bench/accuracy.md`` (the host, the summary table with the worst case per column,
the paper's Table I motions beside the paper's own errors, and every cell), which the
documentation's Accuracy page includes, ``docs/bench/accuracy.png`` (every cell's errors) and
``docs/bench/accuracy_crossing.png`` (``stereod plot`` of one run, the two balls crossing,
against the truth). Usage: ``python benchmarks/accuracy.py [--jobs 2] [--quick] [--only PART
...] [--room-seeds SEED ...] [--out DIR]``: ``--only`` runs a part of the table (balls, rooms,
fused, people) and prints it, writing it only where ``--out`` says; ``--room-seeds`` runs the
room rows at more scene seeds than 0.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import report
from accuracy_room import fusion_section

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from stereod.cli.progress import Progress
from stereod_fakes.scenarios import TABLE_I
from tests import accuracy as acc

HEADING_TARGET_DEG = 1.0
SPEED_TARGET = 0.03
POSITION_TARGET = 0.25
SEEDS = (0, 1, 2)
APPROACH_TARGET_M = 0.85
"""A person walking up to stop 0.8 m from the rig is tracked to within this depth (m)."""
PEOPLE_GATE_M = 0.5
"""A confirmed track within this distance (m) of a person's truth centre is on them."""
ROOM = (("lamp_ball", {"lamp": "overhead"}), ("lamp_ball", {"lamp": "side"}))
PEOPLE: tuple[tuple[str, dict[str, object]], ...] = (
    ("robot_stop_go", {}),
    ("robot_push_box", {}),
    ("person_sit_walk", {"stop_s": 60.0}),
    ("person_approach", {}),
    ("people_crossing", {}),
)


@dataclass
class Cell:
    """One object of one scene, scored."""

    renderer: str
    mode: str
    scene: str
    seed: int
    kind: str
    obj: str
    heading_err_deg: float
    heading_p90_deg: float
    speed_err: float
    position_ratio: float
    position_err_m: float
    ids: int
    ghosts: int
    first_tracked: int | None
    first_valid: int | None
    frames_in_view: int
    tracked_share: float = math.nan
    """People rows: the share of frames in view with a confirmed track within 0.5 m."""
    closest_m: float = math.nan
    """People rows: the closest true depth (m) at which it was tracked."""
    ghost_life_s: float = 0.0
    """The longest a ghost track lived (s)."""

    def ok(self) -> bool:
        if self.kind == "people":
            near = "approach" not in self.scene or self.closest_m <= APPROACH_TARGET_M
            return self.ids == 1 and self.ghosts == 0 and near
        fast_ok = self.kind != "fast" or (
            self.first_tracked is not None and self.first_tracked <= 2
        )
        measured = self.kind == "fast" and self.frames_in_view < 4
        return (
            (measured or abs(self.heading_err_deg) <= HEADING_TARGET_DEG)
            and (measured or abs(self.speed_err) <= SPEED_TARGET)
            and (measured or self.position_ratio <= POSITION_TARGET)
            and self.ids == 1
            and self.ghosts == 0
            and fast_ok
        )


Spec = tuple[str, str, int, str, dict[str, object]]
"""(renderer, mode name, seed, what, arguments) of one case, picklable for the workers."""


PARTS = ("balls", "rooms", "fused", "people")
"""The table's parts (``--only``): the balls and robots of both renderers, the room rows (a
ball under a lamp), the fused rooms, the people rows."""


def specs(
    quick: bool, parts: tuple[str, ...] = PARTS, room_seeds: tuple[int, ...] = (0,)
) -> list[Spec]:
    """Every case of the chosen ``parts`` (one mode and one seed with ``quick``; the room rows
    at ``room_seeds``)."""
    out: list[Spec] = []
    modes = acc.MODES[:1] if quick else acc.MODES
    seeds = SEEDS[:1] if quick else SEEDS
    for mode in modes if "balls" in parts else ():
        for seed in seeds:
            for renderer in ("synth", "world"):
                for row in acc.TABLE_I:
                    out.append(
                        (
                            renderer,
                            mode.name,
                            seed,
                            "robot",
                            {"h": row.heading_deg, "v": row.speed_mps},
                        )
                    )
            for preset in ("crossing", "robot_cylinder", "robot_box"):
                out.append(("world", mode.name, seed, preset, {}))
            for direction in ("lateral", "radial"):
                for v in (10.0, 20.0):
                    out.append(("world", mode.name, seed, "fast", {"direction": direction, "v": v}))
    for mode in modes if "rooms" in parts else ():
        for seed in room_seeds:
            for preset, kw in ROOM:
                for webcam in (False, True):
                    args = {"preset": preset, "webcam": webcam, **kw}
                    out.append(("world", mode.name, seed, "room", args))
    for mode in modes if "people" in parts else ():
        for preset, kw in PEOPLE:
            out.append(("world", mode.name, 0, "people", {"preset": preset, **kw}))
    return out


def build(spec: Spec) -> acc.Case:
    renderer, mode_name, seed, what, args = spec
    mode = next(m for m in acc.MODES if m.name == mode_name)
    if what == "robot":
        make: Callable[..., acc.Case] = acc.world_robot if renderer == "world" else acc.synth_robot
        return make(float(args["h"]), float(args["v"]), mode, seed)  # type: ignore[arg-type]
    if what == "fast":
        return acc.world_preset(
            "fast_ball", mode, seed, direction=args["direction"], speed_mps=args["v"]
        )
    if what in ("room", "people"):
        kw = dict(args)
        preset = str(kw.pop("preset"))
        webcam = bool(kw.pop("webcam", False))
        return acc.world_room(preset, mode, seed, webcam=webcam, **kw)
    return acc.world_preset(what, mode, seed)


def run(spec: Spec) -> list[Cell]:
    case = build(spec)
    people = spec[3] == "people"
    result = acc.score(case, acc.run_case(case), gate_m=PEOPLE_GATE_M if people else None)
    kind = "fast" if case.fast else ("crossing" if spec[3] == "crossing" else "robot")
    kind = spec[3] if spec[3] in ("room", "people") else kind
    life = max(result.ghost_life_s.values(), default=0.0)
    return [
        Cell(
            case.renderer,
            case.mode.name,
            case.name,
            case.seed,
            kind,
            o.name,
            o.heading_err_deg,
            o.heading_p90_deg,
            o.speed_err,
            o.position_ratio,
            o.position_err_m,
            len(o.track_ids),
            len(result.ghosts),
            o.first_tracked,
            o.first_valid,
            o.frames_in_view,
            o.tracked_share,
            o.closest_tracked_m,
            life,
        )
        for o in result.objects
    ]


def _f(x: float, fmt: str) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def worst(cells: list[Cell]) -> dict[str, float]:
    def amax(vals: list[float]) -> float:
        vals = [abs(v) for v in vals if not math.isnan(v)]
        return max(vals) if vals else math.nan

    fast = [c for c in cells if c.kind == "fast"]
    return {
        "heading": amax([c.heading_err_deg for c in cells]),
        "heading_p90": amax([c.heading_p90_deg for c in cells]),
        "speed": amax([c.speed_err for c in cells]),
        "position": amax([c.position_ratio for c in cells]),
        "ids": max(c.ids for c in cells),
        "no_track": sum(c.ids == 0 for c in cells),
        "ghosts": sum(c.ghosts for c in cells),
        "fast_first": max((c.first_tracked or 99) for c in fast) if fast else math.nan,
        "failed": sum(not c.ok() for c in cells),
        "cells": len(cells),
    }


def summary_table(cells: list[Cell]) -> str:
    lines = [
        "| renderer | mode | objects | worst heading error (deg) | worst heading p90 (deg) "
        "| worst speed error (%) | worst position error / eq. 12 | most ids for one object "
        "| objects never tracked | ghost tracks | fast: first frame tracked "
        "| cells missing a target |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str], list[Cell]] = {}
    for c in cells:
        groups.setdefault((c.renderer, c.mode), []).append(c)
    for (renderer, mode), group in sorted(groups.items()):
        w = worst(group)
        lines.append(
            f"| {renderer} | {mode} | {w['cells']} | {_f(w['heading'], '.2f')} "
            f"| {_f(w['heading_p90'], '.1f')} | {_f(w['speed'] * 100, '.1f')} "
            f"| {_f(w['position'], '.2f')} | {w['ids']} "
            f"| {w['no_track']} | {w['ghosts']} | {_f(w['fast_first'], '.0f')} | {w['failed']} |"
        )
    w = worst(cells)
    lines.append(
        f"| **all** | | {w['cells']} | **{_f(w['heading'], '.2f')}** "
        f"| **{_f(w['heading_p90'], '.1f')}** | **{_f(w['speed'] * 100, '.1f')}** "
        f"| **{_f(w['position'], '.2f')}** | **{w['ids']}** "
        f"| **{w['no_track']}** | **{w['ghosts']}** | **{_f(w['fast_first'], '.0f')}** "
        f"| **{w['failed']}** |"
    )
    return "\n".join(lines)


def room_table(cells: list[Cell]) -> str:
    """The room rows: a ball under a lamp (cast shadows), with and without a webcam's
    transport, per mode."""
    lines = [
        "| mode | scene | seed | heading err (deg) | speed err (%) | position / eq. 12 | ids "
        "| ghosts | ok |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        if c.kind == "room":
            lines.append(
                f"| {c.mode} | {c.scene} | {c.seed} | {_f(c.heading_err_deg, '+.2f')} "
                f"| {_f(c.speed_err * 100, '+.1f')} | {_f(c.position_ratio, '.2f')} | {c.ids} "
                f"| {c.ghosts} | {'yes' if c.ok() else '**no**'} |"
            )
    return "\n".join(lines)


def people_table(cells: list[Cell]) -> str:
    """The people rows: ids per person while in view, ghost tracks (and the longest one's
    life), frames tracked, the closest range tracked."""
    lines = [
        "| mode | scene | object | ids | ghosts (longest, s) | frames tracked (%) "
        "| closest tracked (m) | ok |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        if c.kind == "people":
            lines.append(
                f"| {c.mode} | {c.scene} | {c.obj} | {c.ids} | {c.ghosts} "
                f"({c.ghost_life_s:.1f}) | {_f(c.tracked_share * 100, '.0f')} "
                f"| {_f(c.closest_m, '.2f')} | {'yes' if c.ok() else '**no**'} |"
            )
    return "\n".join(lines)


def cell_table(cells: list[Cell]) -> str:
    lines = [
        "| renderer | mode | scene | seed | object | heading err (deg) | heading p90 (deg) "
        "| speed err (%) | position err (cm) | / eq. 12 | ids | ghosts "
        "| first tracked / valid (of frames) | ok |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        lines.append(
            f"| {c.renderer} | {c.mode} | {c.scene} | {c.seed} | {c.obj} "
            f"| {_f(c.heading_err_deg, '+.2f')} | {_f(c.heading_p90_deg, '.1f')} "
            f"| {_f(c.speed_err * 100, '+.1f')} "
            f"| {_f(c.position_err_m * 100, '.2f')} | {_f(c.position_ratio, '.2f')} | {c.ids} "
            f"| {c.ghosts} | {c.first_tracked or '-'} / {c.first_valid or '-'} "
            f"({c.frames_in_view}) | {'yes' if c.ok() else '**no**'} |"
        )
    return "\n".join(lines)


def table_one(cells: list[Cell]) -> str:
    """The paper's Table I motions, worst over modes and seeds, beside the paper's own errors."""
    lines = [
        "| motion | paper: heading, speed error | `synth`: heading, speed "
        "| `world`: heading, speed | `world`: position / eq. 12 |",
        "|---|---|---|---|---|",
    ]

    def worst_of(renderer: str, scene: str) -> dict[str, float] | None:
        group = [c for c in cells if c.renderer == renderer and c.scene == scene]
        return worst(group) if group else None

    def pair(w: dict[str, float] | None) -> str:
        if w is None:
            return ""
        return f"{_f(w['heading'], '.2f')} deg, {_f(w['speed'] * 100, '.1f')} %"

    scenes = {c.scene for c in cells}
    for row in TABLE_I:
        scene = next(
            (s for s in scenes if s == f"ball {row.heading_deg:g} deg {row.speed_mps:g} m/s"),
            None,
        )
        if scene is None:
            continue
        paper_h = abs(row.paper_heading_deg - row.heading_deg)
        paper_v = abs(row.paper_speed_mps - row.speed_mps) / row.speed_mps * 100
        world = worst_of("world", scene)
        lines.append(
            f"| {row.heading_deg:g} deg, {row.speed_mps:g} m/s | {paper_h:g} deg, {paper_v:.0f} % "
            f"| {pair(worst_of('synth', scene))} | {pair(world)} "
            f"| {_f(world['position'], '.2f') if world else ''} |"
        )
    crossing = worst_of("world", "crossing")
    if crossing is not None:
        lines.append(
            f"| two balls crossing | | | {pair(crossing)} | {_f(crossing['position'], '.2f')} |"
        )
    return "\n".join(lines)


def figure(cells: list[Cell], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    colours = {"synth": "tab:blue", "world": "tab:orange"}
    for ax, key, target, label in (
        (axes[0], "heading_err_deg", HEADING_TARGET_DEG, "heading error (deg)"),
        (axes[1], "speed_err", SPEED_TARGET, "speed error (share)"),
        (axes[2], "position_ratio", POSITION_TARGET, "position error / eq. 12 one-pixel error"),
    ):
        for renderer, colour in colours.items():
            for k, mode in enumerate(acc.MODES):
                vals = [
                    getattr(c, key) for c in cells if c.renderer == renderer and c.mode == mode.name
                ]
                vals = [abs(v) for v in vals if not math.isnan(v)]
                x = k + (0.15 if renderer == "world" else -0.15)
                ax.plot(
                    [x] * len(vals),
                    vals,
                    "o",
                    color=colour,
                    alpha=0.5,
                    ms=4,
                    label=renderer if k == 0 else None,
                )
        ax.axhline(target, color="red", ls="--", lw=1, label="target")
        ax.set_xticks(range(len(acc.MODES)), [m.name for m in acc.MODES], rotation=15, fontsize=8)
        ax.set_ylabel(label)
        ax.legend(fontsize=8)
    fig.suptitle("Every object of every scene: |error| per mode, both renderers")
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def trajectory_figure(path: Path) -> None:
    """One run drawn by ``stereod plot``: two balls crossing (independent renderer, 320x240 at
    30 Hz, 42 deg), measured against true."""
    from stereod.bus.messages import dump, objects_message
    from stereod.view.plot import plot_run, read_run, read_truth

    case = acc.world_preset("crossing", acc.MODES[0], seed=0)
    results = acc.run_case(case)
    rig = case.mode.rig
    with tempfile.TemporaryDirectory() as tmp:
        jsonl, truth = Path(tmp) / "run.jsonl", Path(tmp) / "truth.csv"
        rows = ["object,t_ns,x_m,y_m,z_m,vx_mps,vy_mps,vz_mps"]
        with jsonl.open("wb") as fh:
            for r in results:
                msg = objects_message(
                    r, rig="bench", geometry=rig.geometry, calibration_id=None, utc_offset_ns=0
                )
                fh.write(dump(msg) + b"\n")
                for name, (p, v) in case.truth(r.t_ns).items():
                    rows.append(f"{name},{r.t_ns}," + ",".join(f"{x:.6f}" for x in (*p, *v)))
        truth.write_text("\n".join(rows) + "\n")
        run = read_run(jsonl)
        plot_run(run, read_truth(truth, run.t0_ns), path, title=case.label)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--out",
        type=Path,
        default=None,
        help="folder of accuracy.md and the figures (default docs/bench for the whole table; "
        "a part of it is only printed unless this is given)",
    )
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    ap.add_argument(
        "--quick",
        action="store_true",
        help="one mode and one seed only (the fused rooms stay whole); a part of the table",
    )
    ap.add_argument(
        "--only",
        nargs="+",
        choices=PARTS,
        default=list(PARTS),
        help="run these parts of the table only (default: all; the fused rooms have no "
        "targets, so they never fail the run)",
    )
    ap.add_argument(
        "--room-seeds",
        nargs="+",
        type=int,
        default=[0],
        metavar="SEED",
        help="the room rows' scene seeds (default 0; other than 0 alone, a part of the "
        "table; the people rows and the fused rooms are seed 0)",
    )
    a = ap.parse_args()
    parts = tuple(p for p in PARTS if p in a.only)
    room_seeds = tuple(dict.fromkeys(a.room_seeds))
    whole = parts == PARTS and not a.quick and room_seeds == (0,)
    out = a.out if a.out is not None else (report.DOCS_BENCH if whole else None)
    todo = specs(a.quick, parts, room_seeds)
    host = report.host()
    t0 = time.monotonic()
    cells: list[Cell] = []
    tty = sys.stderr.isatty()
    bar = Progress("scenes", total=len(todo), unit="scene")
    with ProcessPoolExecutor(a.jobs) as pool, bar:
        for k, got in enumerate(pool.map(run, todo), 1):
            cells.extend(got)
            bar.update(1)
            bad = [c for c in got if not c.ok()]
            if bad or not tty:
                mark = "  MISSED: " + ", ".join(f"{c.obj}" for c in bad) if bad else ""
                print(
                    f"[{k}/{len(todo)}] {got[0].renderer} {got[0].mode} {got[0].scene} seed "
                    f"{got[0].seed}{mark}",
                    file=sys.stderr,
                    flush=True,
                )
    fused = fusion_section() if "fused" in parts else None
    elapsed = time.monotonic() - t0
    table = [c for c in cells if c.kind not in ("room", "people")]
    rooms = [c for c in cells if c.kind == "room"]
    people = [c for c in cells if c.kind == "people"]
    groups = {"balls and robots": table, "rooms": rooms, "people and robots that stop": people}
    failed = sum(not c.ok() for c in cells)
    counts = ", ".join(
        f"{name} {sum(c.ok() for c in group)} of {len(group)}"
        for name, group in groups.items()
        if group
    )
    how = "`make accuracy`" if whole else "`benchmarks/accuracy.py " + " ".join(sys.argv[1:]) + "`"
    sections = [
        f"{host} {len(todo)} scenes, {len(cells)} objects, {elapsed:.0f} s "
        f"({how}, {a.jobs} worker processes)."
    ]
    if cells:
        sections.append(
            f"**{len(cells) - failed} of {len(cells)} cells meet every target** ({counts})."
        )
    if table:
        sections += [
            "Worst case of the balls and robots per renderer and mode:",
            summary_table(table),
            "The paper's Table I motions, the worst of each over every mode and seed, beside "
            "the paper's own errors:",
            table_one(table),
            "![Every object's heading, speed and position error per mode, both renderers]"
            "(bench/accuracy.png)",
            "One run of the two balls crossing, drawn by `stereod plot` against the scene's truth:",
            "![Two balls crossing: top view, speed and heading against the truth]"
            "(bench/accuracy_crossing.png)",
        ]
    if rooms or fused is not None:
        sections.append("### Rooms")
    if rooms:
        sections += [
            "A ball under one lamp (cast shadows), and through a webcam's transport:",
            room_table(cells),
        ]
    if fused is not None:
        sections.append(fused)
    if people:
        sections += [
            "### People and robots that stop",
            "A confirmed track within 0.5 m of the truth:",
            people_table(cells),
        ]
    if table:
        sections += ["### Every cell", cell_table(table)]
        print(summary_table(table))
    if rooms:
        print(room_table(cells))
    if fused is not None:
        print(fused)
    if people:
        print(people_table(cells))
    wrote = ""
    if out is not None:
        path = report.write("accuracy.md", "\n\n".join(sections), out)
        wrote = f"; wrote {path}"
        if table:
            figure(table, out / "accuracy.png")
            trajectory_figure(out / "accuracy_crossing.png")
    scored = f"{counts} meet" if counts else "none scored"
    print(f"\n{failed} of {len(cells)} cells miss a target ({scored}){wrote}")
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
