"""Latency, CPU and memory of the daemon at a camera's pace, measured from outside.

The daemon runs as its own process (``stereod run``) on the ``synthetic`` driver in live mode:
each eye delivers its frames at their capture instants on this host's CLOCK_MONOTONIC, as a
camera does, at 320x240 and 640x480, 30 Hz, with a ball crossing the view again and again, in colour
(BGR, what the V4L2 driver delivers by default; ``--grey`` for ``color = false``). The frames
are rendered when the source opens, before the clock starts, so rendering costs nothing while
it plays. This process subscribes to the ``objects`` key over Zenoh (loopback) and, for every
message, takes the time from the pair's capture instant to its arrival here on the same
monotonic clock. A pair exists once its later frame is captured (``t_ns + |skew_ns|``: ``t_ns``
is the earlier eye's instant, to which the later eye's centroids are brought), so that is the
instant measured from; the measurement's own age at arrival is that plus the skew.

Each size runs twice: the daemon, then its floor, the same daemon with ``[daemon] detect =
false`` (capture, pairing and an empty objects message published per pair). It reports the
p50, p99 and largest latency, the daemon's CPU (share of one core, from /proc/<pid>/stat over
the measured window) and its resident memory (VmRSS and its peak, VmHWM), and writes them to
``docs/bench/latency.md`` (with the host), which the documentation's Performance page
includes. Absolute figures change from host to host, so the targets are
ratios to the floor measured in the same run: CPU at most 2x the floor's, p99 at most the
floor's plus 2 ms; and the daemon's own RSS at most 110 MB.

The synthetic camera lives inside the daemon's process, and its prerendered scene with it
(66 MB of BGR frames at 640x480 and 30 Hz, 22 MB grey, and the renderer that made them); a
real camera's frames live in the kernel's buffers, of which the daemon maps a few. So the
camera's share is measured too, in a process of its own that imports what the daemon imports
and then opens the same source, and the memory target applies to the daemon's own: its RSS
less that share. Both are reported.

Usage: ``python benchmarks/latency.py [--seconds 30] [--sizes 320x240 640x480] [--fps 30]
[--grey] [--no-floor]``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import report
import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.processes import start_stereod

TARGET_CPU_RATIO = 2.0
"""The daemon's CPU at most this many times the floor's (the same daemon, detection off)."""
TARGET_P99_EXTRA_MS = 2.0
"""The daemon's p99 latency at most the floor's plus this (ms)."""
TARGET_RSS_MB = 110.0
"""The daemon's own RSS (MB): its RSS less the synthetic camera's share."""


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def proc_cpu_s(pid: int) -> float:
    """User plus system CPU time (s) of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_mem_mb(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of a process, MB."""
    status = Path(f"/proc/{pid}/status").read_text()
    got = {
        line.split(":")[0]: int(line.split()[1]) / 1024
        for line in status.splitlines()
        if line.startswith(("VmRSS", "VmHWM"))
    }
    return got["VmRSS"], got["VmHWM"]


def stats(session: zenoh.Session, rig: str, wait_s: float = 5.0) -> dict:
    """A daemon's ``stats`` queryable's reply, asked again until ``wait_s`` s have passed
    (a daemon starting on a busy host takes seconds to declare its keys)."""
    deadline = time.monotonic() + wait_s
    while True:
        replies = list(session.get(f"stereod/{rig}/stats", timeout=5))
        if replies and replies[0].ok is not None:
            return dict(json.loads(replies[0].ok.payload.to_bytes()))
        if time.monotonic() > deadline:
            raise RuntimeError(f"rig {rig}: no reply on stereod/{rig}/stats")
        time.sleep(0.5)


def proc_code_mb(pid: int) -> float:
    """Resident memory (MB) of a process's mapped files (its libraries' code and data, shared
    with every process that maps them and dropped by the kernel under pressure): how much of
    OpenCV's, NumPy's and Zenoh's libraries stay resident varies from run to run."""
    total_kb = 0
    mapped_file = False
    for line in Path(f"/proc/{pid}/smaps").read_text().splitlines():
        head = line.split(None, 5)
        if "-" in head[0] and len(head) >= 5 and ":" in head[3]:  # a mapping's first line
            mapped_file = len(head) == 6 and head[5].startswith("/")
        elif line.startswith("Rss:") and mapped_file:
            total_kb += int(line.split()[1])
    return total_kb / 1024


