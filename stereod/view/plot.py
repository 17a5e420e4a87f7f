"""``stereod plot``: a figure of one run against the truth, from the ``objects`` messages a run
wrote with ``--jsonl``.

Three panels: the top view (X-Z, m) of every track's measured trajectory beside the true one;
speed (m/s) and heading (deg) against time (s from the run's first message) with the filter's
1-sigma band; and the paper's eq. 21 estimate (the two-point difference over the time base)
beside the filter's. The data preparation here is plain numpy and tested on its own;
matplotlib is needed only to draw (the ``plot`` extra: ``pip install 'stereod[plot]'``).

Truth comes as a CSV with the header ``object,t_ns,x_m,y_m,z_m`` (extra columns are ignored,
except ``vx_mps,vy_mps,vz_mps``, which give the true velocity when present), as the independent
renderer's ``truth.csv`` has it, or as a synthetic recording's ``truth.json`` (its balls are
sampled at the scene's frame times while in view).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from stereod.bus.messages import ObjectsMessage, ObjectState
from stereod.errors import InputError, MissingInputError, NotInstalledError, UsageError
from stereod.files.bounds import MAX_COORDINATE, UTC_NS_MAX
from stereod.files.output_file import AtomicOutput, output_target, written_in_place

FIGSIZE_IN = (12.0, 6.0)
DPI = 100
"""The figure is FIGSIZE_IN x DPI pixels (1200 x 600)."""


@dataclass(frozen=True)
class TrackSeries:
    """One track's states over a run, (n,) arrays in time order; NaN where the message said
    null. ``t_s`` from the run's first message; the rest as on the wire (m, m/s, deg)."""

    track_id: int
    t_s: np.ndarray
    position_m: np.ndarray
    valid: np.ndarray
    heading_valid: np.ndarray
    speed_mps: np.ndarray
    speed_sigma_mps: np.ndarray
    heading_deg: np.ndarray
    heading_sigma_deg: np.ndarray
    raw_velocity_mps: np.ndarray
    """(n, 3) the paper's eq. 21 velocity, NaN rows until the track spans the time base."""
    state: np.ndarray | None = None
    """(n,) lifecycle of each state (``tentative``, ``confirmed``, ``coasting``,
    ``stationary``); None: all measured and confirmed."""

    def measured(self) -> np.ndarray:
        """(n,) whether a state had a measurement: a coasting state is the filter's
        prediction alone, and its eq. 21 value the last measured one repeated."""
        if self.state is None:
            return np.ones(len(self.t_s), dtype=bool)
        return np.asarray(self.state != "coasting", dtype=bool)

    def trajectory_m(self) -> np.ndarray:
        """(k, 3) positions to draw as the track's path, m: its states but the tentative
        ones (a track's first, unconfirmed guesses, which draw a hook at its start)."""
        if self.state is None:
            return self.position_m
        return self.position_m[self.state != "tentative"]


@dataclass(frozen=True)
class TruthSeries:
    """One true object: (n,) times (s, the run's clock), (n, 3) positions (m) and velocities
    (m/s)."""

    name: str
    t_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray


@dataclass(frozen=True)
class Run:
    """A run's tracks and the instant its time axis starts (``t0_ns``, the frames' clock)."""

    t0_ns: int
    tracks: list[TrackSeries]


def _num(x: float | None) -> float:
    return float("nan") if x is None else float(x)


