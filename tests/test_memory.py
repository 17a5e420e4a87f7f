"""The allocator setting that gives freed background-sized buffers back to the system and
keeps frame-sized ones in the heap."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from stereod.daemon.memory import MIN_MMAP_THRESHOLD, separate_large_buffers

W, H = 640, 480

CHILD = """
import re, sys
import numpy as np
from stereod.daemon.memory import separate_large_buffers
def rss_kb():
    return int(re.search(r"VmRSS:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
if sys.argv[1] == "set":
    assert separate_large_buffers({w}, {h}) is not None
kept = []
for size in ({w} * {h} * 4, {w} * {h} * 3):  # a grey float32 background, then a BGR frame
    before = rss_kb()
    for _ in range(2):  # glibc's own way: the first free raises its thresholds
        block = np.ones(size, np.uint8)
        del block
    kept.append(rss_kb() - before)
print(*kept)
"""


def kept_kb(mode: str) -> tuple[int, int]:
    """RSS (kB) a fresh process keeps after allocating and freeing, twice, a block the size
    of a grey float32 background, and then one the size of a BGR frame (640x480), with the
    setting (``mode`` "set") or without."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "LD_PRELOAD")
    }
    env["NUMPY_MADVISE_HUGEPAGE"] = "0"  # what is measured is malloc's, not the kernel's
    res = subprocess.run(
        [sys.executable, "-c", CHILD.format(w=W, h=H), mode],
        capture_output=True,
        text=True,
        env=env,
    )
    assert res.returncode == 0, res.stderr
    background, frame = (int(v) for v in res.stdout.split())
    return background, frame


glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="needs glibc's malloc")


@glibc
def test_a_freed_background_goes_back_to_the_system_and_a_frame_stays_in_the_heap() -> None:
    background_kb, frame_kb = W * H * 4 // 1024, W * H * 3 // 1024
    unset, done = kept_kb("unset"), kept_kb("set")
    assert unset[0] > background_kb // 2  # glibc's own way keeps it: the test can fail
    assert done[0] < background_kb // 8
    # A frame-sized block is reused from the heap, not mapped and faulted in for each frame
    # (which a threshold at glibc's 128 KiB, fixed, would do).
    assert done[1] > frame_kb // 2


@glibc
def test_the_threshold_is_three_and_a_half_bytes_a_pixel_within_bounds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    try:
        assert separate_large_buffers(W, H) == W * H * 7 // 2
        assert separate_large_buffers(64, 48) == MIN_MMAP_THRESHOLD  # never below glibc's own
        monkeypatch.setenv("GLIBC_TUNABLES", "glibc.pthread.rseq=0")  # not malloc's: set
        assert separate_large_buffers(320, 240) == 320 * 240 * 7 // 2
    finally:
        separate_large_buffers(64, 48)  # this process goes on with glibc's starting threshold


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("MALLOC_MMAP_THRESHOLD_", "131072"),
        ("MALLOC_TRIM_THRESHOLD_", "131072"),
        ("GLIBC_TUNABLES", "glibc.malloc.mmap_threshold=131072"),
    ],
)
def test_an_environment_that_tunes_malloc_is_left_alone(
    monkeypatch: pytest.MonkeyPatch, name: str, value: str
) -> None:
    monkeypatch.setenv(name, value)
    assert separate_large_buffers(W, H) is None


def test_a_frame_size_must_be_positive() -> None:
    with pytest.raises(ValueError, match="frame size must be positive, got 0x480"):
        separate_large_buffers(0, 480)
