"""What people in view cost, on real footage, beside MOG2 plus connected components.

The throughput scene is one small ball; a room holds people, whose blobs are large, ragged
and cast shadows. This runs real footage of pedestrians (``vtest.avi``, DATA.md: 768x576 at
10 fps, several people in view in most frames) scaled to each size, as a stereo pair whose
right eye is the left shifted by a fixed disparity (12 px at 768 px across, scaled with the
width), through the full pipeline (pair in, JSON payloads out), one detect worker, steady
state (the detectors' warm-up frames fed first), at the footage's own instants. Per pair it
takes the process's CPU time (all its threads, OpenCV's included) and gives its mean,
median, 90th percentile and largest; then the mean with ``[detector] shadows = false`` (no
shadow test and no near-object test; the blobs then keep their shadows, so the difference is
not the tests' cost alone), and MOG2 + CC's on both eyes of the same frames. Writes
``docs/bench/people.md``.

Usage: ``python benchmarks/people.py [--frames 200] [--sizes 320x240 640x480] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import report
from throughput import WARMUP, bench_mog2

from stereod.bus.messages import dump_objects, objects_message
from stereod.pipeline import Pipeline, PipelineParams
from stereod.sources.frames import StereoPair
from stereod.vision.detect_params import DetectorParams
from stereod.vision.geometry import Geometry
from stereod.vision.geometry.stereo import CanonicalRig

ROOT = Path(__file__).resolve().parents[1]
VIDEO = ROOT.parent / "shared" / "data" / "video" / "vtest.avi"
SIZES = {"320x240": (320, 240), "640x480": (640, 480), "768x576": (768, 576)}
SHIFT_PX_AT_768 = 12
"""The right eye's shift at the footage's own width (as ``tests/test_grouping.py`` uses it)."""
PERIOD_NS = 100_000_000
"""The footage's frame period (10 fps)."""


def read_frames(path: Path, n: int) -> list[np.ndarray]:
    """The first ``n`` frames of the video (BGR); exits with a one-line error if it cannot."""
    if not path.is_file():
        sys.exit(f"error: {path}: not found (the shared data folder must sit beside the project)")
    cap = cv2.VideoCapture(str(path))
    frames: list[np.ndarray] = []
    try:
        while len(frames) < n:
            ok, img = cap.read()
            if not ok:
                break
            frames.append(img)
    finally:
        cap.release()
    if len(frames) <= WARMUP:
        sys.exit(f"error: {path}: only {len(frames)} frames decoded, need more than {WARMUP}")
    return frames


def stereo_pairs(frames: list[np.ndarray], w: int, h: int) -> list[StereoPair]:
    """The frames scaled to ``w`` x ``h`` as stereo pairs: the right eye the left shifted."""
    shift = np.array([[1.0, 0.0, -SHIFT_PX_AT_768 * w / 768], [0.0, 1.0, 0.0]], np.float32)
    pairs = []
    for k, img in enumerate(frames):
        left = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA) if img.shape[1] != w else img
        right = cv2.warpAffine(left, shift, (w, h), borderMode=cv2.BORDER_REPLICATE)
        t = 1_000_000_000 + k * PERIOD_NS
        pairs.append(StereoPair.of(left, right, t, t, seq=k))
    return pairs


def stereod_ms(pairs: list[StereoPair], w: int, h: int, shadows: bool) -> tuple[np.ndarray, int]:
    """Each measured pair's CPU time (ms) through the pipeline and its payloads, and the
    median number of tracks a pair."""
    params = PipelineParams(CanonicalRig(0.200, 60.0, w, h), DetectorParams(shadows=shadows))
    cpu, tracks = [], []
    with Pipeline(params) as pipe:
        for k, pair in enumerate(pairs):
            c0 = time.process_time()
            result = pipe.process(pair)
            dump_objects(
                objects_message(
                    result,
                    rig="bench",
                    geometry=Geometry.CANONICAL,
                    calibration_id=None,
                    utc_offset_ns=0,
                )
            )
            if k >= WARMUP:
                cpu.append((time.process_time() - c0) * 1e3)
                tracks.append(len(result.tracks))
    return np.array(cpu), int(np.median(tracks))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200, help="frames of the footage (200)")
    ap.add_argument("--sizes", nargs="+", default=["320x240", "640x480"], choices=list(SIZES))
    ap.add_argument("--video", type=Path, default=VIDEO, help="the footage (vtest.avi)")
    ap.add_argument(
        "--out", type=Path, default=report.DOCS_BENCH, help="folder of the table (docs/bench)"
    )
    a = ap.parse_args()
    host = report.host()
    frames = read_frames(a.video, a.frames)
    rows = [
        "| size | tracks a pair, median | stereod CPU a pair: mean / p50 / p90 / max "
        "| `shadows = false`, mean | MOG2 + CC, mean | vs MOG2, by CPU |",
        "|---|---:|---|---:|---:|---:|",
    ]
    for name in a.sizes:
        w, h = SIZES[name]
        pairs = stereo_pairs(frames, w, h)
        ms, tracks = stereod_ms(pairs, w, h, shadows=True)
        plain, _ = stereod_ms(pairs, w, h, shadows=False)
        mog = 1e3 / bench_mog2(pairs, 1).cpu  # ms a pair, the same pairs measured
        p50, p90 = np.percentile(ms, [50, 90])
        row = (
            f"| {name} | {tracks} | {ms.mean():.1f} / {p50:.1f} / {p90:.1f} / {ms.max():.1f} ms "
            f"| {plain.mean():.1f} ms | {mog:.1f} ms | {mog / ms.mean():.2f}x |"
        )
        print(row, flush=True)
        rows.append(row)
    text = "\n\n".join(
        [
            f"{host} OpenCV threads: {cv2.getNumThreads()}; `{a.video.name}`, {len(frames)} frames "
            f"({len(frames) - WARMUP} measured), BGR (`python benchmarks/people.py`).",
            "\n".join(rows),
        ]
    )
    print(f"wrote {report.write('people.md', text, a.out)}")


if __name__ == "__main__":
    main()
