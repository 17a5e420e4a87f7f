"""VM-only tests: they need the kernel's vivid driver, so they run inside the guest that
``bash tests/vm/run.sh`` boots, and are skipped everywhere else."""

from __future__ import annotations

import math
import os
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

IN_VM = os.environ.get("VIVID_GUEST") == "1"
KERNEL = os.environ.get("VIVID_KERNEL", "")
ACCEL = os.environ.get("VIVID_ACCEL", "?")
"""How run.sh runs the guest: ``kvm`` or ``tcg`` (emulated, several times slower)."""
W, H, FPS = 320, 180, 25.0
"""The size (px) and rate (Hz) every test asks of vivid's eyes."""
SLACK = 5.0
"""Every wait is this many times what the guest's measured pace predicts: the host's load
can change between the measurement and the test, and a wait only costs its length when what
it waits for never comes."""
PACE_FRAMES = 10
"""Frames per eye read to measure the pace; the first one, which waits for streaming to
start, is not timed."""
VIVID = ["vivid", "n_devs=3", "node_types=0x1,0x1,0x1", "input_types=0x0,0x0,0x0"]
"""Three webcam-like instances: a left eye, a right eye, and a spare that plays the left eye
re-plugged. vivid has one platform device for all its instances (``vivid.0``), so unbinding it
takes every eye down at once; one eye alone is unplugged with its instance's Disconnect
control instead, which makes its node fail with ENODEV as a USB unplug does."""


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if IN_VM:
        return
    skip = pytest.mark.skip(reason="needs the vivid kernel driver: run `bash tests/vm/run.sh`")
    for item in items:
        if "tests/vm/" in str(item.fspath):
            item.add_marker(skip)


def _started_s() -> float:
    """How long (s) this Python process has run: from its exec (``/proc/self/stat``'s start
    time, in clock ticks since boot) to now on the boot clock (``/proc/uptime``)."""
    ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
    uptime = float(Path("/proc/uptime").read_text().split()[0])
    return uptime - ticks / os.sysconf("SC_CLK_TCK")


_startup_s: list[float] = []
"""This process's age (s) once pytest has collected the tests, whose modules import what
``stereod`` itself imports (numpy, OpenCV, Zenoh): the guest's measured start-up."""


def pytest_collection_finish(session: pytest.Session) -> None:
    _startup_s.append(_started_s())


@dataclass(frozen=True)
class Pace:
    """How fast this guest runs now, measured: what sizes the tests' waits and counts."""

    accel: str
    boot_s: float
    """Guest uptime when the tests' shell command started: kernel boot and init, s."""
    startup_s: float
    """A Python process started and the tests' modules (numpy, OpenCV, Zenoh, stereod)
    imported: about what starting ``stereod run`` costs before its first frame, s."""
    period_s: float
    """vivid's frame period from its own timestamps over sequence numbers, s."""
    fps: float
    """Frames a second each of two eyes read in turn (YUYV to BGR) delivers in the guest:
    ``1 / period_s`` on an idle host, less when the guest is starved of CPU."""

    def wait_s(self, *, seconds: float = 0.0, frames: float = 0.0, starts: int = 0) -> float:
        """How long (s) to wait for something that takes ``seconds`` of wall time, ``frames``
        frames per eye and ``starts`` starts of a Python process at this pace, times SLACK."""
        return SLACK * (seconds + frames / self.fps + starts * self.startup_s)

    def reads_for(self, frames: int) -> int:
        """How many frames per eye to read, at most, to expect ``frames`` of them to have a
        partner in the other eye: every frame on an idle host, fewer when the guest drops."""
        kept = min(1.0, self.fps * self.period_s)
        return math.ceil(SLACK * frames / kept)

    def describe(self) -> str:
        return (
            f"guest pace ({self.accel}): booted in {self.boot_s:.1f} s, Python with the tests' "
            f"imports started in {self.startup_s:.1f} s, vivid period "
            f"{self.period_s * 1e3:.1f} ms, {self.fps:.1f} frames/s per eye read"
        )


def measure_pace(nodes: list[str]) -> Pace:
    """Read PACE_FRAMES frames from each of two vivid nodes in turn through the V4L2 driver,
    as the tests do, and time them on the guest's clock."""
    from stereod.sources.frames import Eye
    from stereod_v4l2_minoru.driver import MinoruDriver

    opts = {"left": nodes[0], "right": nodes[1], "width": W, "height": H, "fps": FPS}
    source = MinoruDriver({**opts, "manual_exposure": False}).open()
    try:
        frames = []
        for eye in (source.left, source.right):
            assert eye.read() is not None, "vivid sent no first frame"
        start = time.monotonic()
        for _ in range(PACE_FRAMES - 1):
            for eye in (source.left, source.right):
                f = eye.read()
                assert f is not None, "vivid stopped sending frames"
                frames.append(f)
        elapsed = time.monotonic() - start
    finally:
        source.close()
    t = np.array([f.t_ns for f in frames if f.eye is Eye.LEFT], dtype=np.int64)
    seq = np.array([f.seq for f in frames if f.eye is Eye.LEFT], dtype=np.int64)
    period_s = float(np.median(np.diff(t) / np.maximum(np.diff(seq), 1))) / 1e9
    return Pace(
        accel=ACCEL,
        boot_s=float(os.environ.get("VIVID_BOOT_S") or 0.0),
        startup_s=_startup_s[0] if _startup_s else _started_s(),
        period_s=period_s,
        fps=(PACE_FRAMES - 1) / elapsed,
    )


@pytest.fixture
def pace(vivid: list[str], request: pytest.FixtureRequest) -> Pace:
    """The guest's pace measured on vivid's nodes just before the test (the host's load
    changes from one test to the next), written to the run's output."""
    p = measure_pace(vivid)
    reporter = request.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line(f"{request.node.name}: {p.describe()}")
    return p


def modprobe(*args: str) -> None:
    subprocess.run(["modprobe", "-d", KERNEL, *args], check=True, timeout=60)


def wait_nodes(n: int, timeout: float = 20.0) -> list[str]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        nodes = sorted(str(p) for p in Path("/dev").glob("video*"))
        if len(nodes) >= n:
            return nodes
        time.sleep(0.1)
    raise AssertionError(f"vivid made fewer than {n} video nodes")


@pytest.fixture
def vivid() -> Iterator[list[str]]:
    """Three webcam-like vivid capture nodes; the module is unloaded afterwards."""
    modprobe(*VIVID)
    try:
        yield wait_nodes(3)[:3]
    finally:
        subprocess.run(["modprobe", "-d", KERNEL, "-r", "vivid"], timeout=60)


def disconnect(node: str) -> None:
    """Unplug one vivid instance: press its Disconnect control. Its node stays in /dev but
    every open and ioctl on it fails with ENODEV from then on (until the module reloads)."""
    from stereod_v4l2_minoru.device import V4L2Device

    with V4L2Device(node) as dev:
        button = next(c for c in dev.controls() if c.name == "Disconnect")
        dev.set_control(button.id, 1)