def read_run(path: Path) -> Run:
    """The tracks of a JSONL file of ``objects`` messages (``stereod replay --jsonl``)."""
    rows: dict[int, list[tuple[int, ObjectState]]] = {}
    t0: int | None = None
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise _unreadable(path, "run", exc, " (write one with --jsonl)") from exc
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: not a text file (byte {exc.start} is not UTF-8); give the objects "
            "messages written by --jsonl"
        ) from exc
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            msg = ObjectsMessage.model_validate_json(line)
        except ValidationError as exc:
            raise InputError(
                f"{path}:{n}: not an objects message ({exc.errors()[0]['msg']}); "
                "give the file written by --jsonl"
            ) from exc
        t0 = msg.t_ns if t0 is None else min(t0, msg.t_ns)
        for o in msg.objects:
            _check_state(path, n, o)
            rows.setdefault(o.track_id, []).append((o.t_ns, o))
    if t0 is None:
        raise InputError(f"{path}: no objects messages in the file")
    tracks = []
    for tid, states in sorted(rows.items()):
        states.sort(key=lambda r: r[0])
        obs = [o for _, o in states]
        tracks.append(
            TrackSeries(
                track_id=tid,
                t_s=np.array([(t - t0) * 1e-9 for t, _ in states]),
                position_m=np.array([o.position_m for o in obs], dtype=float),
                valid=np.array([o.velocity_valid for o in obs], dtype=bool),
                heading_valid=np.array([o.heading_valid for o in obs], dtype=bool),
                speed_mps=np.array([o.speed_mps for o in obs], dtype=float),
                speed_sigma_mps=np.array([_num(o.speed_sigma_mps) for o in obs]),
                heading_deg=np.array([o.heading_deg for o in obs], dtype=float),
                heading_sigma_deg=np.array([_num(o.heading_sigma_deg) for o in obs]),
                raw_velocity_mps=np.array(
                    [o.raw_velocity_mps or (math.nan,) * 3 for o in obs],
                    dtype=float,
                ),
                state=np.array([str(getattr(o.state, "value", o.state)) for o in obs]),
            )
        )
    return Run(t0, tracks)


def _check_state(path: Path, line: int, o: ObjectState) -> None:
    """Refuse (65) an object whose position, velocity or speed, or one of their sigmas (drawn
    as bands), lies beyond what the figure's axes can hold (:data:`MAX_TRUTH_M`), naming the
    file, line, track and field."""
    fields = {
        "position_m": o.position_m,
        "velocity_mps": o.velocity_mps,
        "raw_velocity_mps": o.raw_velocity_mps or (),
        "speed_mps": (o.speed_mps,),
        "position_sigma_m": o.position_sigma_m,
        "velocity_sigma_mps": o.velocity_sigma_mps or (),
        "speed_sigma_mps": (o.speed_sigma_mps,),
        "heading_sigma_deg": (o.heading_sigma_deg,),
    }
    for name, values in fields.items():
        for v in values:
            if v is not None and not (math.isfinite(v) and abs(v) <= MAX_TRUTH_M):
                raise InputError(
                    f"{path}:{line}: track {o.track_id}'s {name} holds {v:g}, out of range "
                    f"(|value| <= {MAX_TRUTH_M:g}); give the file written by --jsonl"
                )


def read_truth(path: Path, t0_ns: int) -> list[TruthSeries]:
    """True trajectories from a ``truth.csv`` or a synthetic ``truth.json``, on the run's
    time axis (s after ``t0_ns``)."""
    if path.suffix == ".json":
        return truth_from_scene(path, t0_ns)
    columns = ("object", "t_ns", "x_m", "y_m", "z_m")
    per: dict[str, list[list[float]]] = {}
    try:
        with path.open(newline="") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in columns if c not in (reader.fieldnames or [])]
            if missing:
                raise InputError(
                    f"{path}: truth CSV lacks column(s) {', '.join(missing)} "
                    f"(header must have {','.join(columns)})"
                )
            has_v = all(c in (reader.fieldnames or []) for c in ("vx_mps", "vy_mps", "vz_mps"))
            for n, row in enumerate(reader, 2):
                try:
                    vals = [float(row[c]) for c in columns[1:]]
                    vel = [float(row[c]) for c in ("vx_mps", "vy_mps", "vz_mps")] if has_v else []
                except (TypeError, ValueError) as exc:
                    raise InputError(f"{path}:{n}: not a number: {exc}") from exc
                named = zip((*columns[1:], "vx_mps", "vy_mps", "vz_mps"), vals + vel, strict=False)
                _check_truth_row(path, n, dict(named))
                per.setdefault(row["object"], []).append(vals + vel)
    except OSError as exc:
        raise _unreadable(path, "truth", exc) from exc
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{path}: not a text file (byte {exc.start} is not UTF-8); give a truth CSV or a "
            "synthetic recording's truth.json"
        ) from exc
    out = []
    for name, rows in sorted(per.items()):
        a = np.array(sorted(rows, key=lambda r: r[0]))
        t_s = (a[:, 0] - t0_ns) * 1e-9
        pos = a[:, 1:4]
        velocity = a[:, 4:7] if a.shape[1] >= 7 else finite_difference(t_s, pos)
        out.append(TruthSeries(name, t_s, pos, velocity))
    return out


