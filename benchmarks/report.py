"""Where the benchmarks write their results, and the description of the host they ran on.

Each benchmark writes a markdown fragment into ``docs/bench/`` (figures beside it), which the
Accuracy and Performance pages of the documentation include as they are: the site shows the
last committed run, and running the benchmark again updates it.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from datetime import datetime, timezone
from pathlib import Path

DOCS_BENCH = Path(__file__).resolve().parents[1] / "docs" / "bench"
"""The folder of the generated fragments and figures."""


def _cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo, or the platform's processor string."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def _memory_gib() -> float:
    """Total memory, GiB, from /proc/meminfo (0 when unknown)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return 0.0


def floor_figures() -> str:
    """What the host itself costs, so that runs on two hosts can be compared: one 640x480 BGR
    absolute difference (OpenCV, median of 200, us), the CPU one 1 ms sleep costs to wake
    from (median of 200, us), and the spread of the thread CPU time a fixed loop of Python
    takes (300 times, p50 and p99, ms): how steady the host runs the same work, which every
    latency's tail measured on it carries too."""
    import cv2
    import numpy as np

    a = np.full((480, 640, 3), 90, np.uint8)
    b = np.full((480, 640, 3), 95, np.uint8)
    diff = []
    for _ in range(200):
        t0 = time.perf_counter()
        cv2.absdiff(a, b)
        diff.append(time.perf_counter() - t0)
    wake = []
    for _ in range(200):
        c0 = time.thread_time()
        time.sleep(0.001)
        wake.append(time.thread_time() - c0)
    work = []
    for _ in range(300):
        c0 = time.thread_time()
        _python_work()
        work.append(time.thread_time() - c0)
        time.sleep(0.001)
    cuts = statistics.quantiles(work, n=100)
    return (
        f"640x480 BGR absdiff {statistics.median(diff) * 1e6:.0f} us, "
        f"CPU to wake from a 1 ms sleep {statistics.median(wake) * 1e6:.0f} us, "
        f"a fixed pure-Python loop's thread CPU p50 {cuts[49] * 1e3:.2f} ms, "
        f"p99 {cuts[98] * 1e3:.2f} ms (the same work each time: the spread is the host's)"
    )


def _python_work() -> int:
    """About a millisecond of interpreter work, the same on every host but for its speed."""
    s = 0
    for i in range(15_000):
        s += i * i
    return s


def host() -> str:
    """One paragraph: when, on what machine and software, under what load the run was made."""
    import cv2
    import numpy as np

    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (
        f"Measured {when} on {_cpu_model()}, {os.cpu_count()} logical cores, "
        f"{_memory_gib():.1f} GiB, {platform.system()} {platform.release()}; "
        f"Python {platform.python_version()}, NumPy {np.__version__}, OpenCV {cv2.__version__}; "
        f"load average {load} at the start. Host floor: {floor_figures()}."
    )


def write(name: str, text: str, out: Path | None = None) -> Path:
    """Write the fragment ``name`` (``throughput.md``) into ``out`` (default
    :data:`DOCS_BENCH`), ending in one newline; its path."""
    folder = DOCS_BENCH if out is None else out
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(text.rstrip("\n") + "\n")
    return path


def table_path(parser: argparse.ArgumentParser, out: Path, name: str) -> Path:
    """Where ``--out`` puts the table ``name``: into ``out`` when it is a folder (or names no
    ``.md`` file), else ``out`` itself; checked before the benchmark runs, so that a long run
    does not end unable to write (a parser error, exit 2)."""
    path = out if out.suffix == ".md" and not out.is_dir() else out / name
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        parser.error(f"--out {out}: cannot make {path.parent}: {exc.strerror}")
    if path.is_dir() or not os.access(path.parent, os.W_OK):
        parser.error(f"--out {out}: cannot write {path}")
    return path
