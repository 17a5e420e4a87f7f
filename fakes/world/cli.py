"""``python -m stereod_fakes.world PRESET [OUT_DIR]``: render a preset scene to a folder."""

from __future__ import annotations

import argparse
import inspect
import sys
import time
from collections.abc import Sequence
from dataclasses import replace

from ._base import MODE_320x240_30, MODE_640x480_15, Skew
from .files import write_scene
from .presets_room import PRESETS
from .transport import Transport

EX_USAGE = 64  # sysexits.h: the command was used incorrectly


def main(argv: Sequence[str] | None = None) -> int:
    """Quick look: ``python -m stereod_fakes.world robot_ball OUT_DIR [--vga] [--bench]``."""
    ap = argparse.ArgumentParser(
        prog="python -m stereod_fakes.world",
        description="Render a preset scene of the independent stereo renderer to a folder.",
    )
    ap.add_argument("preset", choices=sorted(PRESETS))
    ap.add_argument("out_dir", nargs="?")
    ap.add_argument("--vga", action="store_true", help="640x480 at 15 fps (default 320x240@30)")
    ap.add_argument("--hfov", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skew", default="0", help="fraction of a frame or 'wander'")
    ap.add_argument("--bench", action="store_true", help="time the rendering of frame pairs")
    ap.add_argument("--stop", type=float, metavar="S", help="stop length, s (person_sit_walk, "
                    "robot_stop_go)")  # fmt: skip
    ap.add_argument("--lit", action="store_true", help="a ceiling lamp with shadows (people)")
    ap.add_argument("--rolling-shutter", type=float, nargs="?", const=0.030, metavar="READOUT_S",
                    help="rolling shutter with this readout, s (default 0.030)")  # fmt: skip
    ap.add_argument("--yuyv", action="store_true", help="4:2:2 chroma subsampling (YUYV)")
    ap.add_argument("--mjpeg", type=int, default=0, metavar="Q", help="MJPEG quality 1..100")
    ap.add_argument("--flicker", type=float, default=0.0, metavar="DEPTH",
                    help="100 Hz mains flicker depth, 0..1")  # fmt: skip
    a = ap.parse_args(argv)
    skew: Skew = "wander" if a.skew == "wander" else float(a.skew)
    mode = MODE_640x480_15 if a.vga else MODE_320x240_30
    make = PRESETS[a.preset]
    kw: dict[str, object] = {}
    for flag, name, value in (("--stop", "stop_s", a.stop), ("--lit", "lit", a.lit or None)):
        if value is None:
            continue
        if name not in inspect.signature(make).parameters:
            print(f"python -m stereod_fakes.world: {flag}: preset {a.preset} has no {name}; "
                  "leave the flag out", file=sys.stderr)  # fmt: skip
            return EX_USAGE
        kw[name] = value
    scene = make(mode=mode, hfov_deg=a.hfov, seed=a.seed, skew=skew, **kw)
    try:
        transport = Transport(
            rolling_shutter=a.rolling_shutter is not None,
            readout_s=0.030 if a.rolling_shutter is None else a.rolling_shutter,
            yuyv_422=a.yuyv,
            mjpeg_quality=a.mjpeg,
            flicker_depth=a.flicker,
        )
    except ValueError as exc:
        flags = {"readout": "--rolling-shutter", "mjpeg": "--mjpeg", "flicker": "--flicker"}
        bad = next((f for k, f in flags.items() if k in str(exc)), "transport")
        print(f"python -m stereod_fakes.world: {bad}: {exc}", file=sys.stderr)
        return EX_USAGE
    scene = replace(scene, transport=transport)
    print(f"{scene.name}: {scene.duration_s:.2f} s, "
          f"{len(scene.frame_times('left'))}+{len(scene.frame_times('right'))} frames")  # fmt: skip
    if a.bench:
        times = scene.all_frame_times()
        scene.render("left", times[0])
        scene.render("right", times[0])
        t0 = time.perf_counter()
        for t in times[::4]:
            scene.render("left", t)
            scene.render("right", t)
        print(f"{(time.perf_counter() - t0) / len(times[::4]) * 1e3:.1f} ms per pair")
    if a.out_dir:
        print(write_scene(scene, a.out_dir))
    return 0
