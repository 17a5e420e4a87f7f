"""``stereod synth``: render a synthetic recording with its ground truth.

A command of this package, not of the core: it is registered in the ``stereod.commands``
entry-point group, like the drivers in ``stereod.drivers``.
"""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING, Any

from stereod.cli.common import add_canonical_rig, number, path_arg, size_arg
from stereod.cli.progress import Progress
from stereod.errors import UsageError, describe_validation_error
from stereod.vision.detect_params import DetectorParams

if TYPE_CHECKING:
    from .synth import Ball, Scene

BALL_KEYS = {
    "heading": "heading_deg",
    "speed": "speed_mps",
    "radius": "radius_m",
    "vy": "vy_mps",
    "brightness": "brightness",
}


DEFAULT_SIZE = (640, 480)
"""``--size`` when none is given, px."""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "synth",
        help="render a synthetic stereo recording with ground truth",
        description="Render spheres moving on straight lines in front of a textured wall, seen "
        "by a canonical stereo rig, into a recording directory with truth.json.",
    )
    p.add_argument("out", type=path_arg, help="output recording directory")
    p.add_argument(
        "--ball",
        action="append",
        type=parse_ball,
        metavar="SPEC",
        help="a sphere as comma-separated key=value: heading (deg), speed (m/s), "
        "x, y, z (m, position at mid-time), radius (m), vy (m/s), brightness (grey); e.g. "
        "'heading=60,speed=0.7,z=1.8' (repeatable; default one such ball). A ball must lie "
        "between the camera and the wall 4 m away, fit in the view and be a few pixels wide",
    )
    p.add_argument(
        "--size",
        type=recording_size,
        default=DEFAULT_SIZE,
        metavar="WxH",
        help="image size, px: even numbers (default 640x480)",
    )
    p.add_argument(
        "--fps", type=number(0.1, 1000.0, unit="Hz"), default=15.0, help="frame rate, Hz (15)"
    )
    add_canonical_rig(p, defaults=True)
    p.add_argument(
        "--duration",
        type=number(0.0, 3600.0, lo_open=True, unit="s"),
        default=4.0,
        metavar="S",
        help="length, s (4)",
    )
    p.add_argument(
        "--lead-in",
        type=number(0.0, 3600.0, unit="s"),
        default=1.2,
        metavar="S",
        help="seconds of empty scene before the balls appear (background warm-up; default 1.2)",
    )
    p.add_argument(
        "--travel",
        type=number(0.0, 3600.0, lo_open=True, unit="s"),
        default=1.6,
        metavar="S",
        help="seconds each ball is in view, centred on its x, y, z (default 1.6)",
    )
    p.add_argument(
        "--noise",
        type=number(0.0, 100.0),
        default=1.5,
        metavar="GREY",
        help="sensor noise sigma, grey levels (default 1.5)",
    )
    p.add_argument(
        "--skew-ms",
        type=number(-1000.0, 1000.0, unit="ms"),
        default=0.0,
        metavar="MS",
        help="right eye's capture delay after the left, ms (default 0)",
    )
    p.add_argument(
        "--drift",
        type=number(0.0, 0.99),
        default=0.0,
        help="lighting gain amplitude, fraction (e.g. 0.05), period 20 s",
    )
    p.add_argument("--color", action="store_true", help="BGR frames instead of grey")
    p.add_argument(
        "--codec",
        choices=["ffv1", "mjpg"],
        default="ffv1",
        help="ffv1 lossless (default) or mjpg lossy",
    )
    p.add_argument("--seed", type=number(0, 2**32 - 1, integer=True), default=0, help="random seed")
    p.set_defaults(func=run)


