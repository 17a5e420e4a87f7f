"""VM-only tests: they need the kernel's vivid driver, so they run inside the guest that
``bash tests/vm/run.sh`` boots, and are skipped everywhere else."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

IN_VM = os.environ.get("STEREOD_VM") == "1"
KERNEL = os.environ.get("STEREOD_VM_KERNEL", "")
VIVID = ["vivid", "n_devs=2", "node_types=0x1,0x1", "input_types=0x0,0x0"]


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
    """Two webcam-like vivid capture nodes; the module is unloaded afterwards."""
    modprobe(*VIVID)
    try:
        yield wait_nodes(2)[:2]
    finally:
        subprocess.run(["modprobe", "-d", KERNEL, "-r", "vivid"], timeout=60)


def unbind(device: str = "vivid.0") -> None:
    """Unplug one vivid instance while it may be streaming (its node disappears)."""
    Path("/sys/bus/platform/drivers/vivid/unbind").write_text(device)


def bind(device: str = "vivid.0") -> None:
    Path("/sys/bus/platform/drivers/vivid/bind").write_text(device)
