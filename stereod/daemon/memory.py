"""The daemon's resident memory: how the C allocator places its large buffers, so that memory
freed is given back, and which pages of its libraries it keeps mapped.

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

The libraries it loads are most of the rest (OpenCV's code alone is 30 MB, Zenoh's 15). A
page touched maps back, where the file is in the page cache, with what the cache holds around
it: up to 64 KB (fault-around), or the whole large folio the import's read-ahead put it in (a
single OpenCV call brought back 5 MB of its code). The same daemon's own RSS read 91 MB from a
clone whose libraries the cache had mostly let go, and 118 MB from a fresh install, all of it
in cache. :func:`release_library_pages` unmaps their pages once the daemon has started, turns
read-ahead off for them and drops from the page cache what no process maps (a page another
process runs stays): a page used again is read back alone, so what stays mapped is what the
daemon runs. The cost is a few hundred small reads in the first frames.
"""

from __future__ import annotations

import ctypes
import logging
import os
import re
from typing import NamedTuple

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


MADV_RANDOM = 1
"""madvise's advice: no read-ahead for the range (<sys/mman.h>)."""
MADV_DONTNEED = 4
"""madvise's advice: unmap the range's pages (a file's stay in the page cache)."""
_MAPPING = re.compile(r"^([0-9a-f]+)-([0-9a-f]+) (\S+) \S+ \S+ \S+\s*(\S.*)?$")


class LibraryMapping(NamedTuple):
    """One mapping of a shared library: its addresses, resident size (kB) and file."""

    start: int
    end: int
    rss_kb: int
    path: str


def library_mappings(smaps: str) -> list[LibraryMapping]:
    """Each mapping of a shared library in ``smaps`` (the text of ``/proc/<pid>/smaps``)
    whose pages are all the file's: not writable, and holding no private copy (a relocated
    read-only segment does; unmapping it would lose the relocations)."""
    out: list[LibraryMapping | None] = []
    current: LibraryMapping | None = None
    for line in smaps.splitlines():
        m = _MAPPING.match(line)
        if m:
            path, perms = m.group(4) or "", m.group(3)
            library = path.startswith("/") and ".so" in path.rsplit("/", 1)[-1]
            current = None
            if library and "w" not in perms:
                current = LibraryMapping(int(m.group(1), 16), int(m.group(2), 16), 0, path)
                out.append(current)
            continue
        if current is None:
            continue
        key, _, value = line.partition(":")
        if key == "Rss":
            current = current._replace(rss_kb=int(value.split()[0]))
            out[-1] = current
        elif key == "Anonymous" and int(value.split()[0]):
            out[-1] = current = None  # a private copy in it: left alone
    return [m for m in out if m is not None]


def drop_cached_pages(path: str) -> bool:
    """Ask the kernel to drop ``path``'s pages from the page cache where no process maps
    them (a page another process runs stays). Whether the advice was taken."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    except (OSError, AttributeError):
        return False
    finally:
        os.close(fd)
    return True


def release_library_pages() -> int:
    """Unmap the pages of the shared libraries mapped now, turn read-ahead off for them and
    drop their unmapped pages from the page cache (module docstring); the kB unmapped
    (their resident size before), 0 where ``/proc/self/smaps`` or madvise is not there (not
    Linux)."""
    try:
        with open("/proc/self/smaps", encoding="ascii", errors="replace") as fh:
            mappings = library_mappings(fh.read())
        madvise = ctypes.CDLL(None, use_errno=True).madvise
    except (OSError, AttributeError):
        return 0
    madvise.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    madvise.restype = ctypes.c_int
    released = 0
    files: set[str] = set()
    for start, end, rss_kb, path in mappings:
        random = madvise(start, end - start, MADV_RANDOM) == 0
        if random and madvise(start, end - start, MADV_DONTNEED) == 0:
            released += rss_kb
            files.add(path)
    dropped = sum(drop_cached_pages(path) for path in sorted(files))
    log.debug("library pages unmapped: %d kB; %d files' cache dropped", released, dropped)
    return released