def parse_ball(spec: str) -> dict[str, Any]:
    """One ``--ball`` spec as :class:`~.synth.Ball` fields (an argparse type: a bad spec is
    one line and exit 64)."""
    out: dict[str, Any] = {}
    centre = [0.0, 0.1, 1.8]
    given: set[str] = set()
    for part in filter(None, spec.split(",")):
        k, sep, v = part.partition("=")
        k = k.strip()
        if not sep:
            raise argparse.ArgumentTypeError(f"{spec!r}: expected key=value, got {part!r}")
        if k in given:
            raise argparse.ArgumentTypeError(f"{spec!r}: {k} is given twice: give it once")
        given.add(k)
        try:
            val = number(-1e6, 1e6)(v)
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{spec!r}: {k} = {v!r}: {exc}") from exc
        if k in ("x", "y", "z"):
            centre["xyz".index(k)] = val
        elif k in BALL_KEYS:
            out[BALL_KEYS[k]] = val
        else:
            raise argparse.ArgumentTypeError(
                f"{spec!r}: unknown key {k!r} (heading, speed, x, y, z, radius, vy, brightness)"
            )
    out["centre_m"] = tuple(centre)
    out[SPEC] = spec
    return out


SPEC = "_spec"
"""The key of :func:`parse_ball`'s result that keeps the spec as given, for messages."""


def ball_problem(scene: Scene, ball: Ball, *, move: bool = False) -> str | None:
    """Why ``ball`` cannot be seen in ``scene`` (its ``--ball`` key, the value and the range
    it must lie in), or None. At mid-travel the ball must lie between the camera and the wall
    without touching either, and its image must be large enough for the detector's smallest
    blob (a box of ``min_area_px``, the ball straddling pixels: one pixel narrower) and fit in
    the view. The range given is the radius's at
    the ball's z, or with ``move`` (the user gave z, not the radius) z's for its radius,
    whichever exists."""
    z, r, wall = ball.centre_m[2], ball.radius_m, scene.wall_m
    f = scene.rig.focal_px
    side = min(scene.width_px, scene.height_px)  # px: the widest image that fits
    smallest = math.sqrt(DetectorParams().min_area_px) - 1  # px: the narrowest one detected

    def radii(z: float) -> tuple[float, float]:  # the radii that work at depth z
        return smallest * z / (2 * f), min(side * z / (2 * f), z, wall - z)

    z_lo, z_hi = max(r, 2 * f * r / side), min(wall - r, 2 * f * r / smallest)
    r_lo, r_hi = radii(z) if 0 < z < wall else (1.0, 0.0)
    if r_lo <= r <= r_hi:
        return None
    across = 2 * f * r / z if z > 0 else math.inf
    if z <= 0:
        why = "is behind the camera"
    elif z >= wall:
        why = f"is at or behind the wall at {wall:g} m"
    elif r >= z:
        why = "holds the camera"
    elif r >= wall - z:
        why = f"reaches through the wall at {wall:g} m"
    elif r < r_lo:
        why = f"is {across:.2g} px across, too small to detect (under {smallest:.2g} px)"
    else:
        why = f"is {across:.0f} px across, more than the {scene.width_px}x{scene.height_px} view"
    ball_at = f"a ball of radius {r:g} m at z = {z:g} m {why}"
    radius_range = f"radius must be between {r_lo:.2g} and {r_hi:.2g} m at that z"
    z_range = f"z must be between {z_lo:.3g} and {z_hi:.3g} m for that radius"
    if 0 < z < wall and r_lo <= r_hi and not (move and z_lo <= z_hi):
        return f"{ball_at}; {radius_range}"
    if z_lo <= z_hi:
        return f"{ball_at}; {z_range}"
    largest = max(radii(wall * k / 1000)[1] for k in range(1, 1000))
    return f"{ball_at}; no z fits it: radius must be below {largest:.2g} m"


def travel_problem(scene: Scene, ball: Ball) -> str | None:
    """Why ``ball``, fine at mid-travel, cannot travel its whole path in ``scene``, or None: at
    the start or end of its travel (its depth is linear in time, so the ends bound it) it must
    still lie between the camera and the wall without touching either. A ball that leaves the
    view sideways or up and down is fine: objects cross the view."""
    wall, r = scene.wall_m, ball.radius_m
    for when, t in (("start", ball.t_on_s), ("end", ball.t_off_s)):
        z = float(ball.position_m(t)[2])
        if z - r <= 0:
            where = "at or behind the camera"
        elif z + r >= wall:
            where = f"through the wall at {wall:g} m"
        else:
            continue
        return (
            f"at the {when} of its travel ({t:g} s) it is at z = {z:.3g} m, {where}; "
            "give it a lower speed, a heading more across the view, or a shorter --travel"
        )
    return None