MAX_TRUTH_M = MAX_COORDINATE
"""Largest position (m) or speed (m/s) a truth or a run may give."""
MAX_TRUTH_T_NS = UTC_NS_MAX
"""Largest truth time, ns since the epoch (year 2116)."""


def _check_truth_row(path: Path, line: int, values: dict[str, float]) -> None:
    """Refuse (65) a truth row whose time or values are not finite or out of range, naming
    the file, line and column."""
    for name, v in values.items():
        bound = MAX_TRUTH_T_NS if name == "t_ns" else MAX_TRUTH_M
        if not math.isfinite(v) or abs(v) > bound:
            raise InputError(
                f"{path}:{line}: {name} = {v:g} is out of range (|{name}| <= {bound:g}); "
                "is it the right truth file?"
            )


def _unreadable(path: Path, what: str, exc: OSError, hint: str = "") -> MissingInputError:
    """The one line for a ``what`` file the OS does not give: missing (then ``hint``), or
    its reason (no permission, a folder)."""
    if isinstance(exc, FileNotFoundError):
        return MissingInputError(f"{path}: no such {what} file{hint}")
    return MissingInputError(f"{path}: cannot read the {what} file: {exc.strerror}")


def truth_from_scene(path: Path, t0_ns: int) -> list[TruthSeries]:
    """Every ball of a synthetic recording's ``truth.json``, at the left eye's frame times
    while it is in view."""
    from stereod_fakes.synth import Scene  # the synthetic scene's own model and motion

    try:
        scene = Scene.model_validate_json(path.read_bytes())
    except OSError as exc:
        raise _unreadable(path, "truth", exc) from exc
    except ValidationError as exc:
        raise InputError(
            f"{path}: not a synthetic scene's truth.json: {exc.errors()[0]['msg']}"
        ) from exc
    frames = np.arange(scene.n_frames) / scene.fps
    out = []
    for i, ball in enumerate(scene.balls, 1):
        t = np.array([s for s in frames if ball.visible(float(s))])
        if len(t) == 0:
            continue
        pos = ball.position_m(t)
        vel = np.array([ball.velocity_at(float(s)) for s in t])
        t_ns = scene.t0_ns + np.round(t * 1e9)
        out.append(TruthSeries(f"ball {i}", (t_ns - t0_ns) * 1e-9, pos, vel))
    return out


def check_overlap(run: Run, truth: list[TruthSeries], path: Path) -> None:
    """Refuse a truth whose times do not meet the run's (a truth of another run, or of a
    scene replayed on another clock), which would otherwise be drawn far off to one side."""
    spans = [(float(ts.t_s[0]), float(ts.t_s[-1])) for ts in truth if len(ts.t_s)]
    ends = [float(tr.t_s[-1]) for tr in run.tracks if len(tr.t_s)]
    if not spans or not ends:
        return
    a, b = min(lo for lo, _ in spans), max(hi for _, hi in spans)
    c = max(ends)
    if b < 0.0 or a > c:
        raise InputError(
            f"{path}: its times ({a:.1f} to {b:.1f} s on the run's clock) do not overlap the "
            f"run's (0 to {c:.1f} s): give the truth of the scene this run replayed"
        )


def finite_difference(t_s: np.ndarray, position_m: np.ndarray) -> np.ndarray:
    """(n, 3) velocity (m/s) of sampled positions by central differences (one-sided at the
    ends); zeros for a single sample."""
    if len(t_s) < 2:
        return np.zeros_like(position_m)
    return np.gradient(position_m, t_s, axis=0)


