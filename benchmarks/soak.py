"""Soak: replay a recording in a loop in real time for N minutes and watch the daemon's
resident memory (RSS) and open file descriptors, sampled from /proc. A subscriber receives
everything, so publishing is exercised too. Reports the growth after a warm-up minute.
Target: flat, under 5 MB of RSS growth over 30 minutes.

Usage: ``python benchmarks/soak.py [--minutes 30] [--every 10]``.
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh

from stereod.bus.publish import open_session
from stereod.daemon.config import ZenohConfig
from stereod_fakes.synth import Ball, Scene, write_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.processes import stereod_command


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="how long, min (default 30)")
    ap.add_argument("--every", type=float, default=10.0, help="sampling period, s (default 10)")
    a = ap.parse_args()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    received = 0

    def on(_sample: zenoh.Sample) -> None:
        nonlocal received
        received += 1

    with tempfile.TemporaryDirectory() as tmp:
        scene = Scene(duration_s=6.0, balls=[Ball(t_on_s=1.0, t_off_s=5.0, t_mid_s=3.0)])
        rec = write_scene(scene, Path(tmp) / "rec")
        proc = subprocess.Popen(
            stereod_command(
                "replay",
                str(rec),
                "--loop",
                "--rate",
                "1",
                "--listen",
                endpoint,
                "-q",
            ),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        samples: list[tuple[float, int, int]] = []
        t0 = time.monotonic()
        try:
            with open_session(ZenohConfig(connect=[endpoint])) as session:
                sub = session.declare_subscriber("stereod/**", on)
                print(f"{'t (s)':>8} {'RSS (MiB)':>10} {'fds':>5} {'messages':>9}", flush=True)
                while time.monotonic() - t0 < a.minutes * 60:
                    if proc.poll() is not None:
                        raise RuntimeError(f"daemon exited early: {proc.stderr.read()}")
                    t = time.monotonic() - t0
                    samples.append((t, rss_kib(proc.pid), fds(proc.pid)))
                    print(
                        f"{t:8.0f} {samples[-1][1] / 1024:10.1f} {samples[-1][2]:5d} {received:9d}",
                        flush=True,
                    )
                    time.sleep(a.every)
                sub.undeclare()
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=20)
    warm = [s for s in samples if s[0] >= 60.0]
    if len(warm) < 2:
        print("\nno figure: run longer than the one-minute warm-up (--minutes)")
        return 1
    rss_growth = (warm[-1][1] - warm[0][1]) / 1024
    fd_growth = warm[-1][2] - warm[0][2]
    span = (warm[-1][0] - warm[0][0]) / 60
    print(
        f"\nafter the first minute, over {span:.1f} min: RSS {warm[0][1] / 1024:.1f} -> "
        f"{warm[-1][1] / 1024:.1f} MiB ({rss_growth:+.2f} MiB), open fds {warm[0][2]} -> "
        f"{warm[-1][2]} ({fd_growth:+d}); {received} messages received"
    )
    ok = rss_growth < 5.0 and fd_growth <= 0
    print("flat" if ok else "GROWING")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
