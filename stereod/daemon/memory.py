"""How the C allocator places the daemon's large buffers, so that memory freed is given back.

glibc's malloc maps a block of its own for an allocation at or above a threshold (128 KiB at
first) when its heap cannot serve it, and unmaps it when freed. But each time such a block is
freed, it raises that threshold to the block's size, and the heap's trim threshold to twice
that: after the warm-up frees its stack of frames (about 9 MB at 640x480 in colour), buffers of
several MB come from a heap that is no longer trimmed below them, and the daemon keeps about
12 MB it no longer uses (measured with ``benchmarks/latency.py``). Fixing the threshold at 3.5
bytes a pixel keeps what a frame needs (a BGR frame is 3 bytes a pixel; a difference image or a
mask less) in the heap, reused without page faults, while everything larger (a float32
background is 4 bytes a pixel in grey and 12 in colour, the warm-up's stack ten frames) is a
mapping of its own that goes back to the system when freed.
"""

from __future__ import annotations

import ctypes
import logging
import os

log = logging.getLogger(__name__)

M_TRIM_THRESHOLD = -1
"""mallopt's parameter for the heap's trim threshold, in glibc's <malloc.h>."""
M_MMAP_THRESHOLD = -3
"""mallopt's parameter for the size from which a block is mapped on its own."""

BYTES_PER_PIXEL = 3.5
"""The threshold's size per pixel of a frame: above a BGR frame, below a grey float32 image."""
MIN_MMAP_THRESHOLD = 128 * 1024
"""glibc's own starting threshold (bytes): a small frame never lowers it."""
MAX_MMAP_THRESHOLD = 32 * 1024 * 1024
"""The most asked for (bytes): older 64-bit glibc refuses more, and a frame above it is mapped
per buffer, which is no worse than glibc's own way."""


def _tunes_malloc() -> bool:
    """Whether the environment tunes glibc's malloc: its choice then stands."""
    return (
        "MALLOC_MMAP_THRESHOLD_" in os.environ
        or "MALLOC_TRIM_THRESHOLD_" in os.environ
        or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", "")
    )


def separate_large_buffers(width: int, height: int) -> int | None:
    """Have glibc map every allocation above ``BYTES_PER_PIXEL`` bytes a pixel of a ``width``
    x ``height`` px frame on its own, and trim its heaps above twice that, instead of raising
    both thresholds as large blocks are freed (module docstring). Returns the threshold set
    (bytes), or None when nothing was set: the C library is not glibc, the environment
    already tunes malloc (``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``,
    ``glibc.malloc.*`` in ``GLIBC_TUNABLES``), or mallopt refused. An allocator preloaded in
    glibc's place (``LD_PRELOAD`` of jemalloc or tcmalloc) ignores the setting."""
    if width <= 0 or height <= 0:
        raise ValueError(f"frame size must be positive, got {width}x{height}")
    try:
        glibc = os.confstr("CS_GNU_LIBC_VERSION")
    except (ValueError, OSError):
        glibc = None
    if not glibc or _tunes_malloc():
        log.debug("malloc left as it is (%s)", glibc or "not glibc")
        return None
    mallopt = ctypes.CDLL(None).mallopt  # the C library this process runs on
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    threshold = int(BYTES_PER_PIXEL * width * height)
    threshold = min(max(threshold, MIN_MMAP_THRESHOLD), MAX_MMAP_THRESHOLD)
    if not (mallopt(M_MMAP_THRESHOLD, threshold) and mallopt(M_TRIM_THRESHOLD, 2 * threshold)):
        log.debug("mallopt refused a threshold of %d bytes", threshold)
        return None
    log.debug("blocks from %d bytes are mapped on their own", threshold)
    return threshold
