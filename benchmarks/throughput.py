"""Throughput of the full pipeline (pair in, message out) beside two baselines.

For each image size, renders a synthetic scene into memory (a ball crossing a textured wall,
sensor noise), then times on the same pairs:

- stereod: ``Pipeline.process`` (detect both eyes, match, triangulate, track) plus building the
  wire payloads (objects message and per-track states), as the daemon does per pair;
- naive: paper sec. II in float numpy + scipy.ndimage (``tests/detect_reference.py``), both eyes,
  detection only;
- MOG2: OpenCV's Gaussian-mixture background subtractor on both eyes plus connected components.

Each is timed in steady state: the pairs that make the detectors' initial background (a
one-time cost at start) are fed before the clock starts. Prints pairs/s and the ratios, and
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

import cv2
import report

from stereod.bus.messages import dump, objects_message
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


def timed(fn: Callable[[StereoPair], object], pairs: list[StereoPair], repeat: int) -> float:
    """Best pairs/s over ``repeat`` passes of ``fn`` over the pairs after the first
    ``WARMUP`` (fed untimed first: the start-up of a detector's background)."""
    best = 0.0
    for _ in range(repeat):
        for p in pairs[:WARMUP]:
            fn(p)
        t0 = time.perf_counter()
        for p in pairs[WARMUP:]:
            fn(p)
        best = max(best, (len(pairs) - WARMUP) / (time.perf_counter() - t0))
    return best


def bench_stereod(pairs: list[StereoPair], w: int, h: int, workers: int, repeat: int) -> float:
    from stereod.vision.geometry.stereo import CanonicalRig

    best = 0.0
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
            dump(msg)
            for o in msg.objects:
                dump(o)

        best = max(best, timed(step, pairs, 1))
        pipe.close()
    return best


def bench_naive(pairs: list[StereoPair], repeat: int) -> float:
    best = 0.0
    for _ in range(repeat):
        left, right = ReferenceDetector(DetectorParams()), ReferenceDetector(DetectorParams())

        def step(
            p: StereoPair, left: ReferenceDetector = left, right: ReferenceDetector = right
        ) -> None:
            left.detect(p.left.image)
            right.detect(p.right.image)

        best = max(best, timed(step, pairs, 1))
    return best


def bench_mog2(pairs: list[StereoPair], repeat: int) -> float:
    best = 0.0
    for _ in range(repeat):
        subs = [cv2.createBackgroundSubtractorMOG2(detectShadows=False) for _ in range(2)]

        def step(p: StereoPair, subs: list[cv2.BackgroundSubtractorMOG2] = subs) -> None:
            for sub, img in zip(subs, (p.left.image, p.right.image), strict=True):
                fg = sub.apply(img)
                cv2.connectedComponentsWithStats(fg, connectivity=8, ltype=cv2.CV_16U)

        best = max(best, timed(step, pairs, 1))
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
        f"{'naive numpy':>12} {'MOG2+CC':>9} {'vs naive':>9} {'vs MOG2':>8}"
    )
    print(header)
    print("-" * len(header))
    frames = "BGR" if a.color else "grey"
    rows = [
        "| size | frames | stereod, 1 detect worker | stereod, 2 workers | naive numpy "
        "| MOG2 + CC | vs naive | vs MOG2 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in a.sizes:
        w, h = SIZES[name]
        pairs = render_pairs(w, h, a.pairs, a.color)
        one = bench_stereod(pairs, w, h, 1, a.repeat)
        two = bench_stereod(pairs, w, h, 2, a.repeat)
        naive = bench_naive(pairs[: max(20, a.pairs // 4)], 1)
        mog = bench_mog2(pairs, a.repeat)
        best = max(one, two)
        print(
            f"{name:>9} {one:13.0f} p/s {two:14.0f} p/s {naive:8.0f} p/s {mog:5.0f} p/s "
            f"{best / naive:8.1f}x {best / mog:7.1f}x",
            flush=True,
        )
        rows.append(
            f"| {name} | {frames} | {one:.0f} pairs/s | {two:.0f} pairs/s | {naive:.0f} pairs/s "
            f"| {mog:.0f} pairs/s | {best / naive:.1f}x | {best / mog:.1f}x |"
        )
    print(
        "p/s = stereo pairs per second; stereod includes matching, triangulation, tracking "
        "and JSON payloads; the baselines only detect."
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