def speed_heading(velocity_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Speed |v| (eq. 22, m/s) and heading atan2(vx, vz) (eq. 23, deg in [0, 360)) of (n, 3)
    velocities; NaN rows stay NaN."""
    v = np.atleast_2d(velocity_mps)
    speed = np.linalg.norm(v, axis=1)
    heading = np.degrees(np.arctan2(v[:, 0], v[:, 2])) % 360.0
    return speed, heading


def eq21(track: TrackSeries) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The paper's eq. 21 series of a track: (t_s, speed m/s, heading deg) where it exists and
    was measured (a coasting state repeats the last value: it is left out, not drawn again)."""
    ok = np.all(np.isfinite(track.raw_velocity_mps), axis=1) & track.measured()
    speed, heading = speed_heading(track.raw_velocity_mps[ok])
    return track.t_s[ok], speed, heading


def band(value: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 1-sigma band (value - sigma, value + sigma); NaN where sigma is unknown."""
    return value - sigma, value + sigma


def unwrap_deg(heading_deg: np.ndarray, near_deg: float | None = None) -> np.ndarray:
    """Headings without 360-degree jumps; shifted by whole turns so that their first value is
    within 180 deg of ``near_deg`` when given (to draw them beside the truth)."""
    h = np.asarray(heading_deg, dtype=float)
    if len(h) == 0:
        return h
    out = np.degrees(np.unwrap(np.radians(h)))
    if near_deg is not None:
        out -= 360.0 * np.round((out[0] - near_deg) / 360.0)
    return out


def display_deg(heading_deg: np.ndarray) -> np.ndarray:
    """Headings to draw: unwrapped, then shifted by whole turns so that their circular mean
    lies in [0, 360) (a track heading 250 deg is drawn at 250, one crossing 0 stays whole)."""
    h = np.asarray(heading_deg, dtype=float)
    if len(h) == 0:
        return h
    mean = math.degrees(math.atan2(np.mean(np.sin(np.radians(h))), np.mean(np.cos(np.radians(h)))))
    out = unwrap_deg(h)
    return out - 360.0 * np.round((np.mean(out) - mean % 360.0) / 360.0)


def _figure_class() -> Any:
    """matplotlib's ``Figure``; without matplotlib, the one line saying how to install it."""
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise NotInstalledError(
            "stereod plot needs matplotlib: pip install 'stereod[plot]'"
        ) from exc
    return Figure


def figure_target(out: Path) -> tuple[Path, str]:
    """The file a figure for ``--out`` is written to and its format, by its suffix (``png``,
    ``pdf``, ``svg``, ...), ``.png`` added when it has none, as matplotlib would. A suffix
    matplotlib cannot write is refused before any work, listing those it can, and so is what
    cannot be an output at all (a folder, a socket: :func:`output_target`'s rule)."""
    if out.is_dir():  # a folder, not a name to add .png to (`-o /tmp` wrote /tmp.png)
        output_target(out)
    if not out.suffix:
        if written_in_place(out):  # /dev/null, a FIFO: that file, as PNG
            return out, "png"
        target = out.with_name(out.name + ".png")
        output_target(target)
        return target, "png"
    output_target(out)
    fmt = out.suffix[1:].lower()
    # PGF is LaTeX source that needs a TeX installation even to write: not offered.
    supported = sorted(set(_figure_class()().canvas.get_supported_filetypes()) - {"pgf"})
    if fmt not in supported:
        raise UsageError(
            f"--out {out}: .{fmt} is not a figure format; give a file ending in "
            f"{', '.join('.' + s for s in supported)}"
        )
    return out, fmt


def plot_run(run: Run, truth: list[TruthSeries], out: Path, *, title: str = "") -> Path:
    """Draw the figure (FIGSIZE_IN at DPI) to ``out`` (PNG, or any format by its suffix: see
    :func:`figure_target`); return the path written."""
    path, fmt = figure_target(out)
    fig = draw(run, truth, title=title)
    image = io.BytesIO()
    fig.savefig(image, dpi=DPI, format=fmt)
    with AtomicOutput(path) as output:  # the output rule of every command (output_file)
        output.write(image.getvalue())
    return path


def draw(run: Run, truth: list[TruthSeries], *, title: str = "") -> Any:
    """The figure (a matplotlib ``Figure``, FIGSIZE_IN at DPI): top view, speed, heading.
    Legends stand beside or below their panel, never over its data."""
    fig = _figure_class()(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=(1.0, 1.4))
    top = fig.add_subplot(grid[:, 0])
    spd = fig.add_subplot(grid[0, 1])
    hdg = fig.add_subplot(grid[1, 1], sharex=spd)
    cycle = [f"C{i}" for i in range(10)]
    true: dict[str, Any] = {"color": "k", "lw": 1.0, "zorder": 5}
    for k, ts in enumerate(truth):
        lbl = "true" if k == 0 else None
        top.plot(ts.position_m[:, 0], ts.position_m[:, 2], "--", label=lbl, **true)
        s, h = speed_heading(ts.velocity_mps)
        spd.plot(ts.t_s, s, "--", label=lbl, **true)
        hdg.plot(ts.t_s, display_deg(h), "--", label=lbl, **true)
    for k, tr in enumerate(run.tracks):
        c = cycle[k % len(cycle)]
        name = f"#{tr.track_id}"
        path = tr.trajectory_m()
        top.plot(path[:, 0], path[:, 2], ".-", color=c, ms=3, lw=0.8, label=name)
        v = tr.valid
        if not v.any():
            continue
        t = tr.t_s[v]
        lo, hi = band(tr.speed_mps[v], tr.speed_sigma_mps[v])
        spd.fill_between(t, lo, hi, color=c, alpha=0.2, lw=0)
        spd.plot(t, tr.speed_mps[v], "-", color=c, label=f"{name} filter")
        hv = tr.heading_valid
        h = display_deg(tr.heading_deg[hv])
        if hv.any():
            lo, hi = band(h, tr.heading_sigma_deg[hv])
            hdg.fill_between(tr.t_s[hv], lo, hi, color=c, alpha=0.2, lw=0)
            hdg.plot(tr.t_s[hv], h, "-", color=c, label=f"{name} filter")
        rt, rs, rh = eq21(tr)
        if len(rt):
            spd.plot(rt, rs, "x", color=c, ms=4, label=f"{name} eq. 21")
            near = h[0] if len(h) else None
            hdg.plot(rt, unwrap_deg(rh, near), "x", color=c, ms=4, label=f"{name} eq. 21")
    top.plot([0.0], [0.0], "k^", ms=8)
    top.set_xlabel("X (m), right")
    top.set_ylabel("Z (m), away from the camera")
    top.set_title("top view")
    top.set_aspect("equal", adjustable="datalim")
    top.grid(alpha=0.3)
    spd.set_ylabel("speed (m/s)")
    spd.set_title("speed and heading (filter with 1-sigma band; x: the paper's eq. 21)")
    hdg.set_ylabel("heading (deg)")
    hdg.set_xlabel("time (s)")
    for ax in (top, spd, hdg):
        ax.grid(alpha=0.3)
    if top.get_legend_handles_labels()[0]:  # below the top view
        top.legend(
            fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncols=4, borderaxespad=0
        )
    for ax in (spd, hdg):  # right of the time series
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    if title:
        fig.suptitle(title, parse_math=False)  # written as given: "$x^{2$" is no formula
    return fig


def summary(run: Run) -> str:
    """One line per track: its span and median valid speed and heading."""
    lines = []
    for tr in run.tracks:
        v, hv = tr.valid, tr.heading_valid
        if v.any():
            s = float(np.median(tr.speed_mps[v]))
            heading = "not yet valid"
            if hv.any():
                h = np.degrees(np.angle(np.mean(np.exp(1j * np.radians(tr.heading_deg[hv])))))
                heading = f"{float(h) % 360.0:.1f} deg"
            lines.append(
                f"track {tr.track_id}: {tr.t_s[0]:.2f}-{tr.t_s[-1]:.2f} s, {int(v.sum())} valid "
                f"states, speed {s:.3f} m/s, heading {heading}"
            )
        else:
            lines.append(f"track {tr.track_id}: {len(tr.t_s)} states, no valid velocity")
    return "\n".join(lines)
