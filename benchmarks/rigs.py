"""Four rigs on one host: four daemons at 320x240, 30 Hz, BGR, each on its own live camera.

A lab PC may carry several stereo webcams, one ``stereod run`` each. This starts four daemons
(``stereod run`` processes, the ``synthetic`` driver in live mode: each eye delivers its
frames at their capture instants on this host's CLOCK_MONOTONIC, a ball crossing the view
again and again, the right eye half a frame late), each publishing its rig's keys on a
loopback endpoint of its own, and subscribes to all four ``objects`` keys from this process.
After a warm-up it measures for ``--seconds`` (default 5 minutes), then reports per daemon:

- pairs: the pairs its pairer made in the window and the messages that arrived here;
- dropped: pairs the daemon made but did not publish (its ``stats`` drops: pipeline or
  publishing behind), frames its pairer found no partner for (a capture thread late), and
  gaps in the sequence numbers that arrived here;
- p50 and p99 latency from the pair's later capture to the message's arrival here (see
  ``benchmarks/latency.py``);
- CPU (share of one core) and RSS, the synthetic camera's share of it (measured apart, as in
  ``benchmarks/latency.py``) and the daemon's own.

Targets: no pair dropped, each daemon's p99 at most 10 ms. Writes ``docs/bench/rigs.md``.
Usage: ``python benchmarks/rigs.py [--seconds 300] [--rigs 4] [--size 320x240] [--fps 30]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import report
from latency import camera_mb, config, free_endpoint, proc_cpu_s, proc_mem_mb, stats

from tests.processes import start_stereod

TARGET_P99_MS = 10.0
"""Each daemon's p99 latency (ms) at most this."""


BEHIND = ("pipeline_behind", "publish_behind")
"""The ``stats`` drops that are pairs made and not published (the rest are frames the pairer
found no partner for)."""


def drops(before: dict, after: dict) -> tuple[int, int]:
    """(pairs a daemon made and did not publish, frames it paired with nothing) between two
    of its ``stats`` replies."""
    pairs = frames = 0
    for key, n in after["drops"].items():
        d = int(n) - int(before["drops"].get(key, 0))
        if key in BEHIND:
            pairs += d
        else:
            frames += d
    return pairs, frames


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=300.0, help="measured time, s (300)")
    ap.add_argument("--warmup", type=float, default=5.0, help="ignored first seconds (5)")
    ap.add_argument("--rigs", type=int, default=4, help="daemons (4)")
    ap.add_argument("--size", default="320x240", help="image size, px (320x240)")
    ap.add_argument("--fps", type=float, default=30.0, help="frame rate per eye, Hz (30)")
    ap.add_argument(
        "--out",
        type=Path,
        default=report.DOCS_BENCH,
        help="folder of the markdown table (default docs/bench), or a .md file",
    )
    a = ap.parse_args()
    a.out = report.table_path(ap, a.out, "rigs.md")
    width, height = (int(v) for v in a.size.split("x"))
    names = [f"rig{k}" for k in range(a.rigs)]
    endpoints = [free_endpoint() for _ in names]
    latencies: dict[str, list[float]] = {n: [] for n in names}
    seqs: dict[str, list[int]] = {n: [] for n in names}
    measuring = threading.Event()
    lock = threading.Lock()

    def on_objects(sample: zenoh.Sample) -> None:
        arrival = time.monotonic_ns()
        if not measuring.is_set():
            return
        msg = json.loads(sample.payload.to_bytes())
        rig = str(sample.key_expr).split("/")[1]
        with lock:
            latencies[rig].append((arrival - msg["t_ns"] - abs(msg["skew_ns"])) * 1e-6)
            seqs[rig].append(msg["seq"])

    with tempfile.TemporaryDirectory() as tmp:
        cfgs = []
        for name, endpoint in zip(names, endpoints, strict=True):
            cfg = Path(tmp) / f"{name}.toml"
            cfg.write_text(config(endpoint, width, height, a.fps, True, rig=name))
            cfgs.append(cfg)
        procs = [start_stereod("run", "--config", str(c), stdout=None, stderr=None) for c in cfgs]
        try:
            conf = zenoh.Config()
            conf.insert_json5("scouting", json.dumps({"delay": 0, "multicast": {"enabled": False}}))
            conf.insert_json5("connect/endpoints", json.dumps(endpoints))
            time.sleep(1.0)
            with zenoh.open(conf) as session:
                sub = session.declare_subscriber("stereod/*/objects", on_objects)
                for name in names:  # every daemon up before the warm-up starts
                    stats(session, name, wait_s=60.0)
                time.sleep(a.warmup)
                for name, proc in zip(names, procs, strict=True):
                    if proc.poll() is not None:
                        print(f"{name}: the daemon ended early", file=sys.stderr)
                        return 1
                before = {n: stats(session, n) for n in names}
                cpu0 = [proc_cpu_s(p.pid) for p in procs]
                wall0 = time.monotonic()
                measuring.set()
                time.sleep(a.seconds)
                measuring.clear()
                wall = time.monotonic() - wall0
                cpu = [(proc_cpu_s(p.pid) - c0) / wall for p, c0 in zip(procs, cpu0, strict=True)]
                mem = [proc_mem_mb(p.pid) for p in procs]
                after = {n: stats(session, n) for n in names}
                sub.undeclare()
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        camera = camera_mb(cfgs[0])
    rows = [
        "| rig | pairs made | messages | pairs dropped | frames unpaired | seq gaps | p50 latency "
        "| p99 latency | max latency | CPU (one core) | RSS (peak) | own RSS |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    ok = True
    for k, name in enumerate(names):
        lat = np.array(latencies[name])
        made = after[name]["pairs"] - before[name]["pairs"]
        gaps = int(np.sum(np.diff(np.sort(seqs[name])) - 1)) if len(seqs[name]) > 1 else 0
        behind, unpaired = drops(before[name], after[name])
        p50 = float(np.percentile(lat, 50)) if lat.size else float("nan")
        p99 = float(np.percentile(lat, 99)) if lat.size else float("nan")
        worst = float(lat.max()) if lat.size else float("nan")
        rss, hwm = mem[k]
        ok = ok and behind == unpaired == gaps == 0 and p99 <= TARGET_P99_MS
        rows.append(
            f"| {name} | {made} | {lat.size} | {behind} | {unpaired} | {gaps} "
            f"| {p50:.2f} ms | {p99:.2f} ms "
            f"| {worst:.2f} ms | {cpu[k] * 100:.1f} % | {rss:.0f} MB ({hwm:.0f} MB) "
            f"| {rss - camera:.0f} MB |"
        )
    total_cpu = sum(cpu) * 100
    rows += [
        "",
        f"{a.rigs} daemons, {width}x{height} BGR at {a.fps:g} Hz, {a.seconds:g} s measured; "
        f"all together {total_cpu:.0f} % of one core; synthetic camera {camera:.0f} MB of each "
        f"RSS; the host's load average {os.getloadavg()[1]:.1f} over the last 5 minutes, "
        f"{os.cpu_count()} cores. Targets: no pair dropped, p99 <= {TARGET_P99_MS:g} ms per "
        f"daemon: {'met' if ok else 'MISSED'}.",
    ]
    table = "\n".join(rows)
    print(table)
    a.out.write_text(table + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
