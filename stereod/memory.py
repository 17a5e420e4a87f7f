"""How the C allocator places the daemon's large buffers, so that memory freed is given back.

glibc's malloc maps a block of its own for any allocation above a threshold (128 KiB at first)
and unmaps it when freed. But each time such a block is freed, it raises that threshold to the
block's size, and the heap's trim threshold to twice that: after the warm-up frees its stack of
frames (about 9 MB at 640x480 in colour), buffers of several MB come from a heap that is never
trimmed below them, and the daemon keeps about 12 MB it no longer uses (measured with
``benchmarks/latency.py``). Fixing the threshold at two frames' worth keeps the per-frame buffers
(a frame, a difference image: at most one frame's bytes) in the heap, reused without page faults,
while everything larger (a float32 background is four frames, the warm-up's stack ten) is a
mapping of its own that goes back to the system when freed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os

log = logging.getLogger(__name__)

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""mallopt's parameters in glibc's <malloc.h>."""

MAX_MMAP_THRESHOLD = 32 * 1024 * 1024
"""The largest threshold glibc accepts on a 64-bit system (bytes)."""

_TUNABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "GLIBC_TUNABLES")
"""Environment variables through which a user tunes glibc's malloc: then it is left alone."""


def separate_large_buffers(frame_bytes: int) -> bool:
    """Have glibc map every allocation above two frames (``frame_bytes`` each, bytes) on its
    own and trim its heaps above the same size, instead of raising both thresholds as large
    blocks are freed (module docstring). Returns whether it was set: not when the C library
    is not glibc, nor when the environment already tunes malloc (``MALLOC_MMAP_THRESHOLD_``,
    ``MALLOC_TRIM_THRESHOLD_``, ``GLIBC_TUNABLES``)."""
    if frame_bytes <= 0:
        raise ValueError(f"frame_bytes must be positive, got {frame_bytes}")
    if any(name in os.environ for name in _TUNABLES):
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
        libc.gnu_get_libc_version  # noqa: B018 (only glibc has it: another libc's mallopt differs)
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    threshold = min(2 * frame_bytes, MAX_MMAP_THRESHOLD)
    ok = bool(mallopt(M_MMAP_THRESHOLD, threshold)) and bool(mallopt(M_TRIM_THRESHOLD, threshold))
    if not ok:
        log.debug("mallopt refused a threshold of %d bytes", threshold)
    return ok