def recording_size(text: str) -> tuple[int, int]:
    """An argparse type: ``WxH`` that a recording stores as it is (even sides: the video
    writer would crop an odd one), so a bad ``--size`` is one line and exit 64."""
    from stereod.sources.recording import size_problem

    w, h = size_arg(text)
    problem = size_problem(w, h)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return w, h


def scene_from_args(a: argparse.Namespace) -> Scene:
    """The :class:`~.synth.Scene` described by ``stereod synth`` flags."""
    from pydantic import ValidationError

    from .synth import Scene

    w, h = a.size
    if not a.lead_in + a.travel <= a.duration:
        raise UsageError(
            f"--lead-in {a.lead_in} s + --travel {a.travel} s must fit in --duration {a.duration} s"
        )
    t_on, t_off = a.lead_in, a.lead_in + a.travel
    balls = [dict(b) for b in (a.ball or [parse_ball("")])]
    specs = [b.pop(SPEC) for b in balls]
    for b in balls:
        b.update(t_on_s=t_on, t_off_s=t_off, t_mid_s=(t_on + t_off) / 2)
    try:
        scene = Scene(
            width_px=w,
            height_px=h,
            fps=a.fps,
            hfov_deg=a.hfov,
            baseline_m=a.baseline,
            duration_s=a.duration,
            noise_sigma=a.noise,
            skew_s=a.skew_ms / 1e3,
            drift=a.drift,
            color=a.color,
            seed=a.seed,
            balls=balls,
        )
    except ValidationError as exc:
        given = {
            "width_px": f"--size {w}x{h}", "height_px": f"--size {w}x{h}", "fps": "--fps",
            "hfov_deg": "--hfov", "baseline_m": "--baseline", "duration_s": "--duration",
            "noise_sigma": "--noise", "skew_s": "--skew-ms", "drift": "--drift",
        }  # fmt: skip
        flags = dict.fromkeys(given.get(str(e["loc"][0]), "synth") for e in exc.errors())
        raise UsageError(f"{', '.join(flags)}: {describe_validation_error(exc)}") from exc
    for spec, ball in zip(specs, scene.balls, strict=True):
        keys = {part.partition("=")[0].strip() for part in spec.split(",")}
        move = "z" in keys and "radius" not in keys
        problem = ball_problem(scene, ball, move=move)
        if problem is not None and not a.ball and (w, h) != DEFAULT_SIZE:
            width, height = DEFAULT_SIZE
            usual = scene.model_copy(update={"width_px": width, "height_px": height})
            if ball_problem(usual, ball, move=move) is None:  # the size is what is off
                raise UsageError(
                    f"--size {w}x{h}: the default ball, {problem}; give a larger --size or "
                    "a --ball that fits (nothing was written)"
                )
        if problem is None:
            problem = travel_problem(scene, ball)
        if problem is not None:
            which = f"--ball {spec!r}" if a.ball else "the default ball (no --ball given)"
            raise UsageError(f"{which}: {problem} (nothing was written)")
    if scene.n_frames == 0:
        raise UsageError(
            f"--duration {a.duration:g} s at --fps {a.fps:g} Hz is not one frame: give a "
            f"--duration of at least {1 / a.fps:g} s or a higher --fps"
        )
    return scene


def run(a: argparse.Namespace) -> int:
    from stereod.sources.recording import Codec

    from .synth import write_scene

    scene = scene_from_args(a)
    with Progress("render", total=scene.n_frames, unit="pair") as bar:
        write_scene(scene, a.out, Codec(a.codec), on_pair=lambda k: bar.update(1))
    print(
        f"wrote {scene.n_frames} stereo frames ({scene.width_px}x{scene.height_px} at "
        f"{scene.fps:g} Hz) and truth.json to {a.out}"
    )
    return 0
