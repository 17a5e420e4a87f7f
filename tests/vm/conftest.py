"""VM-only tests: they need the kernel's vivid driver, so they run inside the guest that
``bash tests/vm/run.sh`` boots, and are skipped everywhere else."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

IN_VM = os.environ.get("VIVID_GUEST") == "1"
KERNEL = os.environ.get("VIVID_KERNEL", "")
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