CAMERA_PROBE = """
import re, sys
try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib
import stereod.cli, stereod.daemon.daemon
from stereod_fakes.synth import SyntheticDriver
def rss_mb():
    return int(re.search(r"VmRSS:\\s+(\\d+)", open("/proc/self/status").read()).group(1)) / 1024
options = tomllib.load(open(sys.argv[1], "rb"))["driver"]["options"]
before = rss_mb()
source = SyntheticDriver(options).open()
print(rss_mb() - before)
"""
"""Prints the resident memory (MB) that opening the synthetic source adds to a process."""


def camera_mb(cfg: Path) -> float:
    """The synthetic camera's own resident memory (MB), measured in a process of its own."""
    out = subprocess.run(
        [sys.executable, "-c", CAMERA_PROBE, str(cfg)], capture_output=True, text=True, check=True
    )
    return float(out.stdout.strip())


def config(
    endpoint: str,
    width: int,
    height: int,
    fps: float,
    color: bool,
    skew: float = 0.5,
    detect: bool = True,
    rig: str = "bench",
) -> str:
    """The daemon's TOML: a live, prerendered, looping synthetic scene of 1.2 s, in colour
    (BGR, as the V4L2 driver delivers by default) or grey, the right eye ``skew`` frames
    late; ``detect = false`` for the floor; the rig named ``rig``."""
    return f"""
[rig]
name = "{rig}"
[driver]
name = "synthetic"
[driver.options]
live = true
prerender = true
loop = true
width_px = {width}
height_px = {height}
fps = {fps}
duration_s = 1.2
skew_s = {skew / fps}
noise_sigma = 2.0
color = {str(color).lower()}
[[driver.options.balls]]
heading_deg = 90.0
speed_mps = 1.5
centre_m = [0.0, 0.1, 1.8]
t_on_s = 0.3
t_off_s = 1.2
t_mid_s = 0.75
[zenoh]
listen = ["{endpoint}"]
[daemon]
log_level = "WARNING"
detect = {str(detect).lower()}
"""


@dataclass(frozen=True)
class Run:
    """What one daemon measured: latencies (ms) of its messages, its CPU (share of one core),
    its RSS and peak (MB), the synthetic camera's share of it (MB), and its own timings."""

    latencies_ms: np.ndarray
    cpu: float
    rss_mb: float
    hwm_mb: float
    camera_mb: float
    code_mb: float
    breakdown: list[dict[str, float]]
    seqs: list[int]

    @property
    def own_mb(self) -> float:
        return self.rss_mb - self.camera_mb

    def p(self, q: float) -> float:
        return float(np.percentile(self.latencies_ms, q))


