"""What a pair costs the pipeline at a camera's pace, against back to back.

The daemon at 30 Hz spends more CPU a pair than ``throughput.py``'s tight loop does. This runs
the same pairs of ``benchmarks/latency.py``'s scene (the daemon's synthetic camera: a ball
crossing the view again and again, sensor noise, the right eye half a frame late) through
``Pipeline.process`` and the objects message three ways, in one process:

- ``back to back``: one pair after the other;
- ``sleeping``: a pause of one frame period (1/fps) after each pair, as a camera's pace gives;
- ``busy``: the same pause spent spinning in a loop, the core kept busy.

Each figure is the thread's CPU time a pair (ms: mean, p50, p90) after a warm-up. If
``busy`` costs what ``sleeping`` does, the extra cost is the time between pairs (caches and
predictors gone cold), not the core's idle states.

Usage: ``python benchmarks/paced.py [--size 320x240] [--pairs 600] [--fps 30] [--grey]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomllib

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import latency

from stereod.bus.messages import dump_objects, objects_message
from stereod.daemon.config import load_config
from stereod.daemon.params import pipeline_params
from stereod.pipeline import Pipeline
from stereod.sources.frames import StereoPair
from stereod.vision.geometry import Geometry
from stereod_fakes.synth import SyntheticDriver

WARMUP_PAIRS = 60
"""Pairs run untimed first: the background's start-up and the ball's first crossing."""


def pairs_of(toml: str, path: Path, n: int) -> tuple[list[StereoPair], Pipeline]:
    """``n`` pairs of the daemon's scene in ``toml`` (read whole, not live) and the pipeline
    the daemon would build for it."""
    path.write_text(toml)
    cfg = load_config(path)
    opts = tomllib.loads(toml)["driver"]["options"]
    opts["live"] = False
    src = SyntheticDriver(opts).open()
    pairs = [StereoPair(k, src.left.read(), src.right.read()) for k in range(n)]
    return pairs, Pipeline(pipeline_params(cfg, opts["width_px"], opts["height_px"]))


def cost_ms(pairs: list[StereoPair], pipe: Pipeline, pause_s: float, busy: bool) -> np.ndarray:
    """The thread CPU time (ms) of each pair after the warm-up, with ``pause_s`` after each
    (slept, or spun when ``busy``)."""
    out = []
    for k, pair in enumerate(pairs):
        t0 = time.thread_time()
        result = pipe.process(pair)
        msg = objects_message(
            result, rig="bench", geometry=Geometry.CANONICAL, calibration_id=None, utc_offset_ns=0
        )
        dump_objects(msg)
        if k >= WARMUP_PAIRS:
            out.append(time.thread_time() - t0)
        if busy:
            end = time.perf_counter() + pause_s
            while time.perf_counter() < end:
                pass
        elif pause_s > 0:
            time.sleep(pause_s)
    return np.array(out) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="320x240", choices=["320x240", "640x480"])
    ap.add_argument("--pairs", type=int, default=600, help="pairs a way (default 600)")
    ap.add_argument("--fps", type=float, default=30.0, help="the camera's rate (default 30)")
    ap.add_argument("--grey", action="store_true", help="grey frames instead of BGR")
    a = ap.parse_args()
    if a.pairs <= WARMUP_PAIRS:
        ap.error(f"--pairs must be more than the {WARMUP_PAIRS} warm-up pairs")
    w, h = (int(v) for v in a.size.split("x"))
    toml = latency.config("tcp/127.0.0.1:0", w, h, a.fps, not a.grey)
    print(f"{a.size} {'grey' if a.grey else 'BGR'}, {a.pairs - WARMUP_PAIRS} timed pairs a way")
    with tempfile.TemporaryDirectory() as tmp:
        for name, pause, busy in (
            ("back to back", 0.0, False),
            ("sleeping", 1.0 / a.fps, False),
            ("busy", 1.0 / a.fps, True),
        ):
            pairs, pipe = pairs_of(toml, Path(tmp) / "scene.toml", a.pairs)
            with pipe:
                c = cost_ms(pairs, pipe, pause, busy)
            print(
                f"{name:>13}: mean {c.mean():.2f}  p50 {np.median(c):.2f}  "
                f"p90 {np.percentile(c, 90):.2f} ms a pair"
            )


if __name__ == "__main__":
    main()
