"""Throughput of the full pipeline (pair in, message out) beside two baselines.

For each image size, renders a synthetic scene into memory (a ball crossing a textured wall,
sensor noise), then times on the same pairs:

- stereod: ``Pipeline.process`` (detect both eyes, match, triangulate, track) plus building the
  wire payloads (the objects message and each track's state, each object serialised once by
  ``dump_objects``), as the daemon does per pair;
- naive: paper sec. II in float numpy + scipy.ndimage (``tests/detect_reference.py``), both eyes,
  detection only;
- MOG2: OpenCV's Gaussian-mixture background subtractor on both eyes plus connected components.

Each is timed in steady state: the pairs that make the detectors' initial background (a
one-time cost at start) are fed before the clock starts. Prints pairs/s and the ratios, the
CPU time a pair of stereod (one worker) and of MOG2 (the steadier measure on a loaded host), and
writes them as a table, with the host, to ``docs/bench/throughput-grey.md`` (or
``throughput-bgr.md`` with ``--color``), which the documentation's Performance page includes.
Usage: ``python benchmarks/throughput.py [--pairs N] [--sizes ...] [--color] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import cv2
import report

from stereod.bus.messages import dump_objects, objects_message
from stereod.pipeline import Pipeline, PipelineParams
from stereod.sources.frames import StereoPair
from stereod.vision.detect_params import DetectorParams
from stereod.vision.geometry import Geometry
from stereod_fakes.synth import Ball, Renderer, Scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.detect_reference import ReferenceDetector

SIZES = {"320x240": (320, 240), "640x480": (640, 480), "1280x720": (1280, 720)}


def render_pairs(w: int, h: int, n: int, color: bool = False) -> list[StereoPair]:
    """``n`` pairs with a ball in view in most of them, after a 10-frame empty lead-in."""
    fps = 15.0
    ball = Ball(
        heading_deg=60,
        speed_mps=0.7,
        t_on_s=10 / fps,
        t_off_s=1e9,
        t_mid_s=(n / 2) / fps,
        centre_m=(0.0, 0.1, 1.8),
    )
    scene = Scene(
        width_px=w, height_px=h, fps=fps, duration_s=(n + 0.5) / fps, balls=[ball], color=color
    )
    pairs = [StereoPair(k, left, right) for k, (left, right) in enumerate(Renderer(scene).frames())]
    return pairs


WARMUP = DetectorParams().warmup_frames + 1
"""Pairs fed before the clock starts: the detectors' warm-up frames, and one more, since eq. 3
with a pair's frame (here: the last warm-up frame, which makes the initial background) runs
when the next pair is detected."""


class Rate(NamedTuple):
    """Pairs per second of wall-clock time and per second of the process's CPU time (all its
    threads): on a host others load, the CPU rate is the steadier of the two."""

    wall: float
    cpu: float

    def best(self, other: Rate) -> Rate:
        return Rate(max(self.wall, other.wall), max(self.cpu, other.cpu))


def timed(fn: Callable[[StereoPair], object], pairs: list[StereoPair], repeat: int) -> Rate:
    """Best pairs/s over ``repeat`` passes of ``fn`` over the pairs after the first
    ``WARMUP`` (fed untimed first: the start-up of a detector's background), by the wall clock
    and by CPU time."""
    best = Rate(0.0, 0.0)
    for _ in range(repeat):
        for p in pairs[:WARMUP]:
            fn(p)
        t0, c0 = time.perf_counter(), time.process_time()
        for p in pairs[WARMUP:]:
            fn(p)
        n = len(pairs) - WARMUP
        rate = Rate(n / (time.perf_counter() - t0), n / max(time.process_time() - c0, 1e-9))
        best = best.best(rate)
    return best


def bench_stereod(pairs: list[StereoPair], w: int, h: int, workers: int, repeat: int) -> Rate:
    from stereod.vision.geometry.stereo import CanonicalRig

    best = Rate(0.0, 0.0)
    for _ in range(repeat):
        rig = CanonicalRig(0.06, 60.0, w, h)
        pipe = Pipeline(PipelineParams(rig, DetectorParams(), detect_workers=workers))

        def step(p: StereoPair, pipe: Pipeline = pipe) -> None:
            msg = objects_message(
                pipe.process(p),
                rig="bench",
                geometry=Geometry.CANONICAL,
                calibration_id=None,
                utc_offset_ns=0,
            )
            dump_objects(msg)  # the objects payload and each object's, as the daemon sends them

        best = best.best(timed(step, pairs, 1))
        pipe.close()
    return best


def bench_naive(pairs: list[StereoPair], repeat: int) -> Rate:
    best = Rate(0.0, 0.0)
    for _ in range(repeat):
        left, right = ReferenceDetector(DetectorParams()), ReferenceDetector(DetectorParams())

        def step(
            p: StereoPair, left: ReferenceDetector = left, right: ReferenceDetector = right
        ) -> None:
            left.detect(p.left.image)
            right.detect(p.right.image)

        best = best.best(timed(step, pairs, 1))
    return best


def bench_mog2(pairs: list[StereoPair], repeat: int) -> Rate:
    best = Rate(0.0, 0.0)
    for _ in range(repeat):
        subs = [cv2.createBackgroundSubtractorMOG2(detectShadows=False) for _ in range(2)]

        def step(p: StereoPair, subs: list[cv2.BackgroundSubtractorMOG2] = subs) -> None:
            for sub, img in zip(subs, (p.left.image, p.right.image), strict=True):
                fg = sub.apply(img)
                cv2.connectedComponentsWithStats(fg, connectivity=8, ltype=cv2.CV_16U)

        best = best.best(timed(step, pairs, 1))
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=120, help="pairs per size (default 120)")
    ap.add_argument("--repeat", type=int, default=3, help="passes; the best is kept (default 3)")
    ap.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES))
    ap.add_argument(
        "--color",
        action="store_true",
        help="BGR frames (a colour video) instead of grey (a camera's Y plane)",
    )
    ap.add_argument(
        "--opencv-threads",
        type=int,
        default=None,
        help="cv2.setNumThreads (default: OpenCV's own choice)",
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=report.DOCS_BENCH,
        help="folder of the markdown table (default docs/bench)",
    )
    a = ap.parse_args()
    host = report.host()
    if a.opencv_threads is not None:
        cv2.setNumThreads(a.opencv_threads)
    print(
        f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} OpenCV threads, "
        f"{a.pairs} {'BGR' if a.color else 'grey'} pairs per size, best of {a.repeat}"
    )
    header = (
        f"{'size':>9} {'stereod 1 worker':>17} {'stereod 2 workers':>18} "
        f"{'naive numpy':>12} {'MOG2+CC':>9} {'vs naive':>9} {'vs MOG2':>8} "
        f"{'CPU a pair: stereod':>20} {'MOG2+CC':>8} {'vs MOG2':>8}"
    )
    print(header)
    print("-" * len(header))
    frames = "BGR" if a.color else "grey"
    rows = [
        "| size | frames | stereod, 1 detect worker | stereod, 2 workers | naive numpy "
        "| MOG2 + CC | vs naive | vs MOG2 | CPU a pair: stereod, 1 worker | MOG2 + CC "
        "| vs MOG2, by CPU |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in a.sizes:
        w, h = SIZES[name]
        pairs = render_pairs(w, h, a.pairs, a.color)
        one = bench_stereod(pairs, w, h, 1, a.repeat)
        two = bench_stereod(pairs, w, h, 2, a.repeat)
        naive = bench_naive(pairs[: max(20, a.pairs // 4)], 1).wall
        mog = bench_mog2(pairs, a.repeat)
        best = max(one.wall, two.wall)
        cpu_ms, mog_ms = 1e3 / one.cpu, 1e3 / mog.cpu
        print(
            f"{name:>9} {one.wall:13.0f} p/s {two.wall:14.0f} p/s {naive:8.0f} p/s "
            f"{mog.wall:5.0f} p/s {best / naive:8.1f}x {best / mog.wall:7.1f}x "
            f"{cpu_ms:17.2f} ms {mog_ms:5.2f} ms {mog_ms / cpu_ms:7.1f}x",
            flush=True,
        )
        rows.append(
            f"| {name} | {frames} | {one.wall:.0f} pairs/s | {two.wall:.0f} pairs/s "
            f"| {naive:.0f} pairs/s | {mog.wall:.0f} pairs/s | {best / naive:.1f}x "
            f"| {best / mog.wall:.1f}x | {cpu_ms:.2f} ms | {mog_ms:.2f} ms "
            f"| {mog_ms / cpu_ms:.1f}x |"
        )
    print(
        "p/s = stereo pairs per second; stereod includes matching, triangulation, tracking "
        "and JSON payloads; the baselines only detect. CPU a pair: the process's CPU time "
        "(all its threads) per pair."
    )
    text = "\n\n".join(
        [
            f"{host} OpenCV threads: {cv2.getNumThreads()}; {a.pairs} {frames} pairs per size, "
            f"best of {a.repeat} (`make bench`).",
            "\n".join(rows),
        ]
    )
    print(f"wrote {report.write(f'throughput-{frames.lower()}.md', text, a.out)}")


if __name__ == "__main__":
    main()
