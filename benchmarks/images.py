"""What images on the bus cost the real daemon: pairs/s with no image subscriber against images
turned off, and with a subscriber on every image key, at the default rate and at every pair.

Renders a synthetic scene once into a recording (FFV1), then replays it through the daemon as
fast as possible (``rate = 0``, file source: nothing is dropped) publishing on a loopback Zenoh
endpoint, for each case:

- off: ``daemon.image_rate_hz = 0`` (no image publisher at all);
- no subscriber: images on at the default rate, nobody listening (the cost rule: unchanged);
- subscribed: a session subscribed to ``image/*`` (left, right, overlay, mask) at the default
  rate, then at 100 Hz (every pair the encoder can take: the drawing and encoding cost).

The cases take turns, ``--repeat`` rounds, and each keeps its best pairs/s (the machine's other
load only ever slows a run down). Prints pairs/s, images received by the subscriber, and the
image thread's time per pictured pair, and the process's CPU time per pair (all threads; less
sensitive than pairs/s to what else the machine runs), and writes both tables, with the host,
to ``docs/bench/images.md``, which the documentation's Performance page includes.

Usage: ``python benchmarks/images.py [--pairs N] [--size WxH] [--repeat R] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import report
import zenoh

from stereod.bus.publish import session_config
from stereod.daemon.config import ZenohConfig, load_config
from stereod.daemon.daemon import Daemon
from stereod.pipeline import Pipeline, PipelineParams
from stereod.sources.drivers import load_driver
from stereod.sources.frames import StereoPair
from stereod.view import overlay
from stereod.view.overlay import Annotations, PairImages
from stereod_fakes.synth import Ball, Renderer, Scene, write_scene


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def run_once(rec: Path, endpoint: str, rate_hz: float | None) -> tuple[float, float, Daemon]:
    """Replay ``rec`` once; (pairs/s, CPU ms per pair, the daemon). ``rate_hz`` None: the
    default rate."""
    daemon_cfg = {} if rate_hz is None else {"image_rate_hz": rate_hz}
    cfg = load_config(overrides={"zenoh": {"connect": [endpoint]}, "daemon": daemon_cfg})
    daemon = Daemon(cfg, load_driver("replay", {"path": rec}), rate=0.0)
    t0, c0 = time.perf_counter(), time.process_time()
    summary = daemon.run()
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    if summary.error is not None:
        raise summary.error
    return summary.pairs / elapsed, cpu / summary.pairs * 1e3, daemon


def encode_costs(scene: Scene, repeat: int = 50) -> dict[str, float]:
    """Median ms to make each image of one pair with a confirmed track, on this thread."""
    pipe = Pipeline(PipelineParams(scene.rig))
    result, images = None, None
    for k, (left, right) in enumerate(Renderer(scene).frames()):
        result = pipe.process(StereoPair(k, left, right))
        if any(s.velocity_valid for s in result.tracks):
            images = PairImages(
                left.image, right.image, pipe.left.mask, pipe.right.mask, pipe.params.rig
            )
            break
    pipe.close()
    assert result is not None and images is not None, "the scene never gave a track"
    ann = Annotations(
        result.seq, result.t_ns, result.skew_ns, result.left, result.right, result.tracks
    )
    makers = {
        "left": lambda: overlay.jpeg(images.left),
        "right": lambda: overlay.jpeg(images.right),
        "overlay": lambda: overlay.jpeg(overlay.overlay(images, ann)),
        "mask": lambda: overlay.jpeg(overlay.masks(images)),
    }
    out = {}
    for name, make in makers.items():
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            make()
            times.append(time.perf_counter() - t0)
        out[name] = float(np.median(times)) * 1e3
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=300, help="pairs in the scene (default 300)")
    ap.add_argument("--size", default="640x480", help="image size WxH (default 640x480)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per case; best kept (3)")
    ap.add_argument(
        "--out",
        type=Path,
        default=report.DOCS_BENCH,
        help="folder of the markdown tables (default docs/bench)",
    )
    a = ap.parse_args()
    host = report.host()
    w, h = (int(x) for x in a.size.split("x"))
    fps = 15.0
    n = a.pairs
    ball = Ball(heading_deg=60, speed_mps=0.3, t_on_s=1.0, t_off_s=1e9, t_mid_s=n / fps / 2)
    scene = Scene(width_px=w, height_px=h, fps=fps, duration_s=(n + 0.5) / fps, balls=[ball])
    costs = encode_costs(scene)
    print(
        f"drawing and JPEG-encoding one {w}x{h} pair (median, ms): "
        + ", ".join(f"{k} {v:.1f}" for k, v in costs.items())
        + f"; all four {sum(costs.values()):.1f}"
    )
    with tempfile.TemporaryDirectory(prefix="stereod-bench-") as tmp:
        rec = write_scene(scene, Path(tmp) / "rec")
        endpoint = free_endpoint()
        zc = session_config(ZenohConfig(listen=[endpoint]))
        with zenoh.open(zc) as session:
            got = {"n": 0}
            lock = threading.Lock()

            def on_image(_sample: zenoh.Sample) -> None:
                with lock:
                    got["n"] += 1

            print(f"{n} pairs of {w}x{h}, replayed as fast as possible, best of {a.repeat}")
            header = (
                f"{'case':<34}{'pairs/s':>9}{'vs off':>8}{'CPU ms/pair':>13}{'images':>8}"
                f"{'ms per pictured pair':>22}"
            )
            print(header)
            print("-" * len(header))
            cases: list[tuple[str, float | None, bool]] = [
                ("images off (image_rate_hz = 0)", 0.0, False),
                ("no image subscriber (5 Hz)", None, False),
                ("image/* subscribed, 5 Hz", None, True),
                ("image/* subscribed, every pair", 100.0, True),
            ]
            best = [0.0] * len(cases)
            cpu = [float("inf")] * len(cases)
            images = [0] * len(cases)
            per_ms = [float("nan")] * len(cases)
            for _ in range(a.repeat):
                for k, (_, rate_hz, subscribed) in enumerate(cases):
                    sub = (
                        session.declare_subscriber("stereod/minoru/image/*", on_image)
                        if subscribed
                        else None
                    )
                    with lock:
                        got["n"] = 0
                    pps, cpu_ms, daemon = run_once(rec, endpoint, rate_hz)
                    cpu[k] = min(cpu[k], cpu_ms)
                    time.sleep(0.2)  # the last images reach the subscriber
                    if sub is not None:
                        sub.undeclare()
                    if pps > best[k]:
                        best[k] = pps
                        with lock:
                            images[k] = got["n"]
                        worker = daemon.images
                        pictured = max(worker.encoded.values()) if worker else 0
                        if worker and pictured:
                            per_ms[k] = worker.encode_s / pictured * 1e3
            rows = [
                "| case | pairs/s | vs off | CPU ms per pair (all threads) | images received "
                "| ms per pictured pair |",
                "|---|---|---|---|---|---|",
            ]
            for k, (name, _, _) in enumerate(cases):
                per = f"{per_ms[k]:.1f}" if per_ms[k] == per_ms[k] else "-"
                print(
                    f"{name:<34}{best[k]:9.0f}{best[k] / best[0]:8.2f}{cpu[k]:13.2f}"
                    f"{images[k]:8d}{per:>22}"
                )
                rows.append(
                    f"| {name} | {best[k]:.0f} | {best[k] / best[0]:.2f} | {cpu[k]:.2f} "
                    f"| {images[k]} | {per} |"
                )
    print(
        "pictured pair = left + right + overlay + mask drawn and JPEG-encoded (quality 80) on "
        "the image thread; the pipeline and output threads never wait for it."
    )
    encode_rows = ["| image | ms (median, one thread) |", "|---|---|"]
    encode_rows += [f"| {k} | {v:.1f} |" for k, v in costs.items()]
    encode_rows.append(f"| all four | {sum(costs.values()):.1f} |")
    text = "\n\n".join(
        [
            f"{host} {w}x{h}, {n} pairs, best of {a.repeat} rounds (`make bench`).",
            f"Drawing and JPEG-encoding the images of one {w}x{h} pair with a track:",
            "\n".join(encode_rows),
            "The real daemon replaying a recording as fast as it can, publishing on loopback, "
            "the cases taking turns:",
            "\n".join(rows),
        ]
    )
    print(f"wrote {report.write('images.md', text, a.out)}")


if __name__ == "__main__":
    sys.exit(main())