def measure(
    width: int,
    height: int,
    fps: float,
    color: bool,
    skew: float,
    detect: bool,
    seconds: float,
    warmup: float,
) -> Run | None:
    """Run one daemon (``[daemon] detect`` as given) for ``warmup`` + ``seconds`` s and
    measure it from outside; None when it ended early or published nothing."""
    endpoint = free_endpoint()
    latencies_ms: list[float] = []
    breakdown: list[dict[str, float]] = []
    seqs: list[int] = []
    measuring = threading.Event()
    lock = threading.Lock()

    def on_objects(sample: zenoh.Sample) -> None:
        arrival = time.monotonic_ns()
        if not measuring.is_set():
            return
        msg = json.loads(sample.payload.to_bytes())
        with lock:
            latencies_ms.append((arrival - msg["t_ns"] - abs(msg["skew_ns"])) * 1e-6)
            breakdown.append(msg["latency"])
            seqs.append(msg["seq"])

    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "latency.toml"
        cfg.write_text(config(endpoint, width, height, fps, color, skew, detect))
        proc = start_stereod("run", "--config", str(cfg), stdout=None, stderr=None)
        try:
            conf = zenoh.Config()
            conf.insert_json5("scouting", json.dumps({"delay": 0, "multicast": {"enabled": False}}))
            conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
            time.sleep(0.5)
            with zenoh.open(conf) as session:
                sub = session.declare_subscriber("stereod/bench/objects", on_objects)
                stats(session, "bench", wait_s=60.0)  # up (seconds on a busy host)
                time.sleep(warmup)
                if proc.poll() is not None:
                    print("the daemon ended early", file=sys.stderr)
                    return None
                cpu0, wall0 = proc_cpu_s(proc.pid), time.monotonic()
                measuring.set()
                time.sleep(seconds)
                measuring.clear()
                cpu = (proc_cpu_s(proc.pid) - cpu0) / (time.monotonic() - wall0)
                rss, hwm = proc_mem_mb(proc.pid)
                code = proc_code_mb(proc.pid)
                sub.undeclare()
        finally:
            proc.terminate()
            proc.wait(10)
        camera = camera_mb(cfg)
    if not latencies_ms:
        print("no message arrived", file=sys.stderr)
        return None
    return Run(np.array(latencies_ms), cpu, rss, hwm, camera, code, breakdown, seqs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="measured time per run, s (30)")
    ap.add_argument("--warmup", type=float, default=3.0, help="ignored first seconds (3)")
    ap.add_argument(
        "--sizes",
        nargs="+",
        default=["320x240", "640x480"],
        help="image sizes, px (320x240 640x480)",
    )
    ap.add_argument("--fps", type=float, default=30.0, help="frame rate per eye, Hz (30)")
    ap.add_argument(
        "--skew",
        type=float,
        default=0.5,
        help="how late the right eye is, in frames (0.5: the most two free-running eyes are "
        "apart; the earlier eye is detected while the later is awaited)",
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=report.DOCS_BENCH,
        help="folder of the markdown table (default docs/bench), or a .md file",
    )
    ap.add_argument(
        "--grey",
        action="store_true",
        help="grey frames (a camera with [driver.options] color = false) instead of BGR",
    )
    ap.add_argument("--no-floor", action="store_true", help="skip the floor (detect = false)")
    ap.add_argument("--breakdown", action="store_true", help="also the daemon's own timings")
    a = ap.parse_args()
    a.out = report.table_path(ap, a.out, "latency.md")
    rows = [
        "| size | rate | frames | daemon | messages | p50 latency | p99 latency | max latency "
        "| CPU (one core) | RSS (peak) | synthetic camera | own RSS | of it, mapped files |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    verdicts: list[str] = []
    ok = True
    expected = a.seconds * a.fps
    for size in a.sizes:
        width, height = (int(v) for v in size.split("x"))
        runs: dict[bool, Run] = {}
        for detect in (True,) if a.no_floor else (True, False):
            run = measure(width, height, a.fps, not a.grey, a.skew, detect, a.seconds, a.warmup)
            if run is None:
                return 1
            runs[detect] = run
            rows.append(
                f"| {width}x{height} | {a.fps:g} Hz | {'grey' if a.grey else 'BGR'} "
                f"| {'full' if detect else 'floor (detect = false)'} "
                f"| {run.latencies_ms.size} of {expected:.0f} | {run.p(50):.2f} ms "
                f"| {run.p(99):.2f} ms | {run.latencies_ms.max():.2f} ms | {run.cpu * 100:.1f} % "
                f"| {run.rss_mb:.0f} MB ({run.hwm_mb:.0f} MB) | {run.camera_mb:.0f} MB "
                f"| {run.own_mb:.0f} MB | {run.code_mb:.0f} MB |"
            )
            if a.breakdown:
                for k in run.breakdown[0]:
                    v = np.array([b[k] for b in run.breakdown])
                    print(
                        f"{size} {'full' if detect else 'floor'} {k}: "
                        f"p50 {np.percentile(v, 50):.2f} ms, p99 {np.percentile(v, 99):.2f} ms"
                    )
                print(f"pairs missing (seq gaps): {int(np.sum(np.diff(run.seqs) - 1))}")
        full = runs[True]
        size_ok = full.own_mb <= TARGET_RSS_MB
        verdict = f"{size}: own RSS {full.own_mb:.0f} MB (<= {TARGET_RSS_MB:g})"
        if False in runs:
            floor = runs[False]
            cpu_ratio = full.cpu / max(floor.cpu, 1e-9)
            extra = full.p(99) - floor.p(99)
            size_ok = size_ok and cpu_ratio <= TARGET_CPU_RATIO and extra <= TARGET_P99_EXTRA_MS
            verdict += (
                f", CPU {cpu_ratio:.2f}x the floor's (<= {TARGET_CPU_RATIO:g}x), "
                f"p99 the floor's {extra:+.2f} ms (<= +{TARGET_P99_EXTRA_MS:g} ms)"
            )
        verdicts.append(f"- {verdict}: {'met' if size_ok else 'MISSED'}.")
        ok = ok and size_ok
    verdicts.append(
        f"- The host's load average over the last 5 minutes: {os.getloadavg()[1]:.1f} "
        f"({os.cpu_count()} cores)."
    )
    table = "\n".join([*rows, "", *verdicts])
    print(table)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(f"{report.host()}\n\n{table}\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
