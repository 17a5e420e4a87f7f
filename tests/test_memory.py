"""The allocator setting that gives freed background-sized buffers back to the system."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

from stereod.memory import separate_large_buffers

FRAME = 640 * 480 * 3
"""Bytes of a 640x480 BGR frame."""

CHILD = """
import re, sys
import numpy as np
from stereod.memory import separate_large_buffers
def rss_kb():
    return int(re.search(r"VmRSS:\\s+(\\d+)", open("/proc/self/status").read()).group(1))
if sys.argv[1] == "set":
    assert separate_large_buffers({frame})
for _ in range(2):  # the first free raises glibc's thresholds; the second block is kept
    before = rss_kb()
    block = np.ones({frame} * 4, np.uint8)  # a float32 background's size
    del block
print(rss_kb() - before)
"""


def kept_kb(mode: str) -> int:
    """RSS (kB) a fresh process keeps after allocating and freeing a background-sized block
    twice, with the setting (``mode`` "set") or without."""
    out = subprocess.run(
        [sys.executable, "-c", CHILD.format(frame=FRAME), mode],
        capture_output=True,
        text=True,
        check=True,
        env={"PATH": "/usr/bin:/bin"},
    )
    return int(out.stdout)


glibc = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="needs glibc's malloc")


@glibc
def test_a_freed_background_sized_block_goes_back_to_the_system() -> None:
    block_kb = FRAME * 4 // 1024
    assert kept_kb("unset") > block_kb * 0.9  # glibc's own way keeps it: the test can fail
    assert kept_kb("set") < 512


def test_an_environment_that_tunes_malloc_is_left_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MALLOC_MMAP_THRESHOLD_", "131072")
    assert separate_large_buffers(FRAME) is False


def test_a_frame_size_must_be_positive() -> None:
    with pytest.raises(ValueError, match="frame_bytes"):
        separate_large_buffers(0)
