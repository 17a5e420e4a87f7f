"""``python -m stereod_fakes.world PRESET [OUT_DIR]``: render a preset scene to a folder."""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence

from ._base import MODE_320x240_30, MODE_640x480_15, Skew
from .files import write_scene
from .presets_room import PRESETS


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
    a = ap.parse_args(argv)
    skew: Skew = "wander" if a.skew == "wander" else float(a.skew)
    mode = MODE_640x480_15 if a.vga else MODE_320x240_30
    scene = PRESETS[a.preset](mode=mode, hfov_deg=a.hfov, seed=a.seed, skew=skew)
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
